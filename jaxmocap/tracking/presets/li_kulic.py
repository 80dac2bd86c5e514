"""``li-kulic`` (:data:`LI_KULIC`): Li & Kulić, "A Stereo Camera Based Full Body Human Motion Capture System Using a Partitioned
Particle Filter": the paper's parameters (left) and this preset (right).

=========================================  ===============================================================
Paper                                      ``--preset li-kulic``
=========================================  ===============================================================
25-DOF full body                           ``full25``: root translation 3 + rotation 3 (torso), neck 3
                                           (head), shoulder 3 (upper arm), elbow 1 (forearm), hip 3 (thigh),
                                           knee 1 (calf = the ``*_shin`` segment): the same DOF per part
partitioned sampling, ten partitions:      ``--filter partitioned``, one layer, systematic resampling, the
torso 6 DOF 1000, head 3 200, upper arms   same particle set passed from partition to partition; the order
3 each 500, forearms 1 each 200, thighs    of the paper, left before right within a pair (the paper gives no
3 each 500, calves 1 each 200              side order; parents always come before their children)
each partition weighed by the cues of the  the likelihood's partition table (:mod:`jaxmocap.likelihood.
body parts in it (eq. 1–3 sum over the     partition`): partition k's depth, edge and colour terms average
partition's sample points)                 over its own segment's samples; its ground term counts its own
                                           ankle (calves only)
depth cue (eq. 1): mean |z − D| of the     ``depth``: camera-facing samples, observed depth where the pixel is
front-surface sample points, a penalty     foreground, penalty 2.8 m, scaled to [0, 1]; on the input's depth
off the foreground                         maps (a sequence's depth/, or ``--depth``)
edge cue (eq. 2): fraction of projected    ``edge_fraction``: Canny edge map, contour samples off the edges
model contour pixels off the Canny edges
colour cue (eq. 3): RGB distance to the    ``colour_template``: each surface sample's colour at the first
first frame's colour at each sample point  tracked frame (the initial pose)
distance cue: wrist bands and ground       ``wristband``: bands found by colour in the stereo pair
                                           (:mod:`jaxmocap.features.bands`, lime by default), matched and
                                           triangulated, each model wrist's distance to the nearest band up to
                                           0.5 m, scaled to [0, 1] (weighs the forearm partitions; 0 when no
                                           band is seen); ``ground``: ankles below the floor z = 0
each distance d turned into w = A^(−d),    the ``li-kulic`` λ table: λ = ln 100 for every cue, cue weights
A = 100, combined as a product (eq. 4)     (exponents) 1: ``p = Π_c 100^(−k_c d_c)``
sample points on the front surface, 15–75  600 flesh samples spread over the ten primitives in proportion to
per cone in proportion to its area         their area (23–179 per segment on ``full25``: the torso has more than
                                           75, the forearms fewer than 30); the facing test keeps the front
                                           ones per view
background subtraction against a          ``--foreground auto``: the input's masks when it has them, else
background image                           subtraction against each camera's empty-scene plate (``plate``:
                                           a sequence folder's ``background.png``, ``--plates`` with videos),
                                           else a median background of the run's frames (a subject that stays
                                           in one place leaves the median without a background where it
                                           stands); ``--foreground plate`` insists on the plates
=========================================  ===============================================================

Every option above can be overridden (``--particles``, ``--cues NAME:EXPONENT,…``, ``--filter``, …).

Missing or different here: the paper's bands are black, which colour alone cannot tell from hair, shadows and dark
clothing, so the band detector looks for one saturated colour (the synthesiser draws lime bands; a real
recording gives the box of the bands worn, :data:`jaxmocap.features.bands.LIME` for the format); the paper's
exponents of eq. 4
are not recorded in this project (all 1 here; give others with ``--cues``); its dynamics (this preset keeps the
tracker's random walk with the damped constant-velocity root, ``--velocity``) and its initialisation
(``--init``: ground truth when the input has it, else IK from detections).
"""

from jaxmocap.tracking.presets.base import Partition, Preset

_LI_KULIC_PARTITIONS = (
    Partition("torso", ("torso",), 1000),
    Partition("head", ("head",), 200),
    Partition("left upper arm", ("left_upper_arm",), 500),
    Partition("right upper arm", ("right_upper_arm",), 500),
    Partition("left forearm", ("left_forearm",), 200),
    Partition("right forearm", ("right_forearm",), 200),
    Partition("left thigh", ("left_thigh",), 500),
    Partition("right thigh", ("right_thigh",), 500),
    Partition("left calf", ("left_shin",), 200),
    Partition("right calf", ("right_shin",), 200),
)
#: ``li-kulic``: Li & Kulić's partitioned filter on ``full25`` (the module docstring's table).
LI_KULIC = Preset(
    name="li-kulic",
    model="full25",
    options=dict(
        model="full25",
        filter="partitioned",
        layers=1,
        particles=[p.particles for p in _LI_KULIC_PARTITIONS],
        cues="depth,edge_fraction,colour_template,wristband,ground",
        refine="none",  # the paper's filter, without the refinement on detections
    ),
    partitions=_LI_KULIC_PARTITIONS,
    schedule="li-kulic",
    partition_cues=True,
)

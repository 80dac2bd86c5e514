"""``iros2007`` (:data:`IROS2007`): Fontmarty, Lerasle & Danès, "Data Fusion within a modified Annealed Particle
Filter dedicated to Human Motion Capture" (IROS 2007): the paper's parameters (left) and this preset (right).

==============================================  ================================================================
Paper                                           ``--preset iros2007``
==============================================  ================================================================
14-DOF upper body: 6 global, 3 per shoulder,    ``upper14`` (head rigid with the torso)
1 per elbow
stereo head on a mobile robot                   any calibrated input with two views or more; the skin blobs
                                                are matched across views 0 and 1
IAPF (Table I): first layer ICONDENSATION-      ``--filter iapf``: the first layer draws from the mixture of
style importance sampling, then annealed        :mod:`jaxmocap.filters.icondensation` (deterministic-mixture
layers                                          weights ``p(z|x) f/q``), the later layers anneal
importance function q: 3D head and hands from   ``--proposal head-hands`` (:mod:`jaxmocap.tracking.head_hands`):
skin blobs triangulated across the pair, the    skin blobs of both views matched under the epipolar constraint
face detector choosing the head blob, IK to     and triangulated, the head chosen by OpenCV's Haar face
the 14-DOF configuration                        detector (else the highest blob), :func:`jaxmocap.fit.ik.
                                                from_head_hands`
mixture (α, β) = (0.8, 0.2) of q and the        ``--detection-fraction 0.8 --dynamics-fraction 0.2`` (no
dynamics                                        share for the initial prior)
N = 200 particles × 3 layers (600 for           ``--particles 200 --layers 3`` (ICONDENSATION / SIR:
ICONDENSATION)                                  ``--filter icondensation --particles 600``)
dynamics exponents α_l = (1, 4, 25),            ``--annealing iros2007``: diffusion std × α_l^(−1/2) =
likelihood exponents β_l = (0.1, 0.4, 1)        (1, 1/2, 1/5), fixed β_l (:meth:`jaxmocap.filters.annealing.
                                                Schedule.iros2007`)
random-walk dynamics                            ``--velocity 0`` (the tracker's per-DOF random walk,
                                                :func:`jaxmocap.tracking.options.diffusion_std`)
edge distance transform, σ_e = 10               ``edge_distance``, ``sigma_px`` 10 (pixels of the processed
                                                images)
ROI colour histograms, Bhattacharyya distance   ``colour_histogram``, ``sigma`` 0.3; references from the first
to the first frame's, σ_ROI = 0.3               tracked frame at the initial pose
3D blob distances, σ_3D = 0.15                  ``blobs3d``, ``sigma_m`` 0.15 (metres)
skin colour at the projected head and hands,    ``skin``, ``sigma`` 0.02 (on ``1 −`` the mean skin probability)
σ_s = 0.02
homogeneous colour, σ_m = 10                    ``homogeneous_colour``, ``sigma`` 10/255 (the paper's colours
                                                are 0–255, ours 0–1)
fusion: product of the cue likelihoods          one Gibbs likelihood ``exp(−Σ_c E_c)`` over the five cues and
                                                both views, every cue weight 1
no background model (the robot moves)           ``--foreground none``
images of 640x480 (the paper's rig)             ``--downsample 4``: the cues read maps at a quarter of the input's
                                                size (160x120 for 640x480 images; the head and hands are found
                                                on the full-size images), the configuration of
                                                ``benchmarks/results/iros2007.md``; σ_e is in those pixels
automatic (re-)initialisation from head and     ``--init head-hands``: the first pose from the head and hands
hands detections (Fig. 5)                       detection, or — nobody seen — the rest pose 3 m in front of the
                                                first camera, counted lost until a head is seen; a person who
                                                appears after frames without one re-initialises the filter
==============================================  ================================================================

Every option above can be overridden (``--particles``, ``--layers``, ``--filter``, ``--cues NAME:WEIGHT`` — a cue
weight k multiplies ``1/(2σ²)``, so ``edge_distance:0.25`` doubles σ_e —, ``--annealing auto`` for Deutscher's rule,
``--proposal auto``, ``--downsample``, ``--dynamics-fraction``, ``--detection-fraction``, ``--init``, ``--foreground``).

Missing or different here: the mixture's reading — α weighs the importance function and β the dynamics, as in
the ICONDENSATION mixture ``α π(x|z) + β p(x_k|x_{k−1}) + (1−α−β) p0(x)`` of the authors' group; the
``blobs3d`` cue reads the three largest skin blobs of the processed pair (:class:`jaxmocap.features.pipeline.
FeatureExtractor`), not the head and hands the proposal chose; the colour-histogram references are taken once, at
the first frame's pose (a run that starts with nobody in view learns them from the background); the face
detector needs faces of about 12 pixels or more in the full-size first view.
"""

from jaxmocap.tracking.presets.base import Preset

#: ``(σ_e, σ_ROI, σ_3D, σ_s, σ_m)`` of IROS 2007 Table II, in the paper's units.
PAPER_SIGMAS = (10.0, 0.3, 0.15, 0.02, 10.0)
#: The paper's five cues, in the order of :data:`PAPER_SIGMAS`.
CUES = ("edge_distance", "colour_histogram", "blobs3d", "skin", "homogeneous_colour")

#: ``iros2007``: Fontmarty et al.'s IAPF on ``upper14`` (the module docstring's table).
IROS2007 = Preset(
    name="iros2007",
    model="upper14",
    options=dict(
        model="upper14",
        filter="iapf",
        particles=200,
        layers=3,
        cues=",".join(CUES),
        foreground="none",
        init="head-hands",
        proposal="head-hands",
        annealing="iros2007",
        dynamics_fraction=0.2,
        detection_fraction=0.8,
        velocity=0.0,
        refine="none",  # the paper's system, without the refinement on detections
        downsample=4,
    ),
    cue_params={
        "edge_distance": {"sigma_px": PAPER_SIGMAS[0]},
        "colour_histogram": {"sigma": PAPER_SIGMAS[1]},
        "blobs3d": {"sigma_m": PAPER_SIGMAS[2]},
        "skin": {"sigma": PAPER_SIGMAS[3]},
        "homogeneous_colour": {"sigma": PAPER_SIGMAS[4] / 255.0},
    },
)

"""``lopez-mendez`` (:data:`LOPEZ_MENDEZ`): López Méndez, "Feature-Based Annealing Particle Filter for Robust Motion
Capture" (UPC 2009): the thesis' tracker as this project reads it (left) and this preset (right).

The thesis' text is not in this project's reach; the equations below are those the project's cues and filters
cite (their docstrings give the formulas), and every value the thesis' text would fix but that is not recorded
here is marked *chosen here* with the reason.

=============================================  ==========================================================
Thesis                                         ``--preset lopez-mendez``
=============================================  ==========================================================
upper body, Table 6.1: 13-D state (base of     ``upper9`` (:func:`jaxmocap.geometry.body.upper9`)
the neck 3, body orientation 1, neck 1,
shoulders 3 + 3, elbows 1 + 1)
two webcams: one frontal, one lateral, slight  the input's calibration (``jaxmocap synth --rig
down-tilt                                      frontal-lateral`` renders this rig)
adaptive single Gaussian per pixel and         ``--foreground adaptive`` (:class:`jaxmocap.tracking.features.
channel, eq. 4.1–4.2:                          FeatureBuilder`): ρ = 0.01, k = 3, σ floored at 3 grey
``μ_t = ρ I_t + (1 − ρ) μ_{t−1}``,             levels and started at 4 (*chosen here*), the mean started
``σ²_t = ρ (I_t − μ_t)² + (1 − ρ) σ²_{t−1}``,  from the median of the run's frames (*chosen here*: not the
foreground where ``|I − μ| > k σ``             first frame, which holds the subject); only background
                                               pixels learned (*chosen here*)
shadow model: a darker copy of the             brightness distortion 0.4 ≤ α < 1.2 and chromaticity
background colour is background                distortion ≤ 6 σ (Horprasert et al.;
                                               :data:`jaxmocap.tracking.features.ADAPTIVE_SHADOW`;
                                               bounds *chosen here*)
foreground match, eq. 4.3:                     ``foreground``: 600 flesh samples (*chosen here*)
``E_v = (1/P) Σ_p (1 − F_v(u_vp))``
head skin, eq. 4.4: fraction of the head's     ``head_skin``: the RGB skin likelihood-ratio map of
camera-facing samples not on skin              :mod:`jaxmocap.features.skin`
edges, eq. 4.5:                                ``edges``: Canny inside the dilated foreground, dilated and
``E_v = (1/Q) Σ_q (1 − Ẽ_v(u_vq))`` on the     smoothed (§4.2); 8 points per silhouette line (*chosen
occluding contours                             here*)
foreground divergence, eq. 4.6: the part of    ``silhouette_divergence``
the observed silhouette the model leaves out
inter-penetration prior, eq. 6.2–6.3:          ``interpenetration``: forearm–torso and forearm–forearm
``Σ max(0, r_i + r_j − d_ij)² / s²``           pairs, s = 0.02 m (*chosen here*)
Gibbs likelihood with per-layer feature        ``log p_l = −Σ_c λ_c(l) k_c Σ_v E_c,v`` (:mod:`jaxmocap.
weights (eq. 5.2), ``w ∝ p_l^β``               likelihood.compose`), every cue weight ``k_c = 1`` (the
                                               thesis' weights are not recorded here)
200 particles × 3 layers                       ``particles=200, layers=3`` for every scheme below
APF (Deutscher): β by the survival rate        ``--filter apf``: α_target = 0.5; cues 4.3, 4.4, 4.5 and
                                               the prior (no divergence: Table 7.2 adds it)
M-APF, eq. 6.4: ``β_l = β_{l−1} − ε_l          ``--filter m-apf`` (:func:`jaxmocap.filters.annealing.
(α_target − α_{l−1})``, ``ε_l = 1/(1 + l)``    corrected_beta`), the cues of ``apf``
FBAPF, FBAPF2, FBAPF3, eq. 6.5–6.7: the        ``--filter fbapf`` (the default), ``fbapf2``, ``fbapf3``: all
layers weigh the features differently          five cues, λ tables below (:func:`jaxmocap.likelihood.
                                               compose.schedule_preset`)
APFdivergence (Table 7.2): APF with the        ``--filter apf-divergence`` (a variant of this preset: runs
divergence added                               ``apf`` with all five cues, λ = 1)
=============================================  ==========================================================

The λ tables (layer 0, 1, 2; the filter chooses β on top). The thesis' per-layer tables of eq. 6.5–6.7 are not
recorded here; these are the project's coarse-to-fine reading of them (silhouette cues 4.3, 4.4, 4.6 are coarse,
the edges 4.5 fine; the prior keeps λ = 1):

=========  ====================  ===============  ===============
scheme     foreground, head      edges            prior
           skin, divergence
=========  ====================  ===============  ===============
apf, m-apf 1, 1, 1 (no div.)     1, 1, 1          1, 1, 1
fbapf      1, 1, 1               0, 0.5, 1        1, 1, 1
fbapf2     1, 0.5, 0.25          0, 0.5, 1        1, 1, 1
fbapf3     1, 1, 1               0, 1, 1          1, 1, 1
apf-div.   1, 1, 1               1, 1, 1          1, 1, 1
=========  ====================  ===============  ===============

Every option can be overridden (``--cues``, ``--particles``, ``--foreground``, …); an explicit ``--cues`` replaces
the scheme's cue set.

Missing or different here: the thesis' cue weights and exact schedules (above); its dynamics (the tracker's random
walk with the damped constant-velocity root, ``--velocity``); its initialisation (``--init``: ground truth when the
input has it, else IK from detections); its capture at 9.5 frames/s (the tracker reads recorded frames).

The thesis' own results, the values of its Tables 7.1 and 7.2, are not recorded in this project (no copy of them is
at hand): ``benchmarks/experiments/lopez_mendez.py`` runs every scheme above and checks the thesis' claims on the
numbers it measures (``benchmarks/results/lopez_mendez.md``), never against the thesis' figures.

Speed: the divergence (4.6) tests each of its foreground samples (at most 256 per view, the cue's ``samples``
parameter) against every primitive's projected silhouette, per particle and layer; the samples' undistorted
coordinates are read from a table of the sample grid computed once per calibration
(:func:`jaxmocap.likelihood.cues._prepare_divergence`). ``benchmarks/results/lopez_mendez.md`` gives the frames/s
of every scheme.
"""

from jaxmocap.tracking.presets.base import Preset

#: The thesis' cues: foreground match (4.3), head skin (4.4), edges (4.5), the inter-penetration prior (6.3).
CLASSIC_CUES = "foreground,head_skin,edges,interpenetration"
#: The cues of the feature-based schemes: the classic set and the foreground divergence (4.6).
ALL_CUES = "foreground,head_skin,edges,silhouette_divergence,interpenetration"

#: ``lopez-mendez``: the thesis' tracker (the module docstring's table).
LOPEZ_MENDEZ = Preset(
    name="lopez-mendez",
    model="upper9",
    options=dict(
        model="upper9",
        filter="fbapf",
        particles=200,
        layers=3,
        cues=ALL_CUES,
        foreground="adaptive",
        refine="none",  # the thesis's filters, without the refinement on detections
    ),
    filters={
        "apf": dict(cues=CLASSIC_CUES),
        "m-apf": dict(cues=CLASSIC_CUES),
        "fbapf": dict(cues=ALL_CUES),
        "fbapf2": dict(cues=ALL_CUES),
        "fbapf3": dict(cues=ALL_CUES),
        "apf-divergence": dict(filter="apf", cues=ALL_CUES),
    },
)

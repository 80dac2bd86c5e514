"""The names a tracking run chooses from (body models, filters, foregrounds) and the frame-range syntax, without
importing JAX: the command line builds its parser from them; :mod:`jaxmocap.filters.factory`,
:mod:`jaxmocap.tracking.options` and the synthesis wing use them."""

MODELS = ("upper9", "upper14", "full25", "full32", "parsec31")
FILTERS = (
    "sir",
    "icondensation",
    "apf",
    "iapf",
    "partitioned",
    "hierarchical",
    "fbapf",
    "fbapf2",
    "fbapf3",
    "m-apf",
    "hybrid",
    "apf-refine",
)
#: Filters with annealing layers.
ANNEALED = ("apf", "iapf", "hierarchical", "fbapf", "fbapf2", "fbapf3", "m-apf", "hybrid", "apf-refine")
#: Filters without annealing layers.
SINGLE_LAYER = ("sir", "icondensation", "partitioned")
#: Filters that differentiate the likelihood (:mod:`jaxmocap.filters.hybrid`): their cues read maps bilinearly and
#: use their smooth tests (``cues.DIFFERENTIABLE``).
GRADIENT_FILTERS = ("hybrid", "apf-refine")
#: Filters that split the DOFs into groups, one particle count per group.
PARTITIONED = ("partitioned", "hierarchical")
FOREGROUNDS = ("auto", "mask", "plate", "median", "mog2", "adaptive", "none")
#: Detection-driven poses of ICONDENSATION / IAPF and of re-initialisations (``--proposal``).
PROPOSALS = ("auto", "head-hands")
#: DOFs of the tracker's constant-velocity prediction (``--velocity-dofs``): the root's translation, all of the
#: root's DOFs, every DOF.
VELOCITY_DOFS = ("translation", "root", "all")
#: Refinements of the filter's estimate on the frame's detections (``--refine``; :mod:`jaxmocap.tracking.refine`).
REFINEMENTS = ("auto", "none", "estimate", "track")
#: β rules of the annealed filters (``--annealing``).
ANNEALINGS = ("auto", "iros2007")
#: 2D pose detectors of videos given without keypoints (``--detector``; :mod:`jaxmocap.io.detect`).
DETECTORS = ("auto", "none", "blazepose")
#: Layouts of 2D keypoint files (:mod:`jaxmocap.io.keypoints`).
KEYPOINT_LAYOUTS = ("BODY_25", "BODY_25B", "HALPE_26", "COCO_17", "COCO_133", "MEDIAPIPE_33")


def parse_frames(spec: str | tuple[int | None, int | None] | None, num_frames: int) -> tuple[int, int]:
    """``"A:B"`` (either side may be empty; Python slice bounds, negative from the end) → ``(a, b)`` with
    ``0 ≤ a < b ≤ num_frames``."""
    if spec is None:
        a, b = None, None
    elif isinstance(spec, str):
        parts = spec.split(":")
        if len(parts) != 2:
            raise ValueError(f"frames must be A:B, got {spec!r}")
        try:
            a, b = (int(p) if p.strip() else None for p in parts)
        except ValueError:
            raise ValueError(f"frames must be A:B with integers, got {spec!r}") from None
    else:
        a, b = spec
    a, b, _ = slice(a, b).indices(num_frames)
    if a >= b:
        raise ValueError(f"frame range {spec!r} is empty for a clip of {num_frames} frames")
    return a, b

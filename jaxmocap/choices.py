"""The names a tracking run chooses from (body models, filters, foregrounds), without importing JAX: the command
line builds its parser from them; :mod:`jaxmocap.filters.factory` and :mod:`jaxmocap.tracking.options` use them."""

MODELS = ("upper9", "upper14", "full25", "parsec31")
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
#: Filters that differentiate the likelihood (:mod:`jaxmocap.filters.hybrid`): their cues use bilinear lookups.
GRADIENT_FILTERS = ("hybrid", "apf-refine")
#: Filters that split the DOFs into groups, one particle count per group.
PARTITIONED = ("partitioned", "hierarchical")
FOREGROUNDS = ("auto", "mask", "median", "mog2", "none")

"""Named tracker configurations that follow a paper: ``jaxmocap track --preset NAME``, ``preset = "NAME"`` in a
``--config`` file, ``jaxmocap.track(preset=NAME)`` or :meth:`jaxmocap.tracking.options.TrackOptions.from_preset`.

A preset is plain data (:class:`Preset`):

* ``options`` — values of :class:`~jaxmocap.tracking.options.TrackOptions` fields. They sit under everything given
  explicitly: an option on the command line, in the configuration file or as a keyword overrides the preset's
  value (:func:`apply`; precedence command line > file > preset > per-model defaults). The options that only make
  sense for the preset's filter (``particles``, ``layers``) are left out when another filter is chosen.
* what is not an option: ``partitions`` (:class:`Partition`: the body parts whose DOFs a partition samples and
  whose cues weigh it, and its particle count; used by the partitioned and hierarchical filters, in this order),
  ``schedule`` (the λ table of :func:`jaxmocap.likelihood.compose.schedule_preset`), ``cue_params`` (static
  parameters per cue) and ``partition_cues`` (weigh each partition with the cues of its own body parts,
  :mod:`jaxmocap.likelihood.partition`).
* ``filters`` — options per filter the preset knows (e.g. the cues of each annealing scheme), laid over
  ``options`` when that filter is chosen and under what is given explicitly; a name there that is no filter is a
  *variant* (:data:`VARIANTS`): ``--filter VARIANT`` with the preset runs the filter its entry names.

Each paper's preset lives in a module of its own that puts the paper's parameters beside the values chosen here
and lists what differs or is missing: :mod:`.li_kulic` (``li-kulic``), :mod:`.lopez_mendez` (``lopez-mendez``),
:mod:`.iros2007` (``iros2007``).
"""

from __future__ import annotations

from collections.abc import Mapping

from jaxmocap.choices import FILTERS, PARTITIONED
from jaxmocap.tracking.presets.base import FILTER_OPTIONS, Partition, Preset
from jaxmocap.tracking.presets.iros2007 import IROS2007
from jaxmocap.tracking.presets.li_kulic import LI_KULIC
from jaxmocap.tracking.presets.lopez_mendez import LOPEZ_MENDEZ

__all__ = [
    "IROS2007",
    "LI_KULIC",
    "LOPEZ_MENDEZ",
    "PRESETS",
    "VARIANTS",
    "Partition",
    "Preset",
    "apply",
    "get",
    "partition_layout",
]

#: The presets by name.
PRESETS: dict[str, Preset] = {p.name: p for p in (LI_KULIC, LOPEZ_MENDEZ, IROS2007)}

#: The presets' variants (``--filter`` names that only a preset knows) → the presets that define them.
VARIANTS: dict[str, tuple[str, ...]] = {}
for _p in PRESETS.values():
    for _name in _p.filters:
        if _name not in FILTERS:
            VARIANTS[_name] = (*VARIANTS.get(_name, ()), _p.name)


def get(name: str) -> Preset:
    """The preset ``name``; ``ValueError`` naming the known ones otherwise."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")
    return PRESETS[name]


def apply(values: Mapping[str, object]) -> dict:
    """``values`` (option names → values given explicitly) with the options of ``values["preset"]`` under them
    (module docstring); ``values`` itself when it names no preset."""
    name = values.get("preset")
    chosen = values.get("filter")
    if name is None:
        if chosen in VARIANTS:
            raise ValueError(
                f"filter {chosen!r} is a variant of preset {' / '.join(VARIANTS[chosen])}: add --preset "
                f"{VARIANTS[chosen][0]}"
            )
        return dict(values)
    preset = get(str(name))
    if chosen in VARIANTS and chosen not in preset.filters:
        raise ValueError(
            f"preset {preset.name!r} has no variant {chosen!r} (it is one of {', '.join(VARIANTS[chosen])})"
        )
    base = dict(preset.options)
    if chosen is not None and chosen != base.get("filter") and chosen not in preset.filters:
        for key in FILTER_OPTIONS:
            base.pop(key, None)
    own = preset.filters.get(chosen if chosen is not None else base.get("filter"), {})
    base.update(own)
    base.update({k: v for k, v in values.items() if v is not None})
    if "filter" in own:  # a variant runs the filter its entry names
        base["filter"] = own["filter"]
    return base


def partition_layout(preset: Preset | None, model, filter_name: str):
    """``(DOF groups, segment sets)`` of the preset's partitions on ``model`` for ``filter_name``, or
    ``(None, None)`` when the filter is not partitioned or the preset has no partitions. ``ValueError`` when the
    model lacks a body part of a partition or a partition has no DOF."""
    if preset is None or not preset.partitions or filter_name not in PARTITIONED:
        return None, None
    names = model.segment_names
    missing = [s for p in preset.partitions for s in p.segments if s not in names]
    if missing:
        raise ValueError(
            f"preset {preset.name!r} partitions the {preset.model} body; {model.name} has no "
            f"{', '.join(missing)} (use --model {preset.model})"
        )
    groups, parts = [], []
    for p in preset.partitions:
        dofs = tuple(d for s in p.segments for d in model.topology.segment_dofs[names.index(s)])
        if not dofs:
            raise ValueError(f"partition {p.name!r} of preset {preset.name!r} has no DOF on {model.name}")
        groups.append(dofs)
        parts.append(p.segments)
    return tuple(groups), tuple(parts)

"""The data of a preset (:mod:`jaxmocap.tracking.presets`): :class:`Preset` and :class:`Partition`."""

from __future__ import annotations

import dataclasses
import types
from collections.abc import Mapping

#: Options of a preset that belong to its filter: dropped when another filter is chosen explicitly.
FILTER_OPTIONS = ("particles", "layers")


@dataclasses.dataclass(frozen=True)
class Partition:
    """One partition of partitioned sampling: ``name``, the body parts (segment names) whose DOFs it samples and
    whose cues weigh it (``segments``), and its particle count ``particles``."""

    name: str
    segments: tuple[str, ...]
    particles: int


@dataclasses.dataclass(frozen=True)
class Preset:
    """A named configuration (module docstring). ``model``: the body model the partitions are written for.
    ``filters``: options per filter name, laid over ``options`` when that filter is chosen; a name that is not one
    of :data:`jaxmocap.choices.FILTERS` is a *variant* of the preset (``--filter NAME`` with the preset) and its
    entry names the filter it runs under ``"filter"``."""

    name: str
    options: Mapping[str, object]
    model: str | None = None
    partitions: tuple[Partition, ...] = ()
    schedule: str | None = None
    cue_params: Mapping[str, Mapping[str, object]] = dataclasses.field(default_factory=dict)
    partition_cues: bool = False
    filters: Mapping[str, Mapping[str, object]] = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "options", types.MappingProxyType(dict(self.options)))
        object.__setattr__(
            self,
            "filters",
            types.MappingProxyType({k: types.MappingProxyType(dict(v)) for k, v in self.filters.items()}),
        )

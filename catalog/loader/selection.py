"""Which episodes of an opened dataset to keep: the filters of ``catalog.open`` and
:meth:`catalog.loader.dataset.FrameDataset.select`, checked once, then matched per episode."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from catalog.loader.index import Episode
from schemas.errors import SpecError
from schemas.names import shorten
from schemas.objects import OBJECTS
from schemas.scene import COMPLEX_MOTION_TYPES, INTERCEPT_SECONDS, MOTION_TYPES

#: The motion types a filter may name (an episode built from a user's spec file is ``custom``).
FILTER_MOTION_TYPES = (*MOTION_TYPES, *COMPLEX_MOTION_TYPES, "custom")


def _choices(name: str, value: str | Iterable[str] | None, allowed: Iterable[str]) -> frozenset[str] | None:
    if value is None:
        return None
    if isinstance(value, str):
        values = {value}
    elif isinstance(value, Iterable) and not isinstance(value, (bytes, Mapping)):
        values = set()
        for v in value:
            if not isinstance(v, str):
                raise SpecError(f"{name} must be a string or several, got {shorten(repr(v))} in {shorten(repr(value))}")
            values.add(v)
    else:
        raise SpecError(f"{name} must be a string or several, got {shorten(repr(value))}")
    known = set(allowed)
    unknown = sorted(v for v in values if v not in known)
    if unknown:
        raise SpecError(f"{name} {shorten(repr(unknown))} unknown (expected some of {sorted(known)})")
    return frozenset(values)


def _episode_set(value: range | Iterable[int] | int | None) -> frozenset[int] | range | None:
    if value is None or isinstance(value, range):
        return value
    if isinstance(value, (int, np.integer)):
        if isinstance(value, bool):
            raise SpecError(f"episodes must be integers (or a range), got {shorten(repr(value))}")
        return frozenset([int(value)])
    if not isinstance(value, Iterable) or isinstance(value, (str, bytes, Mapping)):
        raise SpecError(f"episodes must be integers (or a range), got {shorten(repr(value))}")
    values = set()
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise SpecError(f"episodes must be integers (or a range), got {shorten(repr(v))}")
        values.add(int(v))
    return frozenset(values)


@dataclass(frozen=True)
class Selection:
    """Filters on an episode's fields; ``None`` keeps every value. Build one with :meth:`of`."""

    motion_type: frozenset[str] | None = None
    intercept_setting: frozenset[str] | None = None
    object: frozenset[str] | None = None
    episodes: frozenset[int] | range | None = None  # on ``episode_index``
    where: Callable[[Episode], bool] | None = None

    @classmethod
    def of(
        cls,
        motion_type: str | Iterable[str] | None = None,
        intercept_setting: str | Iterable[str] | None = None,
        object: str | Iterable[str] | None = None,
        episodes: range | Iterable[int] | int | None = None,
        where: Callable[[Episode], bool] | None = None,
    ) -> Selection:
        """Filters from one value or several each; SpecError naming an unknown value or a
        value of the wrong type (``where`` must be callable)."""
        if where is not None and not callable(where):
            raise SpecError(f"where must be a function of an Episode, got {shorten(repr(where))}")
        return cls(
            _choices("motion_type", motion_type, FILTER_MOTION_TYPES),
            _choices("intercept_setting", intercept_setting, INTERCEPT_SECONDS),
            _choices("object", object, OBJECTS),
            _episode_set(episodes),
            where,
        )

    @property
    def everything(self) -> bool:
        """True when no filter is set."""
        return all(v is None for v in (self.motion_type, self.intercept_setting, self.object, self.episodes,
                                       self.where))

    def describe(self) -> str:
        """The filters that are set, as ``name=values`` (cut short)."""
        parts = [f"{name}={sorted(value)}" for name, value in (
            ("motion_type", self.motion_type), ("intercept_setting", self.intercept_setting), ("object", self.object))
            if value is not None]
        if self.episodes is not None:
            parts.append(f"episodes={shorten(repr(self.episodes if isinstance(self.episodes, range) else sorted(self.episodes)))}")
        if self.where is not None:
            parts.append("where=" + shorten(getattr(self.where, "__name__", repr(self.where)), 60))
        return ", ".join(parts)

    def matches(self, e: Episode) -> bool:
        return (
            (self.motion_type is None or e.motion_type in self.motion_type)
            and (self.intercept_setting is None or e.intercept_setting in self.intercept_setting)
            and (self.object is None or e.object in self.object)
            and (self.episodes is None or e.episode_index in self.episodes)
            and (self.where is None or bool(self.where(e)))
        )


def describe_episodes(episodes: Sequence[Episode]) -> str:
    """What a list of episodes holds, for a message: its count, motion types, intercept
    settings, objects and episode_index range."""
    indices = [e.episode_index for e in episodes]
    kinds = {name: sorted({getattr(e, name) for e in episodes}) for name in ("motion_type", "intercept_setting", "object")}
    return (f"{len(episodes)} episodes: motion_type {kinds['motion_type']}, intercept_setting {kinds['intercept_setting']}, "
            f"object {shorten(repr(kinds['object']), 120)}, episode_index {min(indices)}-{max(indices)}")

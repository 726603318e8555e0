"""The slice registry: which episodes each slice name denotes (the data contract,
``docs/concepts/data-contract.md``, lists the slices).

Nine atomic slices ``{linear,circular,harmonic}-{fast,medium,slow}`` split each motion
type's Figure-4(a) episode count over its three interception settings as evenly as
possible (earlier settings take the remainder). ``test-1k`` is 1,000 held-out episodes
cycling over the nine (type, setting) cells, with its own seed. ``dyana-12m`` is the
union of the nine: its episodes are theirs, in registry order, each keeping its own
slice name, index and seed (its own ``seed`` field is therefore 0 and unused).
The paper's A.11 harder settings are not part of Dyana-12M:
``projectile-{fast,medium,slow}`` (:mod:`generators.projectile`),
``obstacle-{fast,medium,slow}`` (:mod:`generators.obstacles`) and
``irregular-{fast,medium,slow}`` (:mod:`generators.irregular`), 600 episodes each;
``test-irregular`` (99 episodes cycling over the three regular families and three
settings) and ``test-complex`` (300 held-out episodes interleaving the three settings,
:mod:`generators.appendix`).
Episode ``i`` of a slice draws from ``SeedSequence([seed, i])``, so seeds are distinct.
"""

from __future__ import annotations

from dataclasses import dataclass

from schemas.errors import SliceError, SpecError
from schemas.names import did_you_mean, shorten
from schemas.scene import COMPLEX_MOTION_TYPES, INTERCEPT_SECONDS, MOTION_TYPES

#: Figure 4(a): episodes of each motion type in Dyana-12M.
FIGURE4_EPISODES = {"linear": 44_546, "circular": 89_709, "harmonic": 50_463}
SETTINGS = tuple(INTERCEPT_SECONDS)
TEST_SEED = 1_000
#: Paper A.11's irregular-to-regular setting: episodes per interception setting, and the
#: seed of its held-out test set (the three slices take the next seeds).
IRREGULAR_EPISODES = 600
IRREGULAR_SEED = 2_000
#: The projectile and obstacle settings: episodes per interception setting and base seeds
#: (the slices take the next seeds), and the held-out mixed set's size and seed.
APPENDIX_EPISODES = 600
PROJECTILE_SEED = 3_000
OBSTACLE_SEED = 4_000
COMPLEX_EPISODES = 300
COMPLEX_SEED = 5_000
GENERATORS = ("recipe", "irregular", "projectile", "obstacle", "complex")


@dataclass(frozen=True)
class SliceDef:
    """One named slice. Atomic slices have a motion type and a setting; ``test-1k``
    has neither (its episodes cycle over the nine cells); a union lists its ``parts``."""

    name: str
    motion_type: str | None
    intercept_setting: str | None
    episodes: int
    seed: int
    parts: tuple[str, ...] = ()
    #: Who makes the episodes: the Dyana-12M ``recipe``, or a harder setting of paper A.11
    #: (``projectile``, ``obstacle``, ``irregular``, or ``complex`` mixing the three).
    generator: str = "recipe"

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise SpecError(f"slice.name must be a non-empty string, got {shorten(repr(self.name))}")
        if self.motion_type is not None and self.motion_type not in MOTION_TYPES + COMPLEX_MOTION_TYPES:
            raise SpecError(
                f"slice.motion_type must be one of {list(MOTION_TYPES + COMPLEX_MOTION_TYPES)} or None, "
                f"got {shorten(repr(self.motion_type))}"
            )
        if self.generator not in GENERATORS:
            raise SpecError(f"slice.generator must be one of {list(GENERATORS)}, got {shorten(repr(self.generator))}")
        if self.intercept_setting is not None and self.intercept_setting not in SETTINGS:
            raise SpecError(
                f"slice.intercept_setting must be one of {list(SETTINGS)} or None, got {shorten(repr(self.intercept_setting))}"
            )
        if (self.motion_type is None) != (self.intercept_setting is None):
            raise SpecError(f"slice {self.name!r}: motion_type and intercept_setting must both be set or both be None")
        if isinstance(self.episodes, bool) or not isinstance(self.episodes, int) or self.episodes < 1:
            raise SpecError(f"slice.episodes must be an integer >= 1, got {shorten(repr(self.episodes))}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise SpecError(f"slice.seed must be an integer >= 0, got {shorten(repr(self.seed))}")
        object.__setattr__(self, "parts", tuple(self.parts))
        if self.parts and self.motion_type is not None:
            raise SpecError(f"slice {self.name!r}: a union of parts has no single motion type")

    @property
    def atomic(self) -> bool:
        return self.motion_type is not None and self.generator == "recipe"

    @property
    def may_hold_obstacles(self) -> bool:
        """Whether its scenes may hold obstacles (its frames then record the clearance)."""
        return self.generator in ("obstacle", "complex")

    @property
    def union(self) -> bool:
        return bool(self.parts)


def _split(total: int, ways: int) -> list[int]:
    base, extra = divmod(total, ways)
    return [base + (1 if k < extra else 0) for k in range(ways)]


def _registry() -> dict[str, SliceDef]:
    slices: dict[str, SliceDef] = {}
    seed = 0
    for motion_type in MOTION_TYPES:
        for setting, count in zip(SETTINGS, _split(FIGURE4_EPISODES[motion_type], len(SETTINGS))):
            seed += 1
            name = f"{motion_type}-{setting}"
            slices[name] = SliceDef(name, motion_type, setting, count, seed)
    atomic = tuple(slices)
    slices["test-1k"] = SliceDef("test-1k", None, None, 1_000, TEST_SEED)
    total = sum(slices[name].episodes for name in atomic)
    slices["dyana-12m"] = SliceDef("dyana-12m", None, None, total, 0, parts=atomic)
    for family, count, base in (
        ("projectile", APPENDIX_EPISODES, PROJECTILE_SEED),
        ("obstacle", APPENDIX_EPISODES, OBSTACLE_SEED),
        ("irregular", IRREGULAR_EPISODES, IRREGULAR_SEED),
    ):
        for k, setting in enumerate(SETTINGS):
            name = f"{family}-{setting}"
            slices[name] = SliceDef(name, family, setting, count, base + 1 + k, generator=family)
    slices["test-irregular"] = SliceDef("test-irregular", None, None, 99, IRREGULAR_SEED, generator="irregular")
    slices["test-complex"] = SliceDef("test-complex", None, None, COMPLEX_EPISODES, COMPLEX_SEED, generator="complex")
    return slices


#: Every slice, in listing order: the nine atomic slices, ``test-1k``, ``dyana-12m``.
SLICES: dict[str, SliceDef] = _registry()
#: The nine atomic slices in order (types outer, settings inner).
ATOMIC_SLICES: tuple[str, ...] = tuple(name for name, d in SLICES.items() if d.atomic)


def slice_names() -> tuple[str, ...]:
    return tuple(SLICES)


def get_slice(name: str) -> SliceDef:
    """Look a slice up by name; an unknown name raises :class:`SliceError` listing the known ones."""
    if isinstance(name, str) and name in SLICES:
        return SLICES[name]
    raise SliceError(f"unknown slice {shorten(name)!r}{did_you_mean(name, SLICES)} (expected one of: {', '.join(SLICES)})")

"""The Dyana-12M recipe: (slice, episode index) -> :class:`EpisodeSpec`, seeded and pure.

Randomness. Episode ``i`` of a slice with seed ``s`` draws only from
``Generator(PCG64(SeedSequence([s, i])))`` (the stream of
``np.random.default_rng(SeedSequence([s, i]))``). Each attempt draws one block of
:data:`N_DRAWS` doubles, always in this order: object, size, hand, rollout format,
observe window, text template, held-out configuration (used by ``test-1k`` only, drawn
by every episode so the stream layout is the same). An infeasible attempt (the
target would leave the workspace or the view, or move too fast:
:func:`generators.grids.feasible`) is redrawn from the next block of the same
generator; after :data:`MAX_DRAWS` attempts the episode raises :class:`InfeasibleError`.
The blocks of many episodes are computed at once, bit for bit those generators'
(:func:`generators.streams.stream_doubles`).

Motion. The parameter configuration is not drawn but assigned, so every configuration
of the table appears (:mod:`generators.grids`). In an atomic slice, the type-wide
number of episode ``i`` is ``e = i + (episodes of the same type's earlier settings)``
and it takes table row ``e mod TABLE_SIZES[type]``; each type has more episodes than
configurations. ``test-1k`` episode ``i`` belongs to cell ``i mod 9`` of the nine
(type, setting) cells and draws its configuration from the type's held-out rows.
Linear is one ``L`` token, circular one ``A``, harmonic one ``H``.

Timing. ``num_frames = observe + approach (10/20/30 frames) + GRASP_FRAMES +
HOLD_FRAMES``; the motion lasts ``num_frames / FPS`` seconds (one frame more than the
frames need). Observe windows (:data:`WINDOWS`): a share of episodes is direct-act
(no window); otherwise linear targets get a short uniform window of frames, periodic
ones a uniform fraction of their period, clipped. These give Figure 4(c)'s mean
lengths (linear 36, harmonic 64, circular 78 frames).

Everything per episode is elementwise NumPy arithmetic on these draws, so building an
episode alone or in a batch of any size gives the same bits; :func:`slice_summary`
enumerates a slice's choices without building spec objects, and
:func:`summarize_specs` recomputes the same summary from spec objects.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from generators.grids import (
    OBJECT_NAMES,
    OBJECT_RADII,
    OBJECT_SIZES,
    OBJECT_TOPS,
    SIZE_FACTORS,
    config_pool,
    feasible,
)
from generators.streams import stream_doubles
from schemas.errors import InfeasibleError, SpecError
from schemas.motion import ArcToken, HarmonicToken, LineToken, Motion, token_to_dict
from schemas.names import shorten
from schemas.objects import OBJECTS
from schemas.scene import (
    GRASP_FRAMES,
    HANDS,
    HOLD_FRAMES,
    INTERCEPT_SECONDS,
    MOTION_TYPES,
)
from schemas.slices import ATOMIC_SLICES, SLICES, SliceDef, get_slice
from schemas.spec import EpisodeSpec
from schemas.versions import FPS

#: Doubles drawn per attempt: object, size, hand, format, window, text, held-out config.
N_DRAWS = 7
#: Attempts before an episode is declared infeasible.
MAX_DRAWS = 64
#: Episodes enumerated per batch (bounds the generators alive at once).
CHUNK = 16_384
SETTINGS = tuple(INTERCEPT_SECONDS)
APPROACH_FRAMES = {name: round(seconds * FPS) for name, seconds in INTERCEPT_SECONDS.items()}


@dataclass(frozen=True)
class WindowRule:
    """How a motion type's observe window is drawn.

    ``direct_share`` of episodes are direct-act. Otherwise the window is uniform over
    ``[low, high]`` frames, or, with ``period_fraction = (a, b)``, a uniform fraction in
    ``[a, b)`` of the motion's period rounded to frames and clipped to ``[low, high]``.
    """

    direct_share: float
    low: int
    high: int
    period_fraction: tuple[float, float] | None = None


WINDOWS = {
    "linear": WindowRule(0.45, 4, 20),
    "circular": WindowRule(0.1, 24, 100, (0.28, 0.6)),
    "harmonic": WindowRule(0.1, 16, 80, (0.3, 0.8)),
}

MOTION_PHRASES = {
    "linear": "sliding in a straight line",
    "circular": "moving in a circle",
    "harmonic": "swinging back and forth",
}
TEXT_TEMPLATES = (
    "Grasp the moving {object}.",
    "Catch the {object} as it moves.",
    "Pick up the {object} {motion}.",
    "Intercept and grasp the {object} {motion}.",
    "Track the {object} {motion} and grasp it.",
    "Reach for the moving {object} and grasp it.",
)

_CHOICES = (
    "pool_row", "grid_id", "object", "size_index", "hand", "direct", "observe_frames", "num_frames", "text", "attempts",
)
_COLUMNS = ("part", "episode_index", "seed", "motion_type", "setting") + _CHOICES


def _empty(names: tuple[str, ...], n: int) -> dict[str, np.ndarray]:
    return {name: np.zeros(n, dtype=bool if name == "direct" else np.int64) for name in names}


@dataclass(frozen=True, eq=False)
class EpisodeTable:
    """The recipe's choices for a run of episodes: one entry per episode in each column.

    ``part`` indexes ``slice_names`` (the slice each episode belongs to); ``motion_type``,
    ``setting``, ``object``, ``hand`` index :data:`MOTION_TYPES`, :data:`SETTINGS`,
    ``OBJECT_NAMES``, ``HANDS``; ``pool_row`` and ``grid_id`` locate the configuration
    in the type's :func:`config_pool`; ``attempts`` counts the blocks drawn.
    """

    slice_names: tuple[str, ...]
    columns: dict[str, np.ndarray]

    def __len__(self) -> int:
        return len(self.columns["episode_index"])

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]


def _choose(motion_type: str, setting: str, draws: np.ndarray, rows: np.ndarray | None) -> dict[str, np.ndarray]:
    """Map blocks of draws (n, N_DRAWS) to episode choices and their feasibility."""
    pool = config_pool(motion_type)
    rule = WINDOWS[motion_type]
    obj = (draws[:, 0] * len(OBJECT_NAMES)).astype(np.int64)
    size_index = (draws[:, 1] * len(SIZE_FACTORS)).astype(np.int64)
    hand = (draws[:, 2] * len(HANDS)).astype(np.int64)
    direct = draws[:, 3] < rule.direct_share
    if rows is None:
        rows = pool.table_size + (draws[:, 6] * pool.heldout_size).astype(np.int64)
    cols = pool.rows(rows)
    if rule.period_fraction is None:
        window = rule.low + (draws[:, 4] * (rule.high - rule.low + 1)).astype(np.int64)
    else:
        low, high = rule.period_fraction
        fraction = low + draws[:, 4] * (high - low)
        window = np.clip(np.floor(fraction * cols["period_s"] * FPS + 0.5).astype(np.int64), rule.low, rule.high)
    observe = np.where(direct, 0, window)
    num_frames = observe + (APPROACH_FRAMES[setting] + GRASP_FRAMES + HOLD_FRAMES)
    ok = feasible(motion_type, cols, num_frames / FPS, OBJECT_RADII[obj, size_index], OBJECT_TOPS[obj, size_index])
    return {
        "pool_row": rows,
        "grid_id": pool.grid_ids[rows],
        "object": obj,
        "size_index": size_index,
        "hand": hand,
        "direct": direct,
        "observe_frames": observe,
        "num_frames": num_frames,
        "text": (draws[:, 5] * len(TEXT_TEMPLATES)).astype(np.int64),
        "ok": ok,
    }


def _draw_cell(
    motion_type: str, setting: str, seed: int, indices: np.ndarray, rows: np.ndarray | None
) -> dict[str, np.ndarray]:
    """Choices of the given episodes of one (type, setting) cell, redrawing infeasible ones."""
    parts: list[dict[str, np.ndarray]] = []
    for start in range(0, len(indices), CHUNK):
        chunk = indices[start : start + CHUNK]
        chunk_rows = None if rows is None else rows[start : start + CHUNK]
        draws = stream_doubles(seed, chunk, 0, N_DRAWS)
        choice = _choose(motion_type, setting, draws, chunk_rows)
        attempts = np.ones(len(chunk), dtype=np.int64)
        bad = np.flatnonzero(~choice["ok"])
        while len(bad):
            if attempts[bad[0]] >= MAX_DRAWS:
                raise InfeasibleError(
                    f"episode {chunk[bad[0]]} (seed {seed}, {motion_type}-{setting}) "
                    f"found no feasible draw in {MAX_DRAWS} attempts"
                )
            # every episode still in `bad` has failed attempts[bad[0]] times: its next block
            redraw = stream_doubles(seed, chunk[bad], int(attempts[bad[0]]) * N_DRAWS, N_DRAWS)
            again = _choose(motion_type, setting, redraw, None if chunk_rows is None else chunk_rows[bad])
            for name, values in again.items():
                choice[name][bad] = values
            attempts[bad] += 1
            bad = bad[~again["ok"]]
        del choice["ok"]
        choice["attempts"] = attempts
        parts.append(choice)
    if not parts:
        return _empty(_CHOICES, 0)
    return {name: np.concatenate([p[name] for p in parts]) for name in parts[0]}


def _type_offset(definition: SliceDef) -> int:
    """Episodes of the same motion type in the settings before this slice's."""
    return sum(
        SLICES[name].episodes
        for name in ATOMIC_SLICES
        if SLICES[name].motion_type == definition.motion_type
        and SETTINGS.index(SLICES[name].intercept_setting) < SETTINGS.index(definition.intercept_setting)
    )


def _cell(definition: SliceDef) -> tuple[str, str]:
    """An atomic slice's (motion type, interception setting), both set by construction."""
    if definition.motion_type is None or definition.intercept_setting is None:
        raise SpecError(f"slice {definition.name!r} is not one motion type in one setting")
    return definition.motion_type, definition.intercept_setting


def _cell_table(
    definition: SliceDef, indices: np.ndarray, motion_type: str, setting: str, heldout: bool
) -> dict[str, np.ndarray]:
    rows = None
    if not heldout:
        rows = (_type_offset(definition) + indices) % config_pool(motion_type).table_size
    columns = _draw_cell(motion_type, setting, definition.seed, indices, rows)
    n = len(indices)
    columns["episode_index"] = indices.astype(np.int64)
    columns["seed"] = np.full(n, definition.seed, dtype=np.int64)
    columns["motion_type"] = np.full(n, MOTION_TYPES.index(motion_type), dtype=np.int64)
    columns["setting"] = np.full(n, SETTINGS.index(setting), dtype=np.int64)
    return columns


def _table(definition: SliceDef, indices: np.ndarray) -> EpisodeTable:
    """The choices of the given episodes of a slice, in the order given."""
    n = len(indices)
    out = _empty(_COLUMNS, n)
    if definition.union:
        starts = np.cumsum([0] + [SLICES[name].episodes for name in definition.parts])
        which = np.searchsorted(starts, indices, side="right") - 1
        names = definition.parts
        for p, name in enumerate(names):
            mask = which == p
            if mask.any():
                sub = _table(SLICES[name], indices[mask] - starts[p])
                for column in _COLUMNS:
                    out[column][mask] = sub.columns[column]
                out["part"][mask] = p
        return EpisodeTable(names, out)
    if definition.atomic:
        cells = [(np.arange(n), *_cell(definition), False)]
    else:
        cell = indices % len(ATOMIC_SLICES)
        cells = [(np.flatnonzero(cell == c), *_cell(SLICES[name]), True) for c, name in enumerate(ATOMIC_SLICES)]
    for where, motion_type, setting, heldout in cells:
        if len(where):
            columns = _cell_table(definition, indices[where], motion_type, setting, heldout)
            for name, values in columns.items():
                out[name][where] = values
    return EpisodeTable((definition.name,), out)


def _check_count(definition: SliceDef, episodes: int | None) -> int:
    if episodes is None:
        return definition.episodes
    valid = isinstance(episodes, (int, np.integer)) and not isinstance(episodes, bool)
    if not valid or not 0 <= episodes <= definition.episodes:
        raise SpecError(
            f"episodes must be an integer in [0, {definition.episodes}] for slice {definition.name}, got {shorten(repr(episodes))}"
        )
    return int(episodes)


def episode_table(slice_name: str, episodes: int | None = None) -> EpisodeTable:
    """The recipe's choices for the first ``episodes`` episodes of a slice (all by default)."""
    definition = get_slice(slice_name)
    if definition.generator != "recipe":
        raise SpecError(f"{slice_name} is not made by the Dyana-12M recipe (see generators.{definition.generator})")
    return _table(definition, np.arange(_check_count(definition, episodes), dtype=np.int64))


def _token(motion_type: str, row: int, duration: float):
    cols = config_pool(motion_type).cols
    value = {name: float(values[row]) for name, values in cols.items()}
    if motion_type == "linear":
        return LineToken(
            start=(value["start_x"], value["start_z"]),
            direction=value["direction"],
            speed=value["speed"],
            acceleration=value["acceleration"],
            duration=duration,
        )
    if motion_type == "circular":
        return ArcToken(
            centre=(value["centre_x"], value["centre_z"]),
            radius=value["radius"],
            angular_velocity=value["angular_velocity"],
            start_angle=value["start_angle"],
            turn=int(value["turn"]),
            duration=duration,
        )
    return HarmonicToken(
        centre=(value["centre_x"], value["centre_z"]),
        axis=value["axis"],
        amplitude=value["amplitude"],
        frequency=value["frequency"],
        phase=value["phase"],
        duration=duration,
        drift=(value["drift_x"], value["drift_z"]),
    )


def task_text(template: int, object_name: str, motion_type: str) -> str:
    return TEXT_TEMPLATES[template].format(object=object_name.replace("_", " "), motion=MOTION_PHRASES[motion_type])


def _spec(table: EpisodeTable, k: int) -> EpisodeSpec:
    c = table.columns
    motion_type = MOTION_TYPES[c["motion_type"][k]]
    obj, size_index = int(c["object"][k]), int(c["size_index"][k])
    num_frames = int(c["num_frames"][k])
    return EpisodeSpec(
        slice=table.slice_names[c["part"][k]],
        episode_index=int(c["episode_index"][k]),
        seed=int(c["seed"][k]),
        motion_type=motion_type,
        motion=Motion.of(_token(motion_type, int(c["pool_row"][k]), num_frames / FPS)),
        object=OBJECT_NAMES[obj],
        object_size=float(OBJECT_SIZES[obj, size_index]),
        hand=HANDS[c["hand"][k]],
        rollout_format="direct-act" if c["direct"][k] else "observe-before-act",
        intercept_setting=SETTINGS[c["setting"][k]],
        observe_frames=int(c["observe_frames"][k]),
        num_frames=num_frames,
        text=task_text(int(c["text"][k]), OBJECT_NAMES[obj], motion_type),
    )


def spec_for(slice_name: str, index: int) -> EpisodeSpec:
    """Episode ``index`` of a slice. For ``dyana-12m`` the index runs over the nine
    atomic slices concatenated, and the spec keeps its own slice name and index.
    The harder settings' slices come from :mod:`generators.appendix`."""
    definition = get_slice(slice_name)
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < definition.episodes:
        raise SpecError(
            f"episode index must be an integer in [0, {definition.episodes}) for slice {slice_name}, got {shorten(repr(index))}"
        )
    if definition.generator != "recipe":
        from generators.appendix import appendix_spec

        return appendix_spec(definition, int(index))
    return _spec(_table(definition, np.array([int(index)], dtype=np.int64)), 0)


def definition_specs(definition: SliceDef, first: int, end: int) -> list[EpisodeSpec]:
    """Episodes ``[first, end)`` of a slice definition (a registered one, or one whose seed
    was replaced: :mod:`generators.heldout`)."""
    if definition.generator != "recipe":
        from generators.appendix import appendix_spec

        return [appendix_spec(definition, i) for i in range(first, end)]
    table = _table(definition, np.arange(first, end, dtype=np.int64))
    return [_spec(table, k) for k in range(len(table))]


def slice_specs(slice_name: str, episodes: int | None = None) -> Iterator[EpisodeSpec]:
    """The first ``episodes`` specs of a slice (all by default), in order, lazily.

    Arguments are checked now, not on the first ``next``.
    """
    definition = get_slice(slice_name)
    count = _check_count(definition, episodes)

    def generate() -> Iterator[EpisodeSpec]:
        if definition.generator != "recipe":
            yield from (spec_for(slice_name, i) for i in range(count))
            return
        for start in range(0, count, CHUNK):
            table = _table(definition, np.arange(start, min(start + CHUNK, count), dtype=np.int64))
            for k in range(len(table)):
                yield _spec(table, k)

    return generate()


def _summary(
    slice_name: str,
    motion_types: np.ndarray,
    frames: np.ndarray,
    configs: dict[str, set] | dict[str, np.ndarray],
    objects: Iterable[str],
    direct: int,
) -> dict:
    """The stats dict (``catalog stats --json``) from per-episode motion type indices
    and frame counts, each type's configuration identities, and the objects used."""
    used = set(objects)
    by_type = {}
    for t, name in enumerate(MOTION_TYPES):
        mask = motion_types == t
        count = int(mask.sum())
        by_type[name] = {
            "episodes": count,
            "parameter_sets": len(configs[name]),
            "mean_frames": round(float(frames[mask].mean()), 2) if count else None,
        }
    total_frames = int(frames.sum())
    return {
        "slice": slice_name,
        "total_episodes": int(len(frames)),
        "total_frames": total_frames,
        "total_seconds": round(total_frames / FPS, 2),
        "objects": {"categories": len(used), "rolling": sum(1 for o in used if OBJECTS[o].rolling)},
        "rollout_formats": {"observe-before-act": int(len(frames)) - direct, "direct-act": direct},
        "motion_types": by_type,
    }


def summarize_table(slice_name: str, table: EpisodeTable) -> dict:
    """The stats of an enumerated table: configurations counted by grid identity."""
    c = table.columns
    configs = {name: np.unique(c["grid_id"][c["motion_type"] == t]) for t, name in enumerate(MOTION_TYPES)}
    objects = (OBJECT_NAMES[k] for k in np.unique(c["object"]))
    return _summary(slice_name, c["motion_type"], c["num_frames"], configs, objects, int(c["direct"].sum()))


def slice_summary(slice_name: str, episodes: int | None = None) -> dict:
    """``catalog stats``: a slice's counts, enumerated without building spec objects."""
    definition = get_slice(slice_name)
    if definition.generator != "recipe":
        from generators.appendix import appendix_summary

        return appendix_summary(definition, _check_count(definition, episodes))
    return summarize_table(slice_name, episode_table(slice_name, episodes))


def motion_parameters(spec: EpisodeSpec) -> tuple:
    """A spec's parameter configuration: its motion's token parameters, durations aside."""

    def frozen(token) -> tuple:
        items = sorted(token_to_dict(token).items())
        return tuple((k, tuple(v) if isinstance(v, list) else v) for k, v in items if k != "duration")

    base = tuple(frozen(t) for t in spec.motion.base.tokens)
    overlays = tuple((o.start, tuple(frozen(t) for t in o.tokens)) for o in spec.motion.overlays)
    return base, overlays


def summarize_specs(slice_name: str, specs: Iterable[EpisodeSpec]) -> dict:
    """The same stats as :func:`slice_summary`, recomputed from spec objects."""
    types: list[int] = []
    frames: list[int] = []
    configs: dict[str, set] = {name: set() for name in MOTION_TYPES}
    objects: set[str] = set()
    direct = 0
    for spec in specs:
        if spec.motion_type not in configs:
            raise SpecError(f"summarize_specs: spec {spec.episode_id} has motion_type {spec.motion_type!r}")
        types.append(MOTION_TYPES.index(spec.motion_type))
        frames.append(spec.num_frames)
        configs[spec.motion_type].add(motion_parameters(spec))
        objects.add(spec.object)
        direct += spec.rollout_format == "direct-act"
    types_array, frames_array = np.array(types, dtype=np.int64), np.array(frames, dtype=np.int64)
    return _summary(slice_name, types_array, frames_array, configs, objects, direct)


def slice_overview() -> list[dict]:
    """``catalog list``: every slice with its episodes and frames (a union sums its parts)."""
    frames: dict[str, int] = {}
    for name, definition in SLICES.items():
        if definition.generator != "recipe":
            frames[name] = slice_summary(name)["total_frames"]
        elif not definition.union:
            frames[name] = int(episode_table(name)["num_frames"].sum())
    rows = []
    for name, definition in SLICES.items():
        total = sum(frames[p] for p in definition.parts) if definition.union else frames[name]
        rows.append(
            {
                "slice": name,
                "motion_type": definition.motion_type,
                "intercept_setting": definition.intercept_setting,
                "episodes": definition.episodes,
                "frames": total,
                "seed": definition.seed,
            }
        )
    return rows

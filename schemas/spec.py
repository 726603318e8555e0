"""EpisodeSpec: everything that determines one episode, and its JSON form.

A spec comes from the recipe (``generators.recipe``) or from a researcher's JSONL
file. It is validated on construction; ``from_json``/``from_dict`` name the bad field.
"""

from __future__ import annotations

import hashlib
import json
import math
import numbers
from dataclasses import dataclass
from typing import Any

from schemas.errors import SpecError
from schemas.limits import (
    MAX_NUM_FRAMES,
    MAX_OVERLAYS,
    MAX_SPEC_LINE_BYTES,
    MAX_SPECS_FILE_BYTES,
    MAX_TEXT,
    MAX_TRACK_TOKENS,
)
from schemas.motion import Motion
from schemas.names import shorten, validate_name
from schemas.objects import object_category
from schemas.obstacles import Obstacle, obstacles_from_list, obstacles_to_list
from schemas.regular_files import file_kind, open_regular
from schemas.scene import (
    COMPLEX_MOTION_TYPES,
    GRASP_FRAMES,
    HANDS,
    HORIZON_FACTOR,
    INTERCEPT_SECONDS,
    MOTION_TYPES,
    ROLLOUT_FORMATS,
)
from schemas.values import FieldError, LongNumber, load_json, relocate
from schemas.versions import FPS

SPEC_FIELDS = (
    "slice",
    "episode_index",
    "seed",
    "motion_type",
    "motion",
    "object",
    "object_size",
    "hand",
    "rollout_format",
    "intercept_setting",
    "observe_frames",
    "num_frames",
    "text",
)
#: Fields a spec may omit: ``obstacles`` (none by default) and ``disturbance`` (None); each
#: is left out of the JSON when absent, so other specs keep the canonical JSON and hash they
#: always had.
OPTIONAL_FIELDS = ("obstacles", "disturbance")
#: What a disturbance changed (pipeline.loop.disturb).
DISTURBANCE_KINDS = ("speed", "heading")


@dataclass(frozen=True)
class Disturbance:
    """A mid-episode change of the motion (``pipeline eval --disturb``): from ``frame`` on,
    the object's speed was scaled by ``amount`` (``speed``) or its heading turned by
    ``amount`` degrees (``heading``). The motion itself already holds the change; this
    records when and what, for scoring."""

    frame: int
    kind: str
    amount: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "frame", _int("disturbance.frame", self.frame, 0, MAX_NUM_FRAMES))
        _choice("disturbance.kind", self.kind, DISTURBANCE_KINDS)
        amount = self.amount
        if isinstance(amount, bool) or not isinstance(amount, numbers.Real) or not math.isfinite(amount):
            raise FieldError("spec.disturbance.amount", f"must be a finite number, got {shorten(repr(amount))}")
        object.__setattr__(self, "amount", float(amount))

    def to_dict(self) -> dict[str, Any]:
        return {"frame": self.frame, "kind": self.kind, "amount": self.amount}

    @classmethod
    def from_dict(cls, data: Any) -> Disturbance:
        if not isinstance(data, dict) or set(data) != {"frame", "kind", "amount"}:
            raise SpecError(f"spec.disturbance must be an object with frame, kind and amount, got {shorten(repr(data))}")
        return cls(**data)

_MOTION_TYPES = MOTION_TYPES + COMPLEX_MOTION_TYPES + ("custom",)


#: Largest value the shard tables can store (``episode_index``/``seed`` are int64 columns).
_INT64_MAX = 2**63 - 1


def _int(name: str, value: Any, minimum: int, maximum: int) -> int:
    if isinstance(value, LongNumber):
        raise FieldError(f"spec.{name}", f"must be in [{minimum}, {maximum}], got {value!r}")
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        else:
            raise FieldError(f"spec.{name}", f"must be an integer, got {shorten(repr(value))}")
    value = int(value)
    if value < minimum:
        raise FieldError(f"spec.{name}", f"must be >= {minimum}, got {shorten(repr(value))}")
    if value > maximum:
        raise FieldError(f"spec.{name}", f"must be <= {maximum}, got {shorten(repr(value))}")
    return value


def _choice(name: str, value: Any, options: tuple[str, ...]) -> str:
    if value not in options:
        raise FieldError(f"spec.{name}", f"must be one of {list(options)}, got {shorten(repr(value))}")
    return value


@dataclass(frozen=True)
class EpisodeSpec:
    """One episode: the target's motion, the object, the hand and the timing.

    Frames: ``observe`` for ``observe_frames``, ``approach`` until ``intercept_frame``
    (arrival, ``intercept_time_s`` after the first acting frame), ``grasp`` for
    ``GRASP_FRAMES``, then ``hold`` until ``num_frames``.
    """

    slice: str
    episode_index: int
    seed: int
    motion_type: str
    motion: Motion
    object: str
    object_size: float
    hand: str
    rollout_format: str
    intercept_setting: str
    observe_frames: int
    num_frames: int
    text: str
    obstacles: tuple[Obstacle, ...] = ()
    disturbance: Disturbance | None = None

    def __post_init__(self) -> None:
        validate_name("spec.slice", self.slice)
        object.__setattr__(self, "episode_index", _int("episode_index", self.episode_index, 0, _INT64_MAX))
        object.__setattr__(self, "seed", _int("seed", self.seed, 0, _INT64_MAX))
        _choice("motion_type", self.motion_type, _MOTION_TYPES)
        if not isinstance(self.motion, Motion):
            raise SpecError(f"spec.motion must be a Motion, got {shorten(repr(self.motion))}")
        if not isinstance(self.object, str):
            raise SpecError(f"spec.object must be an object category name, got {shorten(repr(self.object))}")
        object_category(self.object)
        size = self.object_size
        if isinstance(size, bool) or not isinstance(size, numbers.Real) or not math.isfinite(size) or size <= 0:
            raise SpecError(f"spec.object_size must be a finite number > 0, got {shorten(size)}")
        low, high = object_category(self.object).size_range
        if not low <= size <= high:
            raise SpecError(
                f"spec.object_size of a {self.object} must be in [{low:.3f}, {high:.3f}] units "
                f"(half to twice its nominal width), got {shorten(size)}"
            )
        object.__setattr__(self, "object_size", float(size))
        _choice("hand", self.hand, HANDS)
        _choice("rollout_format", self.rollout_format, ROLLOUT_FORMATS)
        _choice("intercept_setting", self.intercept_setting, tuple(INTERCEPT_SECONDS))
        object.__setattr__(self, "observe_frames", _int("observe_frames", self.observe_frames, 0, MAX_NUM_FRAMES))
        if self.rollout_format == "direct-act" and self.observe_frames != 0:
            raise SpecError(f"spec.observe_frames must be 0 for direct-act, got {shorten(repr(self.observe_frames))}")
        if self.rollout_format == "observe-before-act" and self.observe_frames < 1:
            raise SpecError(f"spec.observe_frames must be >= 1 for observe-before-act, got {shorten(repr(self.observe_frames))}")
        minimum = self.intercept_frame + GRASP_FRAMES + 1
        object.__setattr__(self, "num_frames", _int("num_frames", self.num_frames, minimum, MAX_NUM_FRAMES))
        needed = (self.num_frames - 1) / FPS
        if self.motion.duration + 1e-9 < needed:
            raise SpecError(
                f"spec.motion lasts {self.motion.duration:.3f} s but {self.num_frames} frames need {needed:.3f} s"
            )
        if not isinstance(self.text, str):
            raise SpecError(f"spec.text must be a string, got {shorten(self.text)}")
        if len(self.text) > MAX_TEXT:
            raise SpecError(f"spec.text holds at most {MAX_TEXT:,} characters, got {len(self.text):,}")
        try:
            self.text.encode("utf-8")
        except UnicodeEncodeError as exc:
            raise SpecError(
                f"spec.text is not valid Unicode text ({exc.reason} at character {exc.start}: "
                f"{shorten(repr(self.text[exc.start]))}), got {shorten(self.text)!r}"
            ) from None
        object.__setattr__(self, "obstacles", obstacles_from_list(self.obstacles))
        if self.disturbance is not None and not isinstance(self.disturbance, Disturbance):
            object.__setattr__(self, "disturbance", Disturbance.from_dict(self.disturbance))
        implied = implied_motion_types(self.motion)
        if self.obstacles:
            implied.add("obstacle")
        if self.motion_type != "custom" and self.motion_type not in implied:
            raise SpecError(
                f"spec.motion_type {shorten(repr(self.motion_type))} contradicts the motion's tokens, which make it "
                f"{' or '.join(repr(t) for t in sorted(implied)) or 'no motion type (only connectors)'}"
            )

    @property
    def fps(self) -> int:
        return FPS

    @property
    def episode_id(self) -> str:
        return f"{self.slice}:{self.episode_index:06d}"

    @property
    def intercept_time_s(self) -> float:
        return INTERCEPT_SECONDS[self.intercept_setting]

    @property
    def approach_frames(self) -> int:
        return round(self.intercept_time_s * FPS)

    @property
    def intercept_frame(self) -> int:
        """Frame at which the palm arrives over the object."""
        return self.observe_frames + self.approach_frames

    @property
    def acting_horizon(self) -> int:
        """Acting frames a closed-loop policy may take: ceil(1.2 x the ground truth's)."""
        return acting_horizon(self.num_frames, self.observe_frames)

    @property
    def rolling(self) -> bool:
        return object_category(self.object).rolling

    def to_dict(self) -> dict[str, Any]:
        out = {name: getattr(self, name) for name in SPEC_FIELDS}
        out["motion"] = self.motion.to_dict()
        if self.obstacles:
            out["obstacles"] = obstacles_to_list(self.obstacles)
        if self.disturbance is not None:
            out["disturbance"] = self.disturbance.to_dict()
        return out

    def to_json(self) -> str:
        """Canonical JSON: sorted keys, no spaces; the input of :attr:`spec_hash`."""
        return json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"), allow_nan=False)

    @property
    def spec_hash(self) -> str:
        return hashlib.sha256(self.to_json().encode()).hexdigest()

    @classmethod
    def from_dict(cls, data: Any) -> EpisodeSpec:
        if not isinstance(data, dict):
            raise SpecError(f"a spec must be a JSON object, got {shorten(repr(data))}")
        missing = [n for n in SPEC_FIELDS if n not in data]
        if missing:
            raise SpecError(f"spec is missing field(s) {missing}")
        unknown = sorted(set(data) - set(SPEC_FIELDS) - set(OPTIONAL_FIELDS))
        if unknown:
            raise SpecError(f"spec has unknown field(s) {unknown}")
        values = dict(data)
        try:
            values["motion"] = Motion.from_dict(data["motion"])
        except SpecError as exc:
            raise relocate(exc, "spec.motion") from None
        if "obstacles" in data:
            values["obstacles"] = obstacles_from_list(data["obstacles"])
        if "disturbance" in data:
            values["disturbance"] = Disturbance.from_dict(data["disturbance"])
        return cls(**values)

    @classmethod
    def from_json(cls, text: str) -> EpisodeSpec:
        return cls.from_dict(load_json("spec", text))


#: Motion type of each token kind; ``C`` (clothoid) only connects the others.
TOKEN_MOTION_TYPES = {"L": "linear", "A": "circular", "H": "harmonic", "P": "projectile"}


def implied_motion_types(motion: Motion) -> set[str]:
    """The motion types a motion may be labelled with: those of its tokens (base and
    overlays), connectors aside, and ``irregular`` for a clothoid chain joined into one
    regular token. A one-token recipe motion has exactly one; a composed
    motion (a line joined to an arc) may be labelled by any of its parts, or ``custom``
    (which any motion may be)."""
    implied = {
        TOKEN_MOTION_TYPES[token.type]
        for track in (motion.base, *motion.overlays)
        for token in track.tokens
        if token.type in TOKEN_MOTION_TYPES
    }
    kinds = [token.type for token in motion.base.tokens]
    if not motion.overlays and len(kinds) >= 2 and set(kinds[:-1]) == {"C"} and kinds[-1] in TOKEN_MOTION_TYPES:
        implied.add("irregular")  # a clothoid chain joined into one regular token
    return implied


def acting_horizon(num_frames, observe_frames):
    """``ceil(HORIZON_FACTOR * (num_frames - observe_frames))`` in exact integer
    arithmetic, for ints or numpy integer arrays."""
    acting = num_frames - observe_frames
    return -((-acting * HORIZON_FACTOR.numerator) // HORIZON_FACTOR.denominator)


def read_specs_jsonl(path: str) -> list[EpisodeSpec]:
    """Load and validate a JSONL file of specs; errors name the file and line."""
    return [spec for _, spec in read_specs_lines(path)]


#: The keys whose value can make a line too long -> (the field, its limit: schemas.limits).
_LONG_FIELDS = {b'"text"': ("text", f"at most {MAX_TEXT:,} characters"),
                b'"base"': ("motion.base", f"at most {MAX_TRACK_TOKENS} tokens"),
                b'"overlays"': ("motion.overlays", f"at most {MAX_OVERLAYS} tracks")}


def overlong_field(head: bytes) -> str:
    """``": its FIELD runs past the cut (at most N ...)"`` for the field of a spec still open
    where an over-long line was cut (the last such key before the cut), or ``""``."""
    key = max(_LONG_FIELDS, key=head.rfind)
    if head.rfind(key) < 0:
        return ""
    name, limit = _LONG_FIELDS[key]
    return f": its {name} runs past the cut ({limit})"


def read_specs_lines(path: str) -> list[tuple[int, EpisodeSpec]]:
    """:func:`read_specs_jsonl` with each spec's line number, for later messages. Only a
    regular file of at most :data:`MAX_SPECS_FILE_BYTES`, with lines of at most
    :data:`MAX_SPEC_LINE_BYTES`, is read (never a device or FIFO, which could stream for ever)."""
    specs: list[tuple[int, EpisodeSpec]] = []
    try:
        opened, status = open_regular(path)
    except (OSError, TypeError, ValueError) as exc:
        raise SpecError(f"cannot read specs file {path}: {getattr(exc, 'strerror', None) or exc}") from exc
    if opened is None:
        raise SpecError(f"specs file {path} is not a regular file ({file_kind(status.st_mode)})")
    if status.st_size > MAX_SPECS_FILE_BYTES:
        opened.close()
        raise SpecError(f"specs file {path} holds {status.st_size:,} bytes, more than the "
                        f"{MAX_SPECS_FILE_BYTES:,} a specs file may hold")
    with opened as handle:
        total = 0
        for lineno, raw in enumerate(iter(lambda: handle.readline(MAX_SPEC_LINE_BYTES + 1), b""), start=1):
            total += len(raw)
            if len(raw) > MAX_SPEC_LINE_BYTES:
                raise SpecError(f"{path}:{lineno}: line longer than {MAX_SPEC_LINE_BYTES:,} bytes (a spec holds less)"
                                f"{overlong_field(raw)}")
            if total > MAX_SPECS_FILE_BYTES:
                raise SpecError(f"specs file {path} grew past the {MAX_SPECS_FILE_BYTES:,} bytes a specs file may hold")
            try:
                line = raw.decode("utf-8")
            except UnicodeDecodeError as exc:
                raise SpecError(f"{path}:{lineno}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
            if not line.strip():
                continue
            try:
                specs.append((lineno, EpisodeSpec.from_json(line)))
            except SpecError as exc:
                raise SpecError(f"{path}:{lineno}: {exc}") from exc
    if not specs:
        raise SpecError(f"specs file {path} holds no spec")
    return specs



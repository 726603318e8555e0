"""Motion tokens: the vocabulary that drives every target (paper 3.1, A.6).

Positions live in the table's XZ plane as ``(x, z)`` pairs in scene units
(1 unit = 10 cm); angles are radians measured from +X toward +Z; times are seconds.

A :class:`Track` is a time-ordered sequence of tokens that meet end to start.
Position continuity at joins holds by construction: every token after the first is
translated so that it begins where the previous one ended (its own position
parameters then fix its shape and phase, not its absolute place). A clothoid
``C`` inherits position, heading, speed and curvature from the token before it,
which makes the join G2.

A :class:`Motion` is a base track plus optional overlay tracks. An overlay acts on
its own interval ``[start, start + duration]`` and adds its displacement since its
start, so overlays compose different degrees of freedom (say a harmonic sway on top
of a line) without breaking continuity (Allen's "during"/"overlaps" relations).

A token type is a frozen dataclass here (its fields, validation, ``type`` letter and
whether it is ``airborne``), listed in :data:`Token` and :data:`TOKEN_TYPES`; its motion
(closed forms, bounds, segments, elevation) is one registered class in
:mod:`generators.primitives`. Those two files are all a new token type touches.
"""

from __future__ import annotations

import json
import math
from dataclasses import MISSING, dataclass, field, fields
from typing import Any, ClassVar

from schemas.errors import SpecError
from schemas.limits import (
    MAX_ACCELERATION,
    MAX_AMPLITUDE,
    MAX_ANGLE,
    MAX_CURVATURE,
    MAX_CURVATURE_SLOPE,
    MAX_FREQUENCY,
    MAX_HEIGHT,
    MAX_OVERLAYS,
    MAX_POSITION,
    MAX_RADIUS,
    MAX_SECONDS,
    MAX_SPEED,
    MAX_TRACK_TOKENS,
    MAX_TURN_RATE,
    MAX_TURNING,
    MIN_RADIUS,
)
from schemas.names import shorten
from schemas.values import (
    FieldError,
    Vec2,
    Vec3,
    finite,
    load_json,
    non_negative,
    pair,
    positive,
    relocate,
    triple,
)

#: Standard gravity in scene units (9.81 m/s^2 = 98.1 units/s^2), the default of ``P``.
STANDARD_GRAVITY = 98.1


def _peak_speed(owner: str, name: str, speed: float) -> None:
    """Refuse a token whose fastest moment exceeds :data:`MAX_SPEED` (a camera shows nothing faster)."""
    if speed > MAX_SPEED:
        raise FieldError(f"{owner}.{name}", f"makes the object reach {speed:.4g} units/s (at most {MAX_SPEED:g})")


@dataclass(frozen=True)
class LineToken:
    """``L``: straight line, r(t) = start + u * (speed t + acceleration t^2 / 2)."""

    start: Vec2
    direction: float
    speed: float
    acceleration: float
    duration: float
    type: ClassVar[str] = "L"
    airborne: ClassVar[bool] = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "start", pair("L", "start", self.start, MAX_POSITION))
        object.__setattr__(self, "direction", finite("L", "direction", self.direction, MAX_ANGLE))
        object.__setattr__(self, "speed", non_negative("L", "speed", self.speed, MAX_SPEED))
        object.__setattr__(self, "acceleration", finite("L", "acceleration", self.acceleration, MAX_ACCELERATION))
        object.__setattr__(self, "duration", positive("L", "duration", self.duration, MAX_SECONDS))
        _peak_speed("L", "acceleration", max(self.speed, abs(self.speed + self.acceleration * self.duration)))


@dataclass(frozen=True)
class ArcToken:
    """``A``: circular arc about ``centre``; ``turn`` +1 turns from +X toward +Z, -1 the other way.

    r(t) = centre + radius * (cos th, sin th), th = start_angle + turn * angular_velocity * t.
    """

    centre: Vec2
    radius: float
    angular_velocity: float
    start_angle: float
    turn: int
    duration: float
    type: ClassVar[str] = "A"
    airborne: ClassVar[bool] = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "centre", pair("A", "centre", self.centre, MAX_POSITION))
        radius = positive("A", "radius", self.radius, MAX_RADIUS)
        if radius < MIN_RADIUS:
            raise FieldError("A.radius", f"must be in [{MIN_RADIUS:g}, {MAX_RADIUS:g}], got {shorten(repr(radius))}")
        object.__setattr__(self, "radius", radius)
        object.__setattr__(self, "angular_velocity",
                           non_negative("A", "angular_velocity", self.angular_velocity, MAX_TURN_RATE))
        object.__setattr__(self, "start_angle", finite("A", "start_angle", self.start_angle, MAX_ANGLE))
        if self.turn not in (1, -1) or isinstance(self.turn, bool):
            raise FieldError("A.turn", f"must be +1 or -1, got {shorten(repr(self.turn))}")
        object.__setattr__(self, "turn", int(self.turn))
        object.__setattr__(self, "duration", positive("A", "duration", self.duration, MAX_SECONDS))
        _peak_speed("A", "angular_velocity", self.radius * self.angular_velocity)


@dataclass(frozen=True)
class HarmonicToken:
    """``H``: simple harmonic motion along ``axis`` (an angle) with optional drift.

    r(t) = centre + (cos axis, sin axis) * amplitude * sin(2 pi frequency t + phase) + drift * t.
    """

    centre: Vec2
    axis: float
    amplitude: float
    frequency: float
    phase: float
    duration: float
    drift: Vec2 = (0.0, 0.0)
    type: ClassVar[str] = "H"
    airborne: ClassVar[bool] = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "centre", pair("H", "centre", self.centre, MAX_POSITION))
        object.__setattr__(self, "axis", finite("H", "axis", self.axis, MAX_ANGLE))
        object.__setattr__(self, "amplitude", non_negative("H", "amplitude", self.amplitude, MAX_AMPLITUDE))
        object.__setattr__(self, "frequency", positive("H", "frequency", self.frequency, MAX_FREQUENCY))
        object.__setattr__(self, "phase", finite("H", "phase", self.phase, MAX_ANGLE))
        object.__setattr__(self, "duration", positive("H", "duration", self.duration, MAX_SECONDS))
        object.__setattr__(self, "drift", pair("H", "drift", self.drift, MAX_SPEED))
        _peak_speed("H", "amplitude", 2.0 * math.pi * self.frequency * self.amplitude + math.hypot(*self.drift))


@dataclass(frozen=True)
class ClothoidToken:
    """``C``: clothoid connector, curvature changing linearly with arc length.

    kappa(s) = curvature + curvature_slope * s at constant speed. After another token it
    inherits position, heading, speed and curvature (a G2 join) and ignores ``start``,
    ``heading``, ``speed`` and ``curvature``; those apply only when it opens a track.
    """

    curvature_slope: float
    duration: float
    start: Vec2 = (0.0, 0.0)
    heading: float = 0.0
    speed: float = 1.0
    curvature: float = 0.0
    type: ClassVar[str] = "C"
    airborne: ClassVar[bool] = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "curvature_slope",
                           finite("C", "curvature_slope", self.curvature_slope, MAX_CURVATURE_SLOPE))
        object.__setattr__(self, "duration", positive("C", "duration", self.duration, MAX_SECONDS))
        object.__setattr__(self, "start", pair("C", "start", self.start, MAX_POSITION))
        object.__setattr__(self, "heading", finite("C", "heading", self.heading, MAX_ANGLE))
        object.__setattr__(self, "speed", non_negative("C", "speed", self.speed, MAX_SPEED))
        object.__setattr__(self, "curvature", finite("C", "curvature", self.curvature, MAX_CURVATURE))
        length = self.speed * self.duration
        turning = (abs(self.curvature) + abs(self.curvature_slope) * length) * length
        if turning > MAX_TURNING:
            raise FieldError("C.curvature_slope", f"turns the heading by up to {turning:.4g} rad over the token "
                             f"(at most {MAX_TURNING:.4g}: 32 turns)")


@dataclass(frozen=True)
class ProjectileToken:
    """``P``: drag-free ballistic flight, the only token that leaves the table plane.

    Horizontally the object moves like a line at the constant velocity
    ``(velocity[0], velocity[2])``; vertically its centre rises ``height`` above its resting
    height at the start (when the token opens the track; after another token it starts at
    that token's end elevation, 0 for planar tokens) with upward speed ``velocity[1]``
    under ``gravity`` (units/s^2, default 9.81 m/s^2). Landing on the table it bounces
    with ``restitution`` (upward speed = restitution x impact speed) until a bounce is
    slower than :data:`generators.ballistics.REST_SPEED`, then slides on. See
    :mod:`generators.ballistics` for the closed forms and the orientation.
    """

    start: Vec2
    velocity: Vec3
    duration: float
    height: float = 0.0
    gravity: float = STANDARD_GRAVITY
    restitution: float = 0.0
    type: ClassVar[str] = "P"
    airborne: ClassVar[bool] = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "start", pair("P", "start", self.start, MAX_POSITION))
        object.__setattr__(self, "velocity", triple("P", "velocity", self.velocity, MAX_SPEED))
        object.__setattr__(self, "duration", positive("P", "duration", self.duration, MAX_SECONDS))
        object.__setattr__(self, "height", non_negative("P", "height", self.height, MAX_HEIGHT))
        object.__setattr__(self, "gravity", positive("P", "gravity", self.gravity, MAX_ACCELERATION))
        restitution = non_negative("P", "restitution", self.restitution)
        if restitution >= 1.0:
            raise FieldError("P.restitution", f"must be < 1 (a bounce loses energy), got {shorten(repr(restitution))}")
        object.__setattr__(self, "restitution", restitution)


Token = LineToken | ArcToken | HarmonicToken | ClothoidToken | ProjectileToken
TOKEN_TYPES: dict[str, type[Token]] = {
    cls.type: cls for cls in (LineToken, ArcToken, HarmonicToken, ClothoidToken, ProjectileToken)
}


def token_to_dict(token: Token) -> dict[str, Any]:
    """JSON-ready dict with ``type`` first; pairs become lists."""
    out: dict[str, Any] = {"type": token.type}
    for f in fields(token):
        value = getattr(token, f.name)
        out[f.name] = list(value) if isinstance(value, tuple) else value
    return out


def token_from_dict(data: Any) -> Token:
    """Validate and build a token from its dict; names the bad field on error."""
    if not isinstance(data, dict):
        raise FieldError("token", f"must be an object, got {shorten(repr(data))}")
    if "type" not in data:
        raise FieldError("token", f"is missing field 'type' (one of {sorted(TOKEN_TYPES)}), got {shorten(repr(data))}")
    kind = data["type"]
    cls = TOKEN_TYPES.get(kind) if isinstance(kind, str) else None
    if cls is None:
        raise FieldError("token.type", f"is an unknown token type {shorten(repr(kind))} (expected one of "
                         f"{sorted(TOKEN_TYPES)})")
    names = {f.name for f in fields(cls)}
    unknown = sorted(str(k) for k in set(data) - names - {"type"})
    if unknown:
        raise FieldError("token", f"({kind}) has unknown field(s) {unknown}")
    required = [f.name for f in fields(cls) if f.default is MISSING]
    missing = [n for n in required if n not in data]
    if missing:
        raise FieldError("token", f"({kind}) is missing field(s) {missing}")
    return cls(**{k: v for k, v in data.items() if k != "type"})


def _tokens(where: str, items: list[Any]) -> tuple[Token, ...]:
    """The tokens of the JSON list at ``where`` (``motion.base``); errors name the token's path."""
    if len(items) > MAX_TRACK_TOKENS:
        raise FieldError(where, f"holds at most {MAX_TRACK_TOKENS} tokens, got {len(items):,}")
    tokens = []
    for i, item in enumerate(items):
        try:
            tokens.append(token_from_dict(item))
        except SpecError as exc:
            raise relocate(exc, f"{where}[{i}]") from None
    return tuple(tokens)


def _track(where: str, tokens: tuple[Token, ...], start: Any = 0.0) -> Track:
    try:
        return Track(tokens, start)
    except SpecError as exc:
        raise relocate(exc, where) from None


@dataclass(frozen=True)
class Track:
    """Tokens that meet end to start, beginning at ``start`` seconds."""

    tokens: tuple[Token, ...]
    start: float = 0.0

    def __post_init__(self) -> None:
        tokens = tuple(self.tokens) if isinstance(self.tokens, (tuple, list)) else self.tokens
        if not isinstance(tokens, tuple) or not tokens:
            raise FieldError("track", "needs at least one token, got none" if isinstance(tokens, tuple) else
                             f"must be a list of tokens, got {shorten(repr(self.tokens))}")
        if len(tokens) > MAX_TRACK_TOKENS:
            raise FieldError("track", f"holds at most {MAX_TRACK_TOKENS} tokens, got {len(tokens):,}")
        for token in tokens:
            if not isinstance(token, tuple(TOKEN_TYPES.values())):
                raise FieldError("track", f"holds something that is not a motion token: {shorten(repr(token))}")
        object.__setattr__(self, "tokens", tokens)
        object.__setattr__(self, "start", non_negative("track", "start", self.start, MAX_SECONDS))
        if self.end > MAX_SECONDS:
            raise FieldError("track", f"ends at {self.end:.6g} s (start plus its tokens' durations; at most "
                             f"{MAX_SECONDS:g} s)")

    @property
    def duration(self) -> float:
        return math.fsum(t.duration for t in self.tokens)

    @property
    def end(self) -> float:
        return self.start + self.duration


@dataclass(frozen=True)
class Motion:
    """A base track starting at t = 0 plus additive overlay tracks."""

    base: Track
    overlays: tuple[Track, ...] = field(default=())

    def __post_init__(self) -> None:
        if not isinstance(self.base, Track):
            raise FieldError("motion.base", f"must be a Track, got {shorten(repr(self.base))}")
        if self.base.start != 0.0:
            raise FieldError("motion.base", f"must start at 0, got start={shorten(repr(self.base.start))}")
        if not isinstance(self.overlays, (tuple, list)):
            raise FieldError("motion.overlays", f"must be a sequence of Tracks, got {shorten(repr(self.overlays))}")
        overlays = tuple(self.overlays)
        if len(overlays) > MAX_OVERLAYS:
            raise FieldError("motion.overlays", f"holds at most {MAX_OVERLAYS} tracks, got {len(overlays):,}")
        for i, overlay in enumerate(overlays):
            if not isinstance(overlay, Track):
                raise FieldError(f"motion.overlays[{i}]", f"must be a Track, got {shorten(repr(overlay))}")
            for k, token in enumerate(overlay.tokens):
                if token.airborne:
                    raise FieldError(f"motion.overlays[{i}].tokens[{k}]", f"({token.type}) leaves the table: such a "
                                     "token may only be in the base track, not in an overlay")
        object.__setattr__(self, "overlays", overlays)

    @classmethod
    def of(cls, *tokens: Token) -> Motion:
        """A single-track motion."""
        return cls(Track(tuple(tokens)))

    @property
    def duration(self) -> float:
        """The base track's duration: the motion is defined on [0, duration]."""
        return self.base.duration

    @property
    def airborne(self) -> bool:
        """Whether the object may leave the table (an ``airborne`` token, ``P``, in the base track)."""
        return any(t.airborne for t in self.base.tokens)

    @property
    def token_types(self) -> str:
        """E.g. ``"L"`` or ``"LCA"``: the base track's token letters."""
        return "".join(t.type for t in self.base.tokens)

    def to_dict(self) -> dict[str, Any]:
        return {
            "base": [token_to_dict(t) for t in self.base.tokens],
            "overlays": [{"start": o.start, "tokens": [token_to_dict(t) for t in o.tokens]} for o in self.overlays],
        }

    @classmethod
    def from_dict(cls, data: Any) -> Motion:
        """A motion from its JSON form (a bare list is its base track); errors name the
        field's path, e.g. ``motion.base[2].curvature``."""
        base_path = "motion.base"
        if isinstance(data, list):
            data, base_path = {"base": data}, "motion"
        if not isinstance(data, dict):
            raise FieldError("motion", f"must be an object with 'base', got {shorten(repr(data))}")
        unknown = sorted(str(k) for k in set(data) - {"base", "overlays"})
        if unknown:
            raise FieldError("motion", f"has unknown field(s) {unknown}")
        if "base" not in data:
            raise FieldError("motion", "is missing field 'base'")
        base = data["base"]
        if not isinstance(base, list):
            raise FieldError(base_path, f"must be a list of tokens, got {shorten(repr(base))}")
        items = data.get("overlays", [])
        if not isinstance(items, list):
            raise FieldError("motion.overlays", f"must be a list of tracks, got {shorten(repr(items))}")
        if len(items) > MAX_OVERLAYS:
            raise FieldError("motion.overlays", f"holds at most {MAX_OVERLAYS} tracks, got {len(items):,}")
        overlays = []
        for i, item in enumerate(items):
            where = f"motion.overlays[{i}]"
            if not isinstance(item, dict) or "tokens" not in item:
                raise FieldError(where, f"must be an object with 'tokens', got {shorten(repr(item))}")
            unknown = sorted(str(k) for k in set(item) - {"start", "tokens"})
            if unknown:
                raise FieldError(where, f"has unknown field(s) {unknown}")
            if not isinstance(item["tokens"], list):
                raise FieldError(f"{where}.tokens", f"must be a list of tokens, got {shorten(repr(item['tokens']))}")
            overlays.append(_track(where, _tokens(f"{where}.tokens", item["tokens"]), item.get("start", 0.0)))
        return cls(_track(base_path, _tokens(base_path, base)), tuple(overlays))

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))

    @classmethod
    def from_json(cls, text: str) -> Motion:
        data = load_json("motion", text)
        return cls.from_dict(data)

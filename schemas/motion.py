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
from schemas.names import shorten
from schemas.values import Vec2, Vec3, finite, load_json, non_negative, pair, positive, triple

#: Standard gravity in scene units (9.81 m/s^2 = 98.1 units/s^2), the default of ``P``.
STANDARD_GRAVITY = 98.1


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
        object.__setattr__(self, "start", pair("L", "start", self.start))
        object.__setattr__(self, "direction", finite("L", "direction", self.direction))
        object.__setattr__(self, "speed", non_negative("L", "speed", self.speed))
        object.__setattr__(self, "acceleration", finite("L", "acceleration", self.acceleration))
        object.__setattr__(self, "duration", positive("L", "duration", self.duration))


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
        object.__setattr__(self, "centre", pair("A", "centre", self.centre))
        object.__setattr__(self, "radius", positive("A", "radius", self.radius))
        object.__setattr__(self, "angular_velocity", non_negative("A", "angular_velocity", self.angular_velocity))
        object.__setattr__(self, "start_angle", finite("A", "start_angle", self.start_angle))
        if self.turn not in (1, -1) or isinstance(self.turn, bool):
            raise SpecError(f"A.turn must be +1 or -1, got {shorten(repr(self.turn))}")
        object.__setattr__(self, "turn", int(self.turn))
        object.__setattr__(self, "duration", positive("A", "duration", self.duration))


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
        object.__setattr__(self, "centre", pair("H", "centre", self.centre))
        object.__setattr__(self, "axis", finite("H", "axis", self.axis))
        object.__setattr__(self, "amplitude", non_negative("H", "amplitude", self.amplitude))
        object.__setattr__(self, "frequency", positive("H", "frequency", self.frequency))
        object.__setattr__(self, "phase", finite("H", "phase", self.phase))
        object.__setattr__(self, "duration", positive("H", "duration", self.duration))
        object.__setattr__(self, "drift", pair("H", "drift", self.drift))


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
        object.__setattr__(self, "curvature_slope", finite("C", "curvature_slope", self.curvature_slope))
        object.__setattr__(self, "duration", positive("C", "duration", self.duration))
        object.__setattr__(self, "start", pair("C", "start", self.start))
        object.__setattr__(self, "heading", finite("C", "heading", self.heading))
        object.__setattr__(self, "speed", non_negative("C", "speed", self.speed))
        object.__setattr__(self, "curvature", finite("C", "curvature", self.curvature))


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
        object.__setattr__(self, "start", pair("P", "start", self.start))
        object.__setattr__(self, "velocity", triple("P", "velocity", self.velocity))
        object.__setattr__(self, "duration", positive("P", "duration", self.duration))
        object.__setattr__(self, "height", non_negative("P", "height", self.height))
        object.__setattr__(self, "gravity", positive("P", "gravity", self.gravity))
        restitution = non_negative("P", "restitution", self.restitution)
        if restitution >= 1.0:
            raise SpecError(f"P.restitution must be < 1 (a bounce loses energy), got {shorten(repr(restitution))}")
        object.__setattr__(self, "restitution", restitution)


Token = LineToken | ArcToken | HarmonicToken | ClothoidToken | ProjectileToken
#: Bounds that keep a spec's cost small (the recipe uses one token and no overlay; the
#: episode stage is linear in the token count, these only cap a hostile input).
MAX_TRACK_TOKENS = 256
MAX_OVERLAYS = 16
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
        raise SpecError(f"a token must be an object, got {shorten(repr(data))}")
    if "type" not in data:
        raise SpecError(f"token is missing field 'type' (one of {sorted(TOKEN_TYPES)}), got {shorten(repr(data))}")
    kind = data["type"]
    cls = TOKEN_TYPES.get(kind) if isinstance(kind, str) else None
    if cls is None:
        raise SpecError(f"unknown token type {shorten(repr(kind))} (expected one of {sorted(TOKEN_TYPES)})")
    names = {f.name for f in fields(cls)}
    unknown = sorted(str(k) for k in set(data) - names - {"type"})
    if unknown:
        raise SpecError(f"{kind} token has unknown field(s) {unknown}")
    required = [f.name for f in fields(cls) if f.default is MISSING]
    missing = [n for n in required if n not in data]
    if missing:
        raise SpecError(f"{kind} token is missing field(s) {missing}")
    return cls(**{k: v for k, v in data.items() if k != "type"})


@dataclass(frozen=True)
class Track:
    """Tokens that meet end to start, beginning at ``start`` seconds."""

    tokens: tuple[Token, ...]
    start: float = 0.0

    def __post_init__(self) -> None:
        tokens = tuple(self.tokens) if isinstance(self.tokens, (tuple, list)) else self.tokens
        if not isinstance(tokens, tuple) or not tokens:
            raise SpecError(f"a track needs at least one token, got {shorten(self.tokens)}")
        if len(tokens) > MAX_TRACK_TOKENS:
            raise SpecError(f"a track holds at most {MAX_TRACK_TOKENS} tokens, got {len(tokens):,}")
        for token in tokens:
            if not isinstance(token, tuple(TOKEN_TYPES.values())):
                raise SpecError(f"not a motion token: {shorten(repr(token))}")
        object.__setattr__(self, "tokens", tokens)
        object.__setattr__(self, "start", non_negative("track", "start", self.start))

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
            raise SpecError(f"motion.base must be a Track, got {shorten(repr(self.base))}")
        if self.base.start != 0.0:
            raise SpecError(f"motion.base must start at 0, got start={shorten(repr(self.base.start))}")
        if not isinstance(self.overlays, (tuple, list)):
            raise SpecError(f"motion.overlays must be a sequence of Tracks, got {shorten(repr(self.overlays))}")
        overlays = tuple(self.overlays)
        if len(overlays) > MAX_OVERLAYS:
            raise SpecError(f"a motion holds at most {MAX_OVERLAYS} overlay tracks, got {len(overlays):,}")
        for overlay in overlays:
            if not isinstance(overlay, Track):
                raise SpecError(f"motion overlay must be a Track, got {shorten(repr(overlay))}")
            for token in overlay.tokens:
                if token.airborne:
                    raise SpecError(f"a token that leaves the table ({token.type}) may only be in the base track, "
                                    "not in an overlay")
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
        if isinstance(data, list):
            data = {"base": data}
        if not isinstance(data, dict):
            raise SpecError(f"motion must be an object with 'base', got {shorten(repr(data))}")
        unknown = sorted(str(k) for k in set(data) - {"base", "overlays"})
        if unknown:
            raise SpecError(f"motion has unknown field(s) {unknown}")
        if "base" not in data:
            raise SpecError("motion is missing field 'base'")
        base = data["base"]
        if not isinstance(base, list):
            raise SpecError(f"motion.base must be a list of tokens, got {shorten(repr(base))}")
        items = data.get("overlays", [])
        if not isinstance(items, list):
            raise SpecError(f"motion.overlays must be a list of tracks, got {shorten(repr(items))}")
        overlays = []
        for i, item in enumerate(items):
            if not isinstance(item, dict) or "tokens" not in item:
                raise SpecError(f"motion.overlays[{i}] must be an object with 'tokens', got {shorten(repr(item))}")
            unknown = sorted(str(k) for k in set(item) - {"start", "tokens"})
            if unknown:
                raise SpecError(f"motion.overlays[{i}] has unknown field(s) {unknown}")
            if not isinstance(item["tokens"], list):
                raise SpecError(f"motion.overlays[{i}].tokens must be a list of tokens, got {shorten(repr(item['tokens']))}")
            overlays.append(Track(tuple(token_from_dict(t) for t in item["tokens"]), item.get("start", 0.0)))
        return cls(Track(tuple(token_from_dict(t) for t in base)), tuple(overlays))

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))

    @classmethod
    def from_json(cls, text: str) -> Motion:
        data = load_json("motion", text)
        return cls.from_dict(data)

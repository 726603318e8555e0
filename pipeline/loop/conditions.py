"""Under which protocol a policy is evaluated: observation perturbations, acting latency,
and the repeat index; recorded in the run's manifest (``settings.protocol``) so a score
always says how it was obtained.

* ``latency_frames`` N: the action computed from the observation at frame t takes effect
  at frame t + N; until then the hand keeps its last applied targets (at first, rest).
  The world keeps moving. Deterministic.
* ``realtime``: the policy's measured inference time of each call, rounded up to whole
  frames (``ceil(seconds x fps)``), is the latency of that call's actions, added to
  ``latency_frames``. Not deterministic (it depends on the machine and its load): the
  manifest says so and scoring flags such runs in every table.
* ``perturb``: what the policy sees is perturbed (:mod:`pipeline.loop.perturb`), seeded by
  the episode, the ``repeat`` and the frame.
* ``disturb``: each episode's motion changes once, seeded, after the observe window
  (:mod:`pipeline.loop.disturb`); the run records the disturbed specs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from pipeline.loop.perturb import Perturbation
from schemas.errors import SpecError
from schemas.names import shorten

#: Most frames of latency a run may ask for (2.5 s at 20 FPS).
MAX_LATENCY_FRAMES = 50
#: Most repeats of each episode.
MAX_REPEATS = 64


def _count(name: str, value: Any, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= high:
        raise SpecError(f"{name} must be an integer in [0, {high}], got {shorten(repr(value))}")
    return value


@dataclass(frozen=True)
class EvalProtocol:
    """The evaluation protocol (module docstring); the default is the plain closed loop."""

    latency_frames: int = 0
    realtime: bool = False
    perturb: Perturbation | None = None
    repeat: int = 0
    disturb: bool = False

    def __post_init__(self) -> None:
        _count("--latency-frames", self.latency_frames, MAX_LATENCY_FRAMES)
        _count("repeat", self.repeat, MAX_REPEATS - 1)
        for name in ("realtime", "disturb"):
            if not isinstance(getattr(self, name), bool):
                raise SpecError(f"{name} must be true or false, got {shorten(repr(getattr(self, name)))}")
        if self.perturb is not None and not isinstance(self.perturb, Perturbation):
            raise SpecError(f"perturb must be a Perturbation, got {shorten(repr(self.perturb))}")

    @property
    def plain(self) -> bool:
        return self == EvalProtocol()

    @property
    def deterministic(self) -> bool:
        return not self.realtime

    def to_dict(self) -> dict[str, Any]:
        """The manifest's ``settings.protocol`` (every key, so a reader needs no defaults)."""
        return {
            "latency_frames": self.latency_frames,
            "realtime": self.realtime,
            "deterministic": self.deterministic,
            "perturb": None if self.perturb is None else self.perturb.name,
            "perturb_strength": None if self.perturb is None else self.perturb.strength,
            "repeat": self.repeat,
            "disturb": self.disturb,
        }

    @classmethod
    def from_dict(cls, data: Any) -> EvalProtocol:
        if data is None:
            return cls()
        if not isinstance(data, dict):
            raise SpecError(f"settings.protocol must be an object, got {shorten(repr(data))}")
        perturb = None if data.get("perturb") is None else Perturbation(data["perturb"], data.get("perturb_strength"))
        return cls(
            latency_frames=data.get("latency_frames", 0),
            realtime=data.get("realtime", False),
            perturb=perturb,
            repeat=data.get("repeat", 0),
            disturb=data.get("disturb", False),
        )

"""The policy protocol of the closed loop, and how a policy is named.

A policy has three attributes and two methods:

* ``name`` (str); ``action_horizon`` (int: 1 returns single actions, H > 1 returns
  (H, 18) chunks executed open loop); ``privileged`` (bool: True only for the
  oracle, whose task carries the spec);
* ``reset(task)`` before each episode. ``task`` (:class:`Task`) = ``{"text", "fps",
  "observe_frames", "horizon", "resolution", "hand"}``, plus ``"intercept_time_s"``
  (the interception setting's time, part of the public task description) when the
  runner provides it, plus ``"spec"`` (the spec's JSON) for privileged policies. Nothing
  a policy receives identifies its episode (no id, slice, seed or spec hash);
* ``act(obs) -> ndarray`` (18,) or (H, 18) float32, from the observation
  (:class:`Observation`, described in :mod:`pipeline.loop.env`). Policies are
  deterministic given the same observations.

:func:`make_policy` resolves a reference: a built-in name (:data:`BUILTIN`) or
``module:attribute`` (dots in the attribute walk into it). The attribute may be a
Policy class or factory (called without arguments, it must return a policy), or a
plain function ``obs -> action`` (a callable with one required argument), which is
wrapped by :class:`FunctionPolicy`. The other kinds of reference (``ws://``, ``vlm:``)
and the choice between them are :mod:`pipeline.policy_registry`'s.
"""

from __future__ import annotations

import importlib
import importlib.machinery
import importlib.util
import inspect
from collections.abc import Callable
from pathlib import Path
from typing import Any, NotRequired, Protocol, TypedDict, runtime_checkable

import numpy as np

from schemas.errors import SpecError
from schemas.names import did_you_mean, shorten

#: Built-in policies: name -> "module:class".
BUILTIN = {
    "oracle": "pipeline.policies.oracle:OraclePolicy",
    "still": "pipeline.policies.still:StillPolicy",
    "chase": "pipeline.policies.chase:ChasePolicy",
    "predictive": "pipeline.policies.predictive:PredictivePolicy",
    # blind reference policies (chance levels): pipeline.policies.blind
    "blind-centre": "pipeline.policies.blind:CentrePolicy",
    "blind-sweep": "pipeline.policies.blind:SweepPolicy",
    "blind-first-seen": "pipeline.policies.blind:FirstSeenPolicy",
    "blind-fitted": "pipeline.policies.blind:FittedPolicy",
}
#: The blind reference policies among them (their scores are chance levels).
BLIND = ("blind-centre", "blind-sweep", "blind-first-seen", "blind-fitted")
#: The task keys every policy receives (``intercept_time_s`` and ``spec`` may be added).
TASK_KEYS = ("text", "fps", "observe_frames", "horizon", "resolution", "hand")
#: The interception time a policy assumes when the task does not say (the medium setting).
DEFAULT_INTERCEPT_TIME_S = 1.0


class Observation(TypedDict):
    """What ``act`` receives every step (docs/guides/your-policy.md says what each is)."""

    #: (H, W, 3) uint8 RGB, the JPEG-decoded frame.
    image: np.ndarray
    #: (6,) float32 palm x, y, z, roll, pitch, yaw.
    palm_pose: np.ndarray
    #: (15,) float32 joint angles (radians).
    joint_angles: np.ndarray
    #: (90,) float32: 15 joint frames, each x, y, z, roll, pitch, yaw.
    joint_poses: np.ndarray
    #: (36,) float32: 5 fingertips then the wrist, each x, y, z, roll, pitch, yaw.
    keypoints: np.ndarray
    #: The episode's instruction.
    text: str
    frame_index: int
    #: 0-d float64 array, ``frame_index / 20``.
    timestamp: np.ndarray
    #: (K, H, W, 3) uint8: the observe window in the first observation, (0, H, W, 3) after.
    observe_images: np.ndarray


class Task(TypedDict):
    """What ``reset`` receives before each episode (module docstring)."""

    text: str
    fps: int
    observe_frames: int
    horizon: int
    resolution: int
    hand: str
    intercept_time_s: NotRequired[float]
    #: The spec's JSON, for privileged policies only.
    spec: NotRequired[str]


@runtime_checkable
class Policy(Protocol):
    """What the closed loop calls (module docstring)."""

    name: str
    action_horizon: int
    privileged: bool

    def reset(self, task: Task) -> None: ...

    def act(self, obs: Observation) -> np.ndarray: ...


def state_action(obs: Observation) -> np.ndarray:
    """(18,) float32 action that keeps the hand where the observation shows it."""
    return np.concatenate([np.asarray(obs["palm_pose"], dtype=np.float32)[:3],
                           np.asarray(obs["joint_angles"], dtype=np.float32)]).astype(np.float32)


class FunctionPolicy:
    """A plain function ``obs -> action`` as a policy (not privileged; ``reset`` is a
    no-op; the function may return (18,) or (H, 18))."""

    privileged = False
    action_horizon = 1

    def __init__(self, fn: Callable[[Observation], Any], name: str):
        self.fn = fn
        self.name = name

    def reset(self, task: Task) -> None:
        return None

    def act(self, obs: Observation) -> np.ndarray:
        return np.asarray(self.fn(obs), dtype=np.float32)


def _is_policy(obj: Any) -> bool:
    return all(hasattr(obj, attr) for attr in ("name", "action_horizon", "privileged")) and all(
        callable(getattr(obj, method, None)) for method in ("reset", "act")
    )


def _required_positional(fn: Callable) -> int | None:
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):
        return None
    return sum(
        1
        for p in sig.parameters.values()
        if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD) and p.default is p.empty
    )


def _resolve(ref: str) -> Any:
    module_name, _, attr = ref.partition(":")
    if not module_name or not attr:
        raise SpecError(f"policy reference must be a built-in name {sorted(BUILTIN)} or module:callable, got {shorten(repr(ref))}")
    try:
        target: Any = importlib.import_module(module_name)
    except ImportError as exc:
        raise SpecError(f"policy {shorten(repr(ref))}: cannot import module {module_name!r} ({exc})") from None
    except Exception as exc:  # the module itself fails while importing (SyntaxError, a missing file, ...)
        raise SpecError(f"policy {shorten(repr(ref))}: importing module {module_name!r} raised {type(exc).__name__}: {exc}") from None
    for part in attr.split("."):
        try:
            target = getattr(target, part)
        except AttributeError:
            raise SpecError(f"policy {shorten(repr(ref))}: {module_name!r} has no attribute {attr!r}") from None
    return target


def module_file(ref: str) -> Path | None:
    """The source file of a ``module:callable`` reference's module, found the way an
    import would find it but without running any of its code (a dotted module's parent
    packages are searched, not imported); None when there is none (not found, or not a
    file: a namespace package, a compiled or built-in module)."""
    module_name = ref.partition(":")[0]
    parts = module_name.split(".")
    if not module_name or not all(part.isidentifier() for part in parts):
        return None
    try:
        spec = importlib.util.find_spec(parts[0])
        for part in parts[1:]:
            search = None if spec is None else spec.submodule_search_locations
            spec = None if search is None else importlib.machinery.PathFinder.find_spec(part, list(search))
    except (ImportError, ValueError):
        return None
    origin = None if spec is None else spec.origin
    return Path(origin) if origin and origin.endswith(".py") and Path(origin).is_file() else None


def make_policy(ref: str) -> Policy:
    """A fresh policy for a built-in name or a ``module:callable`` reference.

    Raises SpecError naming the reference when it is unknown, cannot be imported, or
    does not give a policy.
    """
    if not isinstance(ref, str) or not ref:
        raise SpecError(f"policy must be a non-empty string, got {shorten(repr(ref))}")
    target = _resolve(BUILTIN.get(ref, ref)) if (ref in BUILTIN or ":" in ref) else None
    if target is None:
        raise SpecError(f"unknown policy {shorten(repr(ref))}{did_you_mean(ref, BUILTIN)}: "
                        f"expected one of {sorted(BUILTIN)} or module:callable")
    if _is_policy(target) and not inspect.isclass(target):
        return target
    if not callable(target):
        raise SpecError(f"policy {shorten(repr(ref))} is neither a policy nor callable ({type(target).__name__})")
    required = _required_positional(target)
    if inspect.isclass(target) or required == 0:
        try:
            made = target()
        except Exception as exc:
            raise SpecError(f"policy {shorten(repr(ref))}: creating it raised {type(exc).__name__}: {exc}") from None
        if not _is_policy(made):
            raise SpecError(
                f"policy {shorten(repr(ref))}: calling it gave {type(made).__name__}, not a policy "
                "(needs name, action_horizon, privileged, reset(task), act(obs))"
            )
        return made
    if required == 1:
        return FunctionPolicy(target, ref)
    raise SpecError(f"policy {shorten(repr(ref))}: a callable must take no argument (a factory) or one (obs -> action)")

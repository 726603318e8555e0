"""How Dyana's observation, task and action map onto openpi's request and reply dicts.

An openpi request is a flat dict, by default (the LIBERO example's names)::

    "observation/image"  |u1 (H, W, 3)  <- observation["image"]
    "observation/state"  <f4 (21,)      <- palm_pose (6) then joint_angles (15), as the
                                           LeRobot export's observation.state
    "prompt"             str            <- observation["text"]

plus, unless ``extras`` is off, Dyana's other fields under ``dyana/``: ``dyana/joint_poses``,
``dyana/keypoints``, ``dyana/observe_images``, ``dyana/frame_index``, ``dyana/timestamp``,
and, in the first request of an episode, ``dyana/task`` (the reset's task; openpi has no
reset message). openpi policies read the keys they know and ignore the others. The reply's
``"actions"`` is an (H, 18) chunk (or one (18,) row) run open loop. Every name is
configurable (:class:`OpenpiConfig`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from pipeline.loop.actions import float32_copy
from pipeline.loop.spaces import ACTION_WIDTH
from pipeline.remote.protocol import ProtocolError
from schemas.errors import PolicyError, SpecError

STATE_WIDTH = 21
FPS = 20
EXTRA = "dyana/"
#: Dyana's other observation fields: name -> (dtype kind, trailing shape; None = a scalar).
EXTRAS: dict[str, tuple[str, tuple[int, ...] | None]] = {
    "joint_poses": ("f", (90,)),
    "keypoints": ("f", (36,)),
    "observe_images": ("u", (-1, -1, -1, 3)),
    "frame_index": ("i", None),
    "timestamp": ("f", None),
}
TASK = EXTRA + "task"
_BOOL = {"on": True, "true": True, "1": True, "off": False, "false": False, "0": False}


@dataclass(frozen=True)
class OpenpiConfig:
    """The key names (``image``, ``state``, ``prompt``, ``actions``); for a client also
    ``extras`` (send the ``dyana/`` fields), ``steps`` (run the first N rows of each
    chunk, then ask again; None: all rows) and ``name`` (the policy's name; None: the
    server metadata's ``policy``, else ``openpi``)."""

    image: str = "observation/image"
    state: str = "observation/state"
    prompt: str = "prompt"
    actions: str = "actions"
    extras: bool = True
    steps: int | None = None
    name: str | None = None

    def __post_init__(self) -> None:
        keys = (self.image, self.state, self.prompt, self.actions)
        for key in keys:
            if not isinstance(key, str) or not key or key.startswith(EXTRA):
                raise SpecError(f"openpi key names are non-empty strings outside dyana/, got {key!r:.60}")
            if not key.isprintable() or any(0xD800 <= ord(c) <= 0xDFFF for c in key):
                # undecodable argv bytes arrive as lone surrogates, which msgpack cannot send
                raise SpecError(f"openpi key names are printable UTF-8 text, got {key!r:.60}")
        if len(set(keys[:3])) != 3:
            raise SpecError(f"openpi image, state and prompt keys must differ, got {keys[:3]}")
        if not isinstance(self.extras, bool):
            raise SpecError(f"openpi extras must be on or off, got {self.extras!r:.40}")
        if self.steps is not None and (isinstance(self.steps, bool) or not isinstance(self.steps, int) or self.steps < 1):
            raise SpecError(f"openpi steps must be an integer >= 1, got {self.steps!r:.40}")
        if self.name is not None and (not isinstance(self.name, str) or not self.name):
            raise SpecError(f"openpi name must be a non-empty string, got {self.name!r:.40}")

    @classmethod
    def from_pairs(cls, pairs: Iterable[tuple[str, str]]) -> OpenpiConfig:
        """From ``(field, text)`` pairs (a URL query, ``--openpi-key`` flags); SpecError names a bad one."""
        known = {f.name for f in fields(cls)}
        values: dict[str, Any] = {}
        for key, text in pairs:
            if key not in known:
                raise SpecError(f"unknown openpi setting {key!r:.40} (known: {', '.join(sorted(known))})")
            if key in values:
                raise SpecError(f"openpi setting {key!r} given twice")
            values[key] = _parse(key, text)
        return cls(**values)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> OpenpiConfig:
        return cls(**dict(data or {}))

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def wire_keys(self) -> dict[str, str]:
        return {"image": self.image, "state": self.state, "prompt": self.prompt, "actions": self.actions}


def _parse(key: str, text: str) -> Any:
    if key == "extras":
        if text.lower() not in _BOOL:
            raise SpecError(f"openpi extras must be on or off, got {text!r:.40}")
        return _BOOL[text.lower()]
    if key == "steps":
        if not (text.isascii() and text.isdigit() and len(text) <= 9):  # '²' is a digit to str.isdigit
            raise SpecError(f"openpi steps must be an integer >= 1, got {text!r:.40}")
        return int(text)
    return text


# client side: Dyana -> request, reply -> action chunk -----------------------------------


def request_for(obs: Mapping[str, Any], task: Mapping[str, Any] | None, config: OpenpiConfig) -> dict[str, Any]:
    """The openpi request for one Dyana observation; ``task`` (the episode's, without its
    spec) in the first request of an episode."""
    state = np.concatenate([np.asarray(obs["palm_pose"], dtype=np.float32).reshape(-1)[:6],
                            np.asarray(obs["joint_angles"], dtype=np.float32).reshape(-1)])
    request: dict[str, Any] = {
        config.image: np.ascontiguousarray(obs["image"], dtype=np.uint8),
        config.state: state,
        config.prompt: str(obs["text"]),
    }
    if config.extras:
        for name in ("joint_poses", "keypoints"):
            request[EXTRA + name] = np.asarray(obs[name], dtype=np.float32)
        request[EXTRA + "observe_images"] = np.ascontiguousarray(obs["observe_images"], dtype=np.uint8)
        request[EXTRA + "frame_index"] = int(obs["frame_index"])
        request[EXTRA + "timestamp"] = float(obs["timestamp"])
        if task is not None:
            request[TASK] = {k: v for k, v in task.items() if k != "spec"}
    return request


def chunk_from(reply: Mapping[str, Any], config: OpenpiConfig) -> np.ndarray:
    """The reply's actions as a float32 (H, 18) chunk (the first ``steps`` rows), or
    PolicyError naming what is wrong."""
    if config.actions not in reply:
        raise PolicyError(f"openpi reply has no {config.actions!r} (keys: {sorted(map(str, reply))[:8]})")
    value = reply[config.actions]
    if not isinstance(value, np.ndarray) or value.dtype.kind not in "fiu":
        raise PolicyError(f"openpi reply {config.actions!r} must be a real-valued array, got "
                          f"{getattr(value, 'dtype', type(value).__name__)}")
    chunk = float32_copy(value)
    if chunk.ndim == 1:
        chunk = chunk[None]
    if chunk.ndim != 2 or chunk.shape[1] != ACTION_WIDTH or chunk.shape[0] < 1:
        raise PolicyError(f"openpi reply {config.actions!r} has shape {tuple(value.shape)}; Dyana needs (H, {ACTION_WIDTH}) "
                          f"(palm xyz then 15 joint angles per row)")
    if config.steps is not None:
        if chunk.shape[0] < config.steps:
            raise PolicyError(f"openpi reply {config.actions!r} has {chunk.shape[0]} rows, fewer than steps={config.steps}")
        chunk = chunk[: config.steps]
    return chunk


# server side: request -> Dyana observation and task, action -> reply ------------------


def _array(request: Mapping[str, Any], key: str, kind: str, shape: tuple[int, ...]) -> np.ndarray:
    value = request[key]
    ok = isinstance(value, np.ndarray) and (value.dtype == np.uint8 if kind == "u" else value.dtype.kind in "fiu")
    if not ok:
        raise ProtocolError(f"request {key!r} must be a {'uint8' if kind == 'u' else 'real-valued'} array, got "
                            f"{getattr(value, 'dtype', type(value).__name__)}")
    if value.ndim != len(shape) or any(want not in (-1, got) for want, got in zip(shape, value.shape, strict=True)):
        wanted = "(" + ", ".join("N" if n == -1 else str(n) for n in shape) + ")"
        raise ProtocolError(f"request {key!r} must have shape {wanted}, got {tuple(value.shape)}")
    return value


def observation_from(request: Mapping[str, Any], config: OpenpiConfig) -> dict[str, Any]:
    """The Dyana observation in an openpi request (the ``dyana/`` fields it carries
    included), or ProtocolError naming the missing or malformed key."""
    for key in (config.image, config.state, config.prompt):
        if key not in request:
            raise ProtocolError(f"request is missing {key!r} (keys: {sorted(map(str, request))[:10]})")
    image = _array(request, config.image, "u", (-1, -1, 3))
    state = _array(request, config.state, "f", (STATE_WIDTH,)).astype(np.float32)
    prompt = request[config.prompt]
    if not isinstance(prompt, str):
        raise ProtocolError(f"request {config.prompt!r} must be a str, got {type(prompt).__name__}")
    obs: dict[str, Any] = {"image": image, "palm_pose": state[:6].copy(), "joint_angles": state[6:].copy(), "text": prompt}
    for name, (kind, shape) in EXTRAS.items():
        key = EXTRA + name
        if key not in request:
            continue
        if shape is None:
            value = request[key]
            if isinstance(value, bool) or not isinstance(value, int if kind == "i" else (int, float)):
                raise ProtocolError(f"request {key!r} must be {'an int' if kind == 'i' else 'a number'}, got {value!r:.40}")
            obs[name] = value
        else:
            array = _array(request, key, kind, shape)
            obs[name] = array.astype(np.uint8 if kind == "u" else np.float32)
    if "observe_images" in obs and obs["observe_images"].shape[1:] != image.shape:
        raise ProtocolError(f"request {EXTRA}observe_images frames {obs['observe_images'].shape[1:]} differ from the image {image.shape}")
    return obs


def task_from(request: Mapping[str, Any], obs: Mapping[str, Any]) -> dict[str, Any]:
    """The episode's task: the request's ``dyana/task``, else what the request shows (its
    prompt, fps 20, the observe window's length, the image side, the right hand)."""
    if TASK in request:
        task = request[TASK]
        if not isinstance(task, dict):
            raise ProtocolError(f"request {TASK!r} must be a map, got {type(task).__name__}")
        return task
    return {
        "text": obs["text"],
        "fps": FPS,
        "observe_frames": int(obs["observe_images"].shape[0]) if "observe_images" in obs else 0,
        "resolution": int(obs["image"].shape[0]),
        "hand": "right",
    }


def reply_for(action: Any, infer_ms: float, config: OpenpiConfig) -> dict[str, Any]:
    """The openpi reply: the policy's action as a float32 (H, 18) chunk, and its time as
    openpi's server reports it (``server_timing.infer_ms``)."""
    chunk = float32_copy(action)
    if chunk.ndim == 1:
        chunk = chunk[None]
    return {config.actions: chunk, "server_timing": {"infer_ms": float(infer_ms)}}

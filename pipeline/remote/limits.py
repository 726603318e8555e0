"""What a peer may declare, checked before anything it declares is allocated.

A request's bytes are capped by the WebSocket layer (``--max-message-mb``); these caps
bound what those bytes may *ask for* once decoded, so that a hostile peer costs at most
its own connection (docs/reference/bad-input.md, "Policy servers"):

| Cap | Value | What | Why |
| --- | --- | --- | --- |
| `MAX_DEPTH` | 16 | nesting of maps and arrays in one message | a request is 3 deep (task, array map) |
| `MAX_NODES` | 10,000 | values (maps, arrays, numbers, strings) in a message | a request holds ~60; 32 MiB of `{}` is 33 M dicts |
| `MAX_AXIS` | 1,048,576 | each axis of an array | `[0, 2**40, 3]` is empty yet no image |
| `schemas.limits.MAX_NUM_FRAMES` | 1,200 | a task's ``observe_frames`` and ``horizon``, an observe window's length | a spec's own limit |
| `schemas.limits.MAX_RESOLUTION` | 1,024 | a task's ``resolution``, an image's side | the renderer's own limit |

:func:`scan` walks a msgpack message's headers without building it (its cost is bounded
by ``MAX_NODES``); :func:`check_shape`, :func:`check_task` and :func:`check_images` bound
what the decoded message declares. Each raises :class:`~pipeline.remote.protocol.ProtocolError`
naming the part and the cap.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from schemas.errors import PolicyError
from schemas.limits import MAX_NUM_FRAMES, MAX_RESOLUTION, MAX_SECONDS, MAX_SPEC_LINE_BYTES, MAX_TEXT, MIN_RESOLUTION

MAX_DEPTH = 16
MAX_NODES = 10_000
MAX_AXIS = 1 << 20


class LimitError(PolicyError):
    """A message that declares more than a cap allows (the protocols' ProtocolError is raised in its words)."""


# msgpack first bytes -> (bytes of the length field, extra fixed bytes) for the sized kinds
_SIZED = {0xC4: (1, 0), 0xC5: (2, 0), 0xC6: (4, 0),  # bin 8/16/32
          0xD9: (1, 0), 0xDA: (2, 0), 0xDB: (4, 0),  # str 8/16/32
          0xC7: (1, 1), 0xC8: (2, 1), 0xC9: (4, 1)}  # ext 8/16/32 (+ type byte)
_FIXED = {0xC0: 0, 0xC2: 0, 0xC3: 0, 0xCA: 4, 0xCB: 8, 0xCC: 1, 0xCD: 2, 0xCE: 4, 0xCF: 8,
          0xD0: 1, 0xD1: 2, 0xD2: 4, 0xD3: 8, 0xD4: 2, 0xD5: 3, 0xD6: 5, 0xD7: 9, 0xD8: 17}
_CONTAINERS = {0xDC: (2, 1), 0xDD: (4, 1), 0xDE: (2, 2), 0xDF: (4, 2)}  # array 16/32, map 16/32


def scan(data: bytes, max_depth: int = MAX_DEPTH, max_nodes: int = MAX_NODES) -> None:
    """LimitError unless ``data`` is one msgpack value of at most ``max_nodes`` values nested
    at most ``max_depth`` deep, every declared length inside the message (nothing is built)."""
    view = memoryview(data)
    end = len(view)
    pos = nodes = 0
    pending = [1]  # values still to read at each open level; the outermost holds one
    while pending:
        if pending[-1] == 0:
            pending.pop()
            continue
        pending[-1] -= 1
        nodes += 1
        if nodes > max_nodes:
            raise LimitError(f"message holds more than {max_nodes} values (maps, arrays, numbers, strings)")
        if pos >= end:
            raise LimitError(f"not a msgpack message: it ends early, at byte {pos}")
        head = view[pos]
        pos += 1
        children = 0
        if head <= 0x7F or head >= 0xE0:
            continue
        if 0x80 <= head <= 0x9F:  # fixmap, fixarray
            children = (head & 0x0F) * (2 if head <= 0x8F else 1)
        elif 0xA0 <= head <= 0xBF:  # fixstr
            pos += head & 0x1F
        elif head in _FIXED:
            pos += _FIXED[head]
        elif head in _SIZED:
            width, extra = _SIZED[head]
            pos += width + extra + int.from_bytes(view[pos:pos + width], "big")
        elif head in _CONTAINERS:
            width, per = _CONTAINERS[head]
            children = per * int.from_bytes(view[pos:pos + width], "big")
            pos += width
        else:
            raise LimitError(f"not a msgpack message: byte {pos - 1} (0x{head:02x}) starts no value")
        if pos > end:
            raise LimitError(f"not a msgpack message: a value declares more bytes than it holds ({pos} > {end})")
        if children:
            if children > end - pos:  # every value takes at least one byte
                raise LimitError(f"not a msgpack message: a map or array declares {children} entries, more than its bytes")
            if len(pending) >= max_depth:
                raise LimitError(f"message nests maps and arrays more than {max_depth} deep")
            pending.append(children)
    if pos != end:
        raise LimitError(f"not a msgpack message: {end - pos} bytes follow the value")


def check_shape(shape: list[int]) -> None:
    """LimitError when an array axis is longer than ``MAX_AXIS``."""
    for axis, size in enumerate(shape):
        if size > MAX_AXIS:
            raise LimitError(f"array axis {axis} has {size} entries, more than {MAX_AXIS}")


def _whole(task: Mapping[str, Any], key: str, low: int, high: int) -> None:
    value = task.get(key)
    if key not in task:
        return
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise LimitError(f"task {key} must be an integer in [{low}, {high}], got {str(value)[:40]!r}")


def check_task(task: Mapping[str, Any]) -> None:
    """LimitError naming the first field of ``task`` out of its cap (fields a task does not
    carry are left to the policy, as in-process)."""
    _whole(task, "resolution", MIN_RESOLUTION, MAX_RESOLUTION)
    _whole(task, "observe_frames", 0, MAX_NUM_FRAMES)
    _whole(task, "horizon", 0, MAX_NUM_FRAMES)
    _whole(task, "fps", 1, 1_000)
    for key, cap in (("text", MAX_TEXT), ("spec", MAX_SPEC_LINE_BYTES), ("hand", 16)):
        if key in task and (not isinstance(task[key], str) or len(task[key]) > cap):
            raise LimitError(f"task {key} must be a string of at most {cap} characters")
    if "intercept_time_s" in task:
        value = task["intercept_time_s"]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value <= MAX_SECONDS:
            raise LimitError(f"task intercept_time_s must be a number in [0, {MAX_SECONDS:g}], got {str(value)[:40]!r}")


def check_images(obs: Mapping[str, Any], resolution: int | None) -> None:
    """LimitError unless ``image`` is a square (R, R, 3) frame with R in [8, MAX_RESOLUTION]
    (and R the task's ``resolution`` when known) and ``observe_images`` holds at most
    ``MAX_NUM_FRAMES`` such frames."""
    image = obs.get("image")
    if isinstance(image, np.ndarray):
        side = image.shape[0] if image.ndim == 3 else -1
        if image.ndim != 3 or image.shape != (side, side, 3) or not MIN_RESOLUTION <= side <= MAX_RESOLUTION:
            raise LimitError(f"observation image must be (R, R, 3) with R in [{MIN_RESOLUTION}, {MAX_RESOLUTION}], "
                             f"got {tuple(image.shape)}")
        if resolution is not None and side != resolution:
            raise LimitError(f"observation image is {side} px, the task's resolution {resolution}")
    window = obs.get("observe_images")
    if isinstance(window, np.ndarray):
        if window.ndim != 4 or window.shape[0] > MAX_NUM_FRAMES:
            raise LimitError(f"observation observe_images must be (K, R, R, 3) with K <= {MAX_NUM_FRAMES}, "
                             f"got {tuple(window.shape)}")
        if isinstance(image, np.ndarray) and window.shape[0] and window.shape[1:] != image.shape:
            raise LimitError(f"observation observe_images frames {tuple(window.shape[1:])} differ from the image "
                             f"{tuple(image.shape)}")

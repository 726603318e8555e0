"""Items keyed as LeRobot's ``LeRobotDataset`` keys them: ``catalog.open(..., keys="lerobot")``.

A LeRobot policy's training step then takes Dyana batches as they come, with no export
and at Dyana's reading speed. The names are the export's (:mod:`catalog.loader.lerobot_names`):

================================  ============================================================
key                               value (``history=K`` adds a leading K+1 axis to observations)
================================  ============================================================
``observation.images.ego``        (3, H, W) float32 in [0, 1] (``image_dtype="uint8"``: a uint8
                                  channels-first view, no copy)
``observation.state``             (21,) float32: palm pose (6) then joint angles (15)
``observation.environment_state`` (7,) float32: the object's pose
``action``                        (18,) float32, or (H, 18) with ``action_horizon=H``
``<key>_is_pad``                  bool flags of padded history / horizon slots
``timestamp``                     float32 seconds; ``frame_index``, ``episode_index``,
                                  ``index`` (position in the dataset), ``task_index`` int64
``task``                          the episode's instruction
================================  ============================================================

``task_index`` numbers the opened folders' instructions in order of first use, as
``catalog export`` numbers them, whatever episodes a selection keeps.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from catalog.loader.lerobot_names import (
    ACTION_KEY,
    ENV_KEY,
    IMAGE_KEY,
    IMAGE_SOURCE,
    STATE_KEY,
    VECTOR_SOURCES,
    pad_key,
)

KEYS = ("dyana", "lerobot")
IMAGE_DTYPES = ("float32", "uint8")
_PALM_POSE, _JOINT_ANGLES = VECTOR_SOURCES[STATE_KEY]  # observation_features' order
(_ENV_COLUMN,) = VECTOR_SOURCES[ENV_KEY]
(_ACTION_COLUMN,) = VECTOR_SOURCES[ACTION_KEY]
_MAX = np.float32(255.0)


def _planes(image: np.ndarray, out: np.ndarray) -> None:
    """One (H, W, 3) frame into ``out`` (3, H, W), converting to ``out``'s dtype.

    ``cv2.split`` reads the interleaved pixels once, contiguously; a strided transpose
    costs about twice as much at 224 px.
    """
    for c, plane in enumerate(cv2.split(image)):
        out[c] = plane


def _chw(image: np.ndarray, image_dtype: str) -> np.ndarray:
    """(..., H, W, 3) uint8 -> (..., 3, H, W): float32 in [0, 1] (x / 255, as LeRobot's
    decoders compute it), or for uint8 a channels-first view of the decoded frame (no
    copy: a DataLoader's collate copies it into the batch anyway)."""
    if image_dtype == "uint8":
        return np.moveaxis(image, -1, -3)
    frames = image.reshape((-1,) + image.shape[-3:])
    out = np.empty((len(frames), 3) + image.shape[-3:-1], dtype=np.float32)
    for frame, planes in zip(frames, out):
        _planes(frame, planes)
    np.divide(out, _MAX, out=out)
    return out.reshape(image.shape[:-3] + out.shape[1:])


def observation_features(image: np.ndarray, palm_pose: np.ndarray, joint_angles: np.ndarray,
                         image_dtype: str = "float32") -> dict[str, np.ndarray]:
    """What a policy observes, under LeRobot's keys: the image (channels first) and the state
    (its :data:`~catalog.loader.lerobot_names.VECTOR_SOURCES`: the palm pose, then the joint angles).
    The closed loop (:mod:`pipeline.policies.lerobot_adapter`) and :func:`lerobot_item` share it."""
    return {
        IMAGE_KEY: _chw(image, image_dtype),
        STATE_KEY: np.concatenate([palm_pose, joint_angles], axis=-1).astype(np.float32, copy=False),
    }


def lerobot_item(item: dict[str, Any], index: int, task_index: int, image_dtype: str) -> dict[str, Any]:
    """A Dyana item (see :mod:`catalog.loader.dataset`) under LeRobot's keys."""
    out: dict[str, Any] = {
        **observation_features(item[IMAGE_SOURCE], item[_PALM_POSE], item[_JOINT_ANGLES], image_dtype),
        ENV_KEY: item[_ENV_COLUMN],
        ACTION_KEY: item[_ACTION_COLUMN],
        "timestamp": np.float32(item["timestamp"]),
        "frame_index": np.int64(item["frame_index"]),
        "episode_index": np.int64(item["episode_index"]),
        "index": np.int64(index),
        "task_index": np.int64(task_index),
        "task": item["text"],
    }
    if "image_is_pad" in item:
        out[pad_key(IMAGE_KEY)] = item["image_is_pad"]
        out[pad_key(STATE_KEY)] = item[pad_key(_PALM_POSE)]
        out[pad_key(ENV_KEY)] = item[pad_key(_ENV_COLUMN)]
    if pad_key(_ACTION_COLUMN) in item:
        out[pad_key(ACTION_KEY)] = item[pad_key(_ACTION_COLUMN)]
    return out

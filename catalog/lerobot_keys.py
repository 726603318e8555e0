"""Items keyed as LeRobot's ``LeRobotDataset`` keys them: ``catalog.open(..., keys="lerobot")``.

A LeRobot policy's training step then takes Dyana batches as they come, with no export
and at Dyana's reading speed. The mapping is the export's (:mod:`catalog.export.layout`):

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

KEYS = ("dyana", "lerobot")
IMAGE_DTYPES = ("float32", "uint8")
IMAGE_KEY = "observation.images.ego"
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
    """What a policy observes, under LeRobot's keys: the image (channels first) and the state.
    The closed loop (:mod:`pipeline.policies.lerobot_adapter`) and :func:`lerobot_item` share it."""
    return {
        IMAGE_KEY: _chw(image, image_dtype),
        "observation.state": np.concatenate([palm_pose, joint_angles], axis=-1).astype(np.float32, copy=False),
    }


def lerobot_item(item: dict[str, Any], index: int, task_index: int, image_dtype: str) -> dict[str, Any]:
    """A Dyana item (see :mod:`catalog.dataset`) under LeRobot's keys."""
    out: dict[str, Any] = {
        **observation_features(item["image"], item["palm_pose"], item["joint_angles"], image_dtype),
        "observation.environment_state": item["object_pose"],
        "action": item["action"],
        "timestamp": np.float32(item["timestamp"]),
        "frame_index": np.int64(item["frame_index"]),
        "episode_index": np.int64(item["episode_index"]),
        "index": np.int64(index),
        "task_index": np.int64(task_index),
        "task": item["text"],
    }
    if "image_is_pad" in item:
        out[f"{IMAGE_KEY}_is_pad"] = item["image_is_pad"]
        out["observation.state_is_pad"] = item["palm_pose_is_pad"]
        out["observation.environment_state_is_pad"] = item["object_pose_is_pad"]
    if "action_is_pad" in item:
        out["action_is_pad"] = item["action_is_pad"]
    return out

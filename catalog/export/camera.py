"""``meta/camera.json`` of a LeRobot export: the fixed egocentric camera's pinhole
intrinsics at the exported image size and its pose, in Dyana's world and in the MCAP
``world`` frame (the same numbers as a shard's ``/camera/calibration`` and ``/tf``).

A world point ``p`` (Dyana's axes: X right, Y up, Z forward, metres; the frame of
``observation.state``'s palm pose and of ``action``) lands on the exported image at
``K @ (R @ p + t)`` divided by its last element, as (column, row), where ``[R | t]`` is
``world_to_camera``: the optical frame has x right, y down, z forward in the image, and
pixel ``(c, r)``'s centre is at ``(c + 0.5, r + 0.5)``. Dyana's world is left-handed and
the optical frame right-handed, so ``R`` is a reflection (determinant -1).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from catalog.loader.lerobot_names import ACTION_KEY, IMAGE_KEY, STATE_KEY
from catalog.tables.mcap_layout import WORLD_FRAME, camera_calibration, camera_pose
from schemas.scene import CAMERA_EYE, CAMERA_FAR, CAMERA_FOV_DEG, CAMERA_NEAR, CAMERA_TARGET, CAMERA_UP

CAMERA_META = "meta/camera.json"


def world_to_camera() -> np.ndarray:
    """4x4 rigid map (up to the axes' reflection) from Dyana's world to the optical frame."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (CAMERA_EYE, CAMERA_TARGET, CAMERA_UP))
    forward = (target - eye) / np.linalg.norm(target - eye)
    side = np.cross(forward, up)
    side /= np.linalg.norm(side)
    true_up = np.cross(side, forward)
    # The OpenGL view's axes (side, up, -forward), negated: the renderer mirrors its image
    # left-right, so the stored image's columns grow along -side and its rows along -up.
    rotation = -np.stack([side, true_up, -forward])
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = -rotation @ eye
    return out


def _rounded(values: Any) -> Any:
    """Floats rounded to 12 digits, so a last-bit difference of libm never changes the bytes."""
    return (np.round(np.asarray(values, dtype=np.float64), 12) + 0.0).tolist()  # no -0.0


def camera_meta(height: int, width: int) -> dict[str, Any]:
    """What ``meta/camera.json`` holds for images of ``height`` x ``width`` pixels."""
    calibration = camera_calibration(width, height)
    k = calibration["K"]
    position, quaternion = camera_pose()
    return {
        "camera": "ego",
        "video_key": IMAGE_KEY,
        "fixed": True,
        "model": "pinhole",
        "width": width,
        "height": height,
        "fx": _rounded(k[0]),
        "fy": _rounded(k[4]),
        "cx": _rounded(k[2]),
        "cy": _rounded(k[5]),
        "K": _rounded(np.reshape(k, (3, 3))),
        "distortion_model": calibration["distortion_model"],
        "D": calibration["D"],
        "vertical_fov_deg": CAMERA_FOV_DEG,
        "near": CAMERA_NEAR,
        "far": CAMERA_FAR,
        "pixel_convention": "(column, row) from the image's top-left corner; pixel (c, r) is centred at "
                            "(c + 0.5, r + 0.5)",
        "world": "Dyana's world: X right, Y up, Z forward (left-handed), metres; the frame of "
                 f"{STATE_KEY}'s palm pose and of {ACTION_KEY}",
        "eye": list(CAMERA_EYE),
        "target": list(CAMERA_TARGET),
        "up": list(CAMERA_UP),
        "world_to_camera": _rounded(world_to_camera()),
        "world_to_camera_convention": "optical frame: x right, y down, z forward in the image; pixel = K @ "
                                      "(R @ p + t) / its last element; R is a reflection (det -1): Dyana's "
                                      "world is left-handed",
        "mcap_pose": {
            "frame": WORLD_FRAME,
            "axes": "MCAP world: x = Dyana x, y = Dyana z, z = Dyana y (right-handed, Z up)",
            "position": _rounded(position),
            "quaternion_xyzw": _rounded(quaternion),
        },
    }

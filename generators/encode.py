"""JPEG encoding of RGB frames with OpenCV (libjpeg-turbo), and decoding back to RGB.

Settings are pinned explicitly (baseline, not optimized, not progressive, 4:2:0
chroma subsampling) so that the same pixels give the same bytes; the quality is
recorded in the manifest's settings as ``jpeg_quality``.
"""

from __future__ import annotations

import cv2
import numpy as np

from schemas.errors import ShardError, SpecError
from schemas.names import shorten
from schemas.settings import JPEG_QUALITY

IMAGE_FORMAT = "jpeg"


def jpeg_params(quality: int) -> list[int]:
    """``cv2.imencode`` options of a JPEG at ``quality``: every setting that affects the bytes."""
    return [
        cv2.IMWRITE_JPEG_QUALITY,
        quality,
        cv2.IMWRITE_JPEG_OPTIMIZE,
        0,
        cv2.IMWRITE_JPEG_PROGRESSIVE,
        0,
        cv2.IMWRITE_JPEG_SAMPLING_FACTOR,
        cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420,
    ]


def _checked(image, quality) -> np.ndarray:
    if isinstance(quality, bool) or not isinstance(quality, (int, np.integer)) or not 1 <= quality <= 100:
        raise SpecError(f"JPEG quality must be an integer in [1, 100], got {shorten(repr(quality))}")
    array = np.asarray(image)
    if array.dtype != np.uint8 or array.ndim != 3 or array.shape[2] != 3:
        raise SpecError(f"expected an (H, W, 3) uint8 RGB image, got {array.dtype} {array.shape}")
    return np.ascontiguousarray(array)


def _encode(bgr: np.ndarray, quality) -> bytes:
    ok, buffer = cv2.imencode(".jpg", bgr, jpeg_params(int(quality)))
    if not ok:
        raise SpecError("OpenCV failed to encode the image as JPEG")
    return buffer.tobytes()


def encode_jpeg(rgb: np.ndarray, quality: int = JPEG_QUALITY) -> bytes:
    """(H, W, 3) uint8 RGB -> JPEG bytes. (The channels are swapped for OpenCV with
    ``cvtColor``, one SIMD pass; numpy's ``[:, :, ::-1]`` copy cost more than the encoding.)"""
    return _encode(cv2.cvtColor(_checked(rgb, quality), cv2.COLOR_RGB2BGR), quality)


def encode_bgr_jpeg(bgr: np.ndarray, quality: int = JPEG_QUALITY) -> bytes:
    """(H, W, 3) uint8 BGR, OpenCV's channel order -> the JPEG bytes :func:`encode_jpeg`
    gives for the same pixels in RGB, without swapping channels."""
    return _encode(_checked(bgr, quality), quality)


def decode_jpeg(data: bytes) -> np.ndarray:
    """JPEG bytes -> (H, W, 3) uint8 RGB; anything undecodable (empty, truncated, not
    bytes) is a :class:`ShardError`."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise ShardError(f"an encoded image must be bytes, got {type(data).__name__}")
    bgr = None
    if len(data):
        try:
            bgr = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR)
        except cv2.error:
            bgr = None
    if bgr is None:
        raise ShardError(f"not a decodable JPEG image ({len(data)} bytes)")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)  # one SIMD pass; copying numpy's [:, :, ::-1] view cost more than the decode

"""generators.encode: decoding gives OpenCV's pixels with the channels reversed, exactly,
and drawing in BGR gives the JPEG bytes of the same pixels in RGB."""

import cv2
import numpy as np
import pytest

from generators.encode import decode_jpeg, encode_bgr_jpeg, encode_jpeg


@pytest.mark.parametrize("side", [8, 33, 224])
def test_decode_is_opencvs_decode_with_channels_reversed(side):
    rng = np.random.default_rng(side)
    image = rng.integers(0, 256, size=(side, side + 3, 3), dtype=np.uint8)
    image[: side // 2] = (250, 10, 40)  # flat colour, where chroma subsampling shows
    data = encode_jpeg(image)
    bgr = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR)
    decoded = decode_jpeg(data)
    np.testing.assert_array_equal(decoded, bgr[:, :, ::-1])
    assert decoded.dtype == np.uint8 and decoded.flags["C_CONTIGUOUS"]
    assert encode_bgr_jpeg(np.ascontiguousarray(image[:, :, ::-1])) == data

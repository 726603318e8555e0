"""catalog.export.video: the same frames give the same MP4 bytes in any process, whatever
the heap held before (x264's AVX-512 kernels used to read uninitialised memory)."""

from __future__ import annotations

import ctypes
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from catalog.export import video
from catalog.export.video import VideoWriter, codec_versions, encoder_options

ROOT = Path(__file__).resolve().parents[2]
#: Tiny clips (48 px, 12 frames, moving 3 px left and 2 px up a frame), one per seed: before
#: the fix each of seeds 1-5 gave other bytes under MALLOC_PERTURB_=85 than under 170 on an
#: AVX-512 CPU (the encoder read heap memory it had not written).
SIDE, FRAMES, STEP, SEEDS = 48, 12, (-3, -2), range(6)
#: Run in a child process: encode the clips twice, into ARGV[1]/a and ARGV[1]/b.
CHILD = """
import sys
from pathlib import Path
from tests.catalog.test_export_video import encode_clips
for name in ("a", "b"):
    encode_clips(Path(sys.argv[1]) / name)
"""


def clip(seed: int) -> list[np.ndarray]:
    """A blurred random texture seen through a window that moves by STEP a frame."""
    rng = np.random.default_rng(seed)
    pad = 4 * FRAMES
    texture = rng.integers(0, 256, (SIDE + 2 * pad, SIDE + 2 * pad, 3), dtype=np.uint8).astype(np.float32)
    texture = cv2.GaussianBlur(texture, (0, 0), 4).astype(np.uint8)
    dx, dy = STEP
    return [np.ascontiguousarray(texture[pad + dy * k: pad + dy * k + SIDE, pad + dx * k: pad + dx * k + SIDE])
            for k in range(FRAMES)]


def encode_clip(path: Path, seed: int = 1, codec: str = "h264") -> bytes:
    with VideoWriter(path, SIDE, SIDE, 20, codec) as writer:
        for frame in clip(seed):
            writer.add(frame)
    return path.read_bytes()


def encode_clips(folder: Path) -> dict[str, bytes]:
    """Every seed's clip as ``folder/clip-<seed>.mp4``; returns name -> bytes."""
    return {f"clip-{seed}.mp4": encode_clip(folder / f"clip-{seed}.mp4", seed) for seed in SEEDS}


@pytest.fixture
def fresh_x264_params():
    """Forget the cached x264 parameters before and after the test (it may monkeypatch their lookup)."""
    video._x264_params.cache_clear()
    yield
    video._x264_params.cache_clear()


def test_h264_bytes_are_the_same_in_two_concurrent_processes(tmp_path):
    # Two processes side by side, each encoding twice (the second encode reuses a used
    # heap); glibc fills fresh allocations with a different byte in each, so anything
    # the encoder reads without having written it shows up as different bytes.
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    children = []
    for k, perturb in enumerate(("85", "170")):
        out = tmp_path / f"p{k}"
        out.mkdir()
        children.append((out, subprocess.Popen([sys.executable, "-c", CHILD, str(out)], cwd=ROOT,
                                               env=dict(env, MALLOC_PERTURB_=perturb), stderr=subprocess.PIPE)))
    for _, child in children:
        _, err = child.communicate(timeout=120)
        assert child.returncode == 0, err.decode(errors="replace")
    here = encode_clips(tmp_path / "here")
    differing = [f"{out.name}/{run}/{name}" for out, _ in children for run in ("a", "b") for name, data in here.items()
                 if (out / run / name).read_bytes() != data]
    assert differing == []


def test_libx264_never_gets_avx512_and_the_export_records_its_options():
    options = encoder_options("h264")
    recorded = codec_versions("h264")["options"].split()
    assert [f"{k}={v}" for k, v in sorted(options.items())] == recorded
    library = video._x264_library(video._av())
    if library is None or "x264-params" not in options:
        return  # no AVX-512 here (or x264 not to be asked: see the next test)
    library.x264_cpu_detect.restype = ctypes.c_uint32
    names = ctypes.cast(library.x264_cpu_names, ctypes.POINTER(video._X264CpuName))
    table = {}
    for k in range(256):
        if not names[k].flags:
            break
        table[names[k].name.decode()] = names[k].flags
    avx512 = table["AVX512"] & ~table["AVX2"]
    asm = int(options["x264-params"].removeprefix("asm="))
    assert asm & avx512 == 0
    assert asm == library.x264_cpu_detect() & ~avx512  # every other detected feature kept


def test_without_libx264_to_ask_the_macroblock_tree_goes_off(monkeypatch, tmp_path, fresh_x264_params):
    monkeypatch.setattr(video, "_x264_library", lambda av: None)
    assert encoder_options("h264")["x264-params"] == "mbtree=0"
    assert "x264-params=mbtree=0" in codec_versions("h264")["options"]
    assert encode_clip(tmp_path / "a.mp4") == encode_clip(tmp_path / "b.mp4")


def test_av1_options_are_unchanged():
    assert encoder_options("av1") == video.CODECS["av1"][1]

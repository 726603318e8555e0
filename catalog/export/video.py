"""MP4 videos for exports, through PyAV's bundled FFmpeg, and their decoding.

Codecs (:data:`CODECS`): ``h264`` (libx264, the default: every decoder reads it) and
``av1`` (libsvtav1, LeRobot's own default). Both use yuv420p and a keyframe every
:data:`KEYFRAME_INTERVAL` frames (LeRobot's ``g=2``, so a training loader seeking a
random frame decodes at most one frame before it).

Deterministic: frame ``k`` has presentation time ``k / fps`` exactly (time base
1/fps), encoders run single-threaded with FFmpeg's bit-exact flags and the muxer
writes no creation time, so the same frames give the same bytes under the same PyAV
build; :func:`codec_versions` records that build in every export. libx264 runs without
its AVX-512 kernels (:func:`encoder_options`): those read memory x264 never
initialised, so on an AVX-512 CPU the bytes depended on the process's heap history.

:class:`VideoWriter` is an explicit open/add/finish writer used as a context
manager: the file appears under its name only once finished (write-then-rename).
"""

from __future__ import annotations

import ctypes
import functools
import os
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType, TracebackType

import numpy as np

from catalog.store.atomic import commit, discard, temp_path
from schemas.errors import DyanaError

#: Keyframe interval in frames (LeRobot encodes with g=2).
KEYFRAME_INTERVAL = 2
#: codec name -> (FFmpeg encoder, its options).
CODECS = {
    "h264": ("libx264", {"crf": "18", "preset": "medium", "threads": "1", "g": str(KEYFRAME_INTERVAL)}),
    "av1": ("libsvtav1", {"crf": "30", "preset": "8", "g": str(KEYFRAME_INTERVAL), "svtav1-params": "lp=1"}),
}
PIX_FMT = "yuv420p"


class VideoError(DyanaError):
    """A video could not be written or read."""


class _X264CpuName(ctypes.Structure):
    """One entry of libx264's exported ``x264_cpu_names`` table (name, CPU-flag mask)."""

    _fields_ = [("name", ctypes.c_char_p), ("flags", ctypes.c_uint32)]


def _x264_library(av: ModuleType) -> ctypes.CDLL | None:
    """The libx264 this process's libavcodec uses, opened through ctypes (None if not found).

    Looked for among the libraries mapped into the process (Linux), then beside PyAV's
    package (the wheels' bundled copies); it must export ``x264_cpu_detect``."""
    candidates: list[str] = []
    try:
        maps = Path("/proc/self/maps").read_text(encoding="utf-8", errors="replace")
    except OSError:  # not Linux: only the bundled copies are candidates
        maps = ""
    for line in maps.splitlines():
        fields = line.split(maxsplit=5)
        if len(fields) == 6 and "x264" in os.path.basename(fields[5]):
            candidates.append(fields[5])
    folders: list[Path] = []
    if av.__file__ is not None:  # (a namespace package has no bundled copies beside it)
        package = Path(av.__file__).parent
        folders = [package.parent / "av.libs", package / ".dylibs", package]
    for folder in folders:
        candidates += sorted(str(p) for p in folder.glob("*x264*") if p.is_file())
    for path in dict.fromkeys(candidates):
        try:
            library = ctypes.CDLL(path)
        except OSError:
            continue
        if hasattr(library, "x264_cpu_detect") and hasattr(library, "x264_cpu_names"):
            return library
    return None


@functools.cache
def _x264_params() -> str | None:
    """libx264's ``x264-params`` that keep its output independent of uninitialised memory.

    x264's AVX-512 macroblock-tree kernels (mbtree_propagate_cost/list) process 16 and 8
    macroblocks at a time and, unlike the AVX2 and C versions, use the lanes past the end of
    a row, which hold memory x264 never wrote (a non-referenced B-frame's propagate row is
    zeroed for the row's width only). With 224 px frames (14 macroblocks a row) the bytes
    then depend on what the heap held. So x264 gets the CPU features it detects itself, minus
    AVX-512 (``asm=<flags>``, None when it detects no AVX-512); if libx264 cannot be asked,
    the macroblock tree is switched off instead (``mbtree=0``: larger files, no such kernels).
    """
    av = _av()
    library = _x264_library(av)
    if library is None:
        return "mbtree=0"
    library.x264_cpu_detect.restype = ctypes.c_uint32
    detected = int(library.x264_cpu_detect())
    names: dict[str, int] = {}
    table = ctypes.cast(library.x264_cpu_names, ctypes.POINTER(_X264CpuName))
    for k in range(256):  # the table ends with an entry of no flags
        if not table[k].flags:
            break
        names[table[k].name.decode("ascii", "replace")] = int(table[k].flags)
    avx512 = names.get("AVX512", 0) & ~names.get("AVX2", 0)
    if not detected & avx512:
        return None
    return f"asm={detected & ~avx512}"


def encoder_options(codec: str) -> dict[str, str]:
    """The options ``codec``'s encoder runs with: :data:`CODECS`' own plus, for libx264, :func:`_x264_params`."""
    encoder, options = CODECS[codec]
    options = dict(options)
    if encoder == "libx264" and (params := _x264_params()) is not None:
        options["x264-params"] = params
    return options


def _av() -> ModuleType:
    try:
        import av
    except ImportError:  # pragma: no cover - av is a dependency
        raise VideoError("video export needs PyAV: pip install av") from None
    return av


def codec_versions(codec: str) -> dict[str, str]:
    """What decides an encoded video's bytes: PyAV's version, its libav* versions and the encoder."""
    av = _av()
    encoder, options = CODECS[codec][0], encoder_options(codec)
    libs = {name: ".".join(str(v) for v in version) for name, version in sorted(av.library_versions.items())}
    return {"pyav": av.__version__, **libs, "encoder": encoder, "options": " ".join(f"{k}={v}" for k, v in sorted(options.items()))}


class VideoWriter:
    """Encode RGB frames (H, W, 3) uint8 into one MP4 at ``fps``; call :meth:`finish` (or
    leave the ``with`` block normally) to complete the file, anything else discards it."""

    def __init__(self, path: str | os.PathLike[str], width: int, height: int, fps: int, codec: str = "h264"):
        if codec not in CODECS:
            raise VideoError(f"unknown video codec {codec!r} (expected one of {sorted(CODECS)})")
        if width % 2 or height % 2:
            raise VideoError(f"{codec} in {PIX_FMT} needs even image sides, got {width}x{height}")
        av = _av()
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._temp = temp_path(self.path)
        self.frames = 0
        self._shape = (height, width, 3)
        encoder, options = CODECS[codec][0], encoder_options(codec)
        if encoder == "libsvtav1":
            os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 prints its banner to stderr unless told not to
        self._container = av.open(os.fspath(self._temp), "w", format="mp4", options={"fflags": "+bitexact"})
        try:
            stream = self._container.add_stream(encoder, rate=fps)
            stream.width, stream.height, stream.pix_fmt = width, height, PIX_FMT
            stream.codec_context.flags |= av.codec.context.Flags.bitexact
            stream.options = dict(options)
            self._stream = stream
        except BaseException:
            self._abort()
            raise

    def add(self, rgb: np.ndarray) -> None:
        if rgb.shape != self._shape or rgb.dtype != np.uint8:
            raise VideoError(f"{self.path}: frames must be {self._shape} uint8, got {rgb.shape} {rgb.dtype}")
        frame = _av().VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
        frame.pts = self.frames
        for packet in self._stream.encode(frame):
            self._container.mux(packet)
        self.frames += 1

    def finish(self) -> Path:
        for packet in self._stream.encode():
            self._container.mux(packet)
        self._container.close()
        commit(self._temp, self.path)
        return self.path

    def _abort(self) -> None:
        try:
            self._container.close()
        except Exception:  # noqa: BLE001 - closing a broken container may fail; the file goes anyway
            pass
        discard(self._temp)

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.finish()
        else:
            self._abort()


def decode_frames(path: str | os.PathLike[str]) -> Iterator[tuple[float, np.ndarray]]:
    """Every frame of a video as ``(timestamp in seconds, (H, W, 3) uint8 RGB)``, in order."""
    av = _av()
    try:
        with av.open(os.fspath(path)) as container:
            stream = container.streams.video[0]
            for frame in container.decode(stream):
                yield float(frame.pts * stream.time_base), frame.to_ndarray(format="rgb24")
    except av.error.FFmpegError as exc:
        raise VideoError(f"{path}: cannot decode: {exc}") from None


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """Peak signal-to-noise ratio of two uint8 images in dB (inf when equal)."""
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0.0 else 10.0 * np.log10(255.0**2 / mse)

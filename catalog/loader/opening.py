"""``catalog.open``: check the dataloader's options, index each folder, return a
:class:`~catalog.loader.dataset.FrameDataset` (see :mod:`catalog.loader.dataset` for its items)."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import cast

import numpy as np

from catalog.loader.dataset import FrameDataset
from catalog.loader.decode import RESAMPLE_MODES
from catalog.loader.index import VERIFY_MODES, Episode, Options, ShardFile, load_source, non_negative
from catalog.loader.lerobot_keys import IMAGE_DTYPES, KEYS
from catalog.loader.selection import Selection
from catalog.store.manifest import Manifest
from catalog.store.storage import as_location, is_remote, is_url
from schemas.errors import SpecError
from schemas.names import shorten

#: Largest ``resize`` side (px). A 4096x4096 RGB frame is 48 MiB as uint8 and 192 MiB as
#: float32 (``keys="lerobot"``), times ``history + 1`` per item: any larger is an upscale of
#: images stored at a few hundred px that no model reads, and a sure out-of-memory.
MAX_RESIZE = 4096
#: Largest ``cache_mb``: 1 TiB. The cache only bounds memory; a bound beyond any machine's
#: memory is no bound (and ``inf`` has no byte count).
MAX_CACHE_MB = 1 << 20
#: Largest ``history`` / ``action_horizon`` before any folder is read: ``frame_index`` is an
#: int32, so no episode holds more frames. Once the folders are indexed the bound is the
#: longest episode they hold (:func:`check_windows`).
MAX_WINDOW_FRAMES = 2**31 - 1


def _size(value: object, whole: object) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise SpecError(f"resize must be a size in px or (height, width), got {shorten(repr(whole))}")
    if not 1 <= value <= MAX_RESIZE:
        raise SpecError(f"resize must be 1..{MAX_RESIZE} px a side, got {shorten(repr(whole))}")
    return int(value)


def _resize(value: int | tuple[int, int] | None) -> tuple[int, int] | None:
    """``resize`` as (height, width): integers (not strings: ``"64"`` would read as 6x4)
    of 1..:data:`MAX_RESIZE` px."""
    if value is None:
        return None
    if isinstance(value, (int, np.integer)):
        size = _size(value, value)
        return size, size
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise SpecError(f"resize must be a size in px or (height, width), got {shorten(repr(value))}")
    return _size(value[0], value), _size(value[1], value)


def _is_folder(value: object) -> bool:
    """A string, a path-like or a UPath (which is not always an ``os.PathLike``)."""
    return isinstance(value, (str, os.PathLike, Path)) or is_remote(value)


def _roots(paths: object) -> list[Path]:
    """The folders of ``paths`` (one, or a list or tuple of them): strings or path-likes; a URL
    needs a bucket (``s3://`` alone names none)."""
    if _is_folder(paths):
        items: list[object] = [paths]
    elif isinstance(paths, (list, tuple)):
        items = list(paths)
    else:
        raise SpecError(f"paths must be a folder or a list of folders, got {shorten(repr(paths))}")
    roots = []
    for item in items:
        if not _is_folder(item):
            raise SpecError(f"paths must be folders (str or path-like), got {shorten(repr(item))}")
        if isinstance(item, str) and is_url(item) and not item.split("://", 1)[1].strip("/"):
            raise SpecError(f"paths: {shorten(repr(item))} names no bucket (expected e.g. s3://bucket/folder)")
        roots.append(as_location(cast("str | os.PathLike[str]", item)))  # a UPath is handled as one
    if not roots:
        raise SpecError("catalog.open needs at least one folder")
    return roots


def check_windows(history: int, action_horizon: int | None, spans: Sequence[tuple[int, int, int]]) -> None:
    """SpecError when ``history`` or ``action_horizon`` is longer than the longest episode
    opened (frames): such a window is padding only, and each item would allocate it."""
    longest = max((n for _, _, n in spans), default=0)
    if longest and history > longest:
        raise SpecError(f"history must be at most {longest} (the longest episode opened), got {history}")
    if longest and action_horizon is not None and action_horizon > longest:
        raise SpecError(f"action_horizon must be at most {longest} (the longest episode opened), got {action_horizon}")


def open_dataset(
    paths: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    history: int = 0,
    action_horizon: int | None = None,
    *,
    motion_type: str | Iterable[str] | None = None,
    intercept_setting: str | Iterable[str] | None = None,
    object: str | Iterable[str] | None = None,
    episodes: range | Iterable[int] | int | None = None,
    where: Callable[[Episode], bool] | None = None,
    resize: int | tuple[int, int] | None = None,
    resample: str = "area",
    verify: str = "sha256",
    cache_mb: float = 512,
    keys: str = "dyana",
    image_dtype: str = "float32",
) -> FrameDataset:
    """Open built slices or evaluated rollouts (folders with ``catalog.json``) as one dataset.

    ``paths`` is a folder or a list of folders (concatenated in order; items then carry
    ``source``). ``history=K`` stacks the K previous frames; ``action_horizon=H``
    returns H actions. Filters select episodes (see :meth:`FrameDataset.select`).
    ``resize=(height, width)`` (or one size) resizes images on load: ``resample="area"``
    (the default) decodes in full and resizes with ``cv2.INTER_AREA``; ``resample="jpeg"``
    lets the JPEG decoder scale by 1/2, 1/4 or 1/8 when the target is half the resolution
    or less (~1.3x faster than ``"area"`` at half size; other sizes as ``"area"``): a different
    resampling than ``"area"`` (pixels differ by a few levels), deterministic for a given
    libjpeg build (:func:`catalog.loader.decode.decode_plan`).
    ``verify`` is ``"sha256"`` or ``"checksums"`` (:mod:`catalog.loader.dataset` says what each checks); ``cache_mb``
    bounds each process's cache of loaded shards.
    Limits, checked before anything is read or allocated (SpecError naming the argument):
    ``resize`` 1..:data:`MAX_RESIZE` px a side, ``cache_mb`` at most :data:`MAX_CACHE_MB`,
    ``history`` and ``action_horizon`` at most the longest episode opened. ``keys="lerobot"`` names items as
    LeRobot does (:mod:`catalog.loader.lerobot_keys`), with images as ``image_dtype``
    (``"float32"`` in [0, 1], or ``"uint8"``), channels first.
    """
    roots = _roots(paths)
    if verify not in VERIFY_MODES:
        raise SpecError(f"verify must be one of {list(VERIFY_MODES)}, got {shorten(repr(verify))}")
    if isinstance(cache_mb, bool) or not isinstance(cache_mb, (int, float)) or not 0 < cache_mb <= MAX_CACHE_MB:
        raise SpecError(f"cache_mb must be a number in (0, {MAX_CACHE_MB}], got {shorten(repr(cache_mb))}")
    if keys not in KEYS:
        raise SpecError(f"keys must be one of {list(KEYS)}, got {shorten(repr(keys))}")
    if image_dtype not in IMAGE_DTYPES:
        raise SpecError(f"image_dtype must be one of {list(IMAGE_DTYPES)}, got {shorten(repr(image_dtype))}")
    if resample not in RESAMPLE_MODES:
        raise SpecError(f"resample must be one of {list(RESAMPLE_MODES)}, got {shorten(repr(resample))}")
    options = Options(
        resample=resample,
        keys=keys,
        image_dtype=image_dtype,
        history=non_negative("history", history, 0, MAX_WINDOW_FRAMES),
        action_horizon=None if action_horizon is None else non_negative("action_horizon", action_horizon, 1,
                                                                         MAX_WINDOW_FRAMES),
        resize=_resize(resize),
        verify=verify,
        cache_bytes=int(cache_mb * (1 << 20)),
    )
    selection = Selection.of(motion_type, intercept_setting, object, episodes, where)
    manifests: list[Manifest] = []
    files: list[ShardFile] = []
    episodes_all: list[Episode] = []
    spans: list[tuple[int, int, int]] = []
    for source, root in enumerate(roots):
        manifest, source_episodes, source_spans = load_source(root, source, verify, files)
        manifests.append(manifest)
        episodes_all.extend(source_episodes)
        spans.extend(source_spans)
    check_windows(options.history, options.action_horizon, spans)
    dataset = FrameDataset(roots, manifests, files, episodes_all, spans, options)
    return dataset if selection.everything else dataset.filtered(selection)

"""The stage chain that turns specs into a written shard: episode stage, render, encode, write.

A worker process keeps one :class:`~generators.render.Renderer` per resolution and
renderer kind for its whole life (loading the scene and both hands costs far more than a frame).
"""

from __future__ import annotations

import atexit
from collections.abc import Sequence
from pathlib import Path

from catalog.store.records import ShardRecord
from catalog.tables.partial import PartialShard, StagedEpisode
from catalog.tables.shard import ShardWriter
from generators.encode import encode_bgr_jpeg
from generators.render import Renderer
from pipeline.stages.episode import episode
from schemas.frames import EpisodeFrames
from schemas.renderers import DEFAULT_RENDERER
from schemas.spec import EpisodeSpec

_RENDERERS: dict[tuple[int, str], Renderer] = {}


def renderer_for(resolution: int, kind: str = DEFAULT_RENDERER) -> Renderer:
    """This process's renderer of ``kind`` at ``resolution``, created on first use."""
    renderer = _RENDERERS.get((resolution, kind))
    if renderer is None:
        renderer = Renderer(resolution, kind=kind)
        _RENDERERS[(resolution, kind)] = renderer
    return renderer


@atexit.register
def close_renderers() -> None:
    """Close this process's renderers (at exit; a benchmark calls it after a warm-up, so
    the next build starts from a fresh renderer as a new worker does)."""
    for renderer in _RENDERERS.values():
        renderer.close()
    _RENDERERS.clear()


def encoded_frames(
    spec: EpisodeSpec, frames: EpisodeFrames, resolution: int, jpeg_quality: int, renderer: str = DEFAULT_RENDERER
) -> list[bytes]:
    """Render every frame of an episode with ``renderer`` (:mod:`schemas.renderers`) and
    encode it as JPEG (frames drawn in OpenCV's channel order, so nothing is converted
    between renderer and encoder)."""
    images = renderer_for(resolution, renderer).render_episode(
        frames, spec.object, spec.object_size, spec.hand, obstacles=spec.obstacles, bgr=True
    )
    return [encode_bgr_jpeg(image, jpeg_quality) for image in images]


def write_ground_truth_shard(
    specs: Sequence[EpisodeSpec], first: int, end: int, settings, slice_dir: Path, partial: PartialShard | None = None
) -> tuple[ShardRecord, int]:
    """Episodes ``[first, end)`` of a slice, ground truth, as one atomic shard; and how many
    were taken from ``partial`` (an interrupted run's staged episodes, :mod:`catalog.tables.partial`),
    where each episode computed is staged while the shard is in flight."""
    taken = 0
    with ShardWriter(slice_dir, first, end, settings.to_dict()) as writer:
        for _index, spec in zip(range(first, end), specs):
            staged = None if partial is None else partial.load(spec)
            if staged is None:
                frames = episode(spec)
                images = encoded_frames(spec, frames, settings.resolution, settings.jpeg_quality, settings.renderer)
                if partial is not None:
                    partial.save(spec, StagedEpisode(spec, frames, images))
            else:
                frames, images, taken = staged.frames, staged.images, taken + 1
            writer.add_episode(spec, frames, images)
    if partial is not None:
        partial.remove()
    return writer.result, taken

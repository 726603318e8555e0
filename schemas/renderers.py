"""The two ways :class:`generators.render.Renderer` draws a frame's moving bodies, and the
dataset version each one's bytes belong to.

- ``window`` (the default, dataset 4.0.0): only the screen window around the hand and the
  object, found from their visual shapes before drawing (:mod:`generators.window`).
- ``full`` (dataset 3.0.0): the whole viewport, as every build before 4.0.0.

The two give the same frames but for rare one-level differences at a few pixels, so a
folder's dataset version names the renderer that rebuilds it byte for byte.
"""

from __future__ import annotations

from schemas.errors import SpecError
from schemas.names import shorten
from schemas.versions import DATASET_VERSION

#: Renderer name -> the dataset version its builds write.
RENDERER_VERSIONS = {"window": DATASET_VERSION, "full": "3.0.0"}
RENDERERS = tuple(RENDERER_VERSIONS)
#: Dataset versions this code rebuilds byte for byte: one per renderer, oldest first.
REBUILDABLE_DATASET_VERSIONS = tuple(sorted(RENDERER_VERSIONS.values()))
DEFAULT_RENDERER = "window"


def check_renderer(value: object, name: str = "renderer") -> str:
    """``value`` if it names a renderer, else SpecError naming ``name`` and the value."""
    if not isinstance(value, str) or value not in RENDERER_VERSIONS:
        raise SpecError(f"{name} must be one of {list(RENDERERS)}, got {shorten(repr(value))}")
    return value


def dataset_version_of(renderer: object) -> str:
    """The dataset version a build with ``renderer`` writes."""
    return RENDERER_VERSIONS[check_renderer(renderer)]


def renderer_of(dataset_version: object) -> str | None:
    """The renderer that rebuilds a folder of ``dataset_version`` byte for byte, or None."""
    return next((name for name, version in RENDERER_VERSIONS.items() if version == dataset_version), None)

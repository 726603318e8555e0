"""The two ways :class:`generators.render.Renderer` draws a frame's moving bodies (its
draw kinds), and the renderer a build chooses, which names the dataset version it writes.

- ``window`` (the default, the build renderer of dataset 5.0.0, as of 4.0.0): only the
  screen window around the hand and the object, found from their visual shapes before
  drawing (:mod:`generators.window`).
- ``full``: the whole viewport, as every build before 4.0.0 drew. A draw kind still
  (benchmarks compare the two draws), no longer a build renderer: it wrote dataset
  3.0.0's bytes with the splayed-thumb hand, and dataset 5.0.0 changed the hand
  (:data:`RETIRED_RENDERERS`; commit :data:`SPLAYED_HAND_COMMIT` rebuilds 3.0.0 and 4.0.0).

The two draws give the same frames but for rare one-level differences at a few pixels.
"""

from __future__ import annotations

from schemas.errors import SpecError
from schemas.names import shorten
from schemas.versions import DATASET_VERSION

#: Renderer name -> the dataset version its builds write.
RENDERER_VERSIONS = {"window": DATASET_VERSION}
#: The last commit with the splayed-thumb hand (main before dataset 5.0.0): it rebuilds
#: 3.0.0 (``--renderer full``) and 4.0.0 (``--renderer window``) folders byte for byte.
SPLAYED_HAND_COMMIT = "ebf6e48"
#: Build renderers this code no longer has -> the dataset version they wrote.
RETIRED_RENDERERS = {"full": "3.0.0"}
#: The renderer names a build accepts on the command line (a retired one is refused with
#: :func:`check_renderer`'s one line, not argparse's).
RENDERERS = tuple(RENDERER_VERSIONS) + tuple(RETIRED_RENDERERS)
#: How :class:`generators.render.Renderer` may draw.
DRAW_KINDS = ("window", "full")
#: Dataset versions this code rebuilds byte for byte: one per renderer, oldest first.
REBUILDABLE_DATASET_VERSIONS = tuple(sorted(RENDERER_VERSIONS.values()))
DEFAULT_RENDERER = "window"


def check_renderer(value: object, name: str = "renderer") -> str:
    """``value`` if it names a build renderer, else SpecError naming ``name`` and the value
    (for a retired one, the commit that still builds with it)."""
    if isinstance(value, str) and value in RETIRED_RENDERERS:
        raise SpecError(f"{name} {value!r} wrote dataset {RETIRED_RENDERERS[value]}, whose hand dataset "
                        f"{DATASET_VERSION} changed: check out commit {SPLAYED_HAND_COMMIT} to build "
                        f"{RETIRED_RENDERERS[value]} (--renderer {value}) or 4.0.0 (--renderer window)")
    if not isinstance(value, str) or value not in RENDERER_VERSIONS:
        raise SpecError(f"{name} must be one of {list(RENDERER_VERSIONS)}, got {shorten(repr(value))}")
    return value


def check_draw_kind(value: object, name: str = "kind") -> str:
    """``value`` if it names a draw kind (:data:`DRAW_KINDS`), else SpecError naming ``name``."""
    if not isinstance(value, str) or value not in DRAW_KINDS:
        raise SpecError(f"{name} must be one of {list(DRAW_KINDS)}, got {shorten(repr(value))}")
    return value


def dataset_version_of(renderer: object) -> str:
    """The dataset version a build with ``renderer`` writes."""
    return RENDERER_VERSIONS[check_renderer(renderer)]


def renderer_of(dataset_version: object) -> str | None:
    """The renderer that rebuilds a folder of ``dataset_version`` byte for byte, or None."""
    return next((name for name, version in RENDERER_VERSIONS.items() if version == dataset_version), None)

"""The byte settings: everything besides the episode specs that determines a shard's bytes.

:class:`BuildSettings` is the one place they are defined. A build or an eval assembles it
(from the CLI's flags, :func:`setting_flags`), the manifest stores :meth:`BuildSettings.to_dict`
as ``catalog.json``'s ``settings``, and replay, verify, ``catalog info`` and the
environment read it back with :meth:`BuildSettings.from_dict`. Each field carries a
:class:`Setting` in its metadata: the CLI flags that choose it (none: it is derived, and
``derived`` says from what) and its line on the settings reference page, so a new
byte-affecting setting is one field here, its flag's registration and its docs line
(``tests/catalog/test_byte_settings.py`` checks all four are there).

It lives in ``schemas`` so that ``catalog`` (info), ``generators`` and ``pipeline`` share it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from schemas.errors import SpecError
from schemas.formats import ALL_FORMATS, parse_formats
from schemas.names import shorten
from schemas.renderers import renderer_of
from schemas.scene import DEFAULT_RESOLUTION
from schemas.versions import DATASET_VERSION, FPS, HAND_MODEL

#: JPEG quality (0-100) of built datasets (:mod:`generators.encode` encodes with it).
JPEG_QUALITY = 90


@dataclass(frozen=True)
class Setting:
    """A byte setting's documentation: the CLI ``flags`` that choose it (empty when it is
    derived, ``derived`` saying from what) and ``doc``, its line on the settings page."""

    doc: str
    flags: tuple[str, ...] = ()
    derived: str = ""

    def __post_init__(self) -> None:
        if bool(self.flags) == bool(self.derived):
            raise SpecError(f"a setting has CLI flags or says how it is derived, not both or neither: {self.doc[:60]!r}")


def _setting(doc: str, *flags: str, derived: str = "") -> dict[str, Setting]:
    return {"setting": Setting(doc, tuple(flags), derived)}


@dataclass(frozen=True)
class BuildSettings:
    """Everything besides the specs that determines a shard's bytes (module docstring)."""

    resolution: int = field(default=DEFAULT_RESOLUTION, metadata=_setting(
        "image side in pixels of the square frames, 16 to 1024 (default: 224)", "--resolution"))
    jpeg_quality: int = field(default=JPEG_QUALITY, metadata=_setting(
        "JPEG quality of the stored frames, 1 to 100", derived="fixed at 90 (schemas.settings.JPEG_QUALITY)"))
    fps: int = field(default=FPS, metadata=_setting(
        "frames per second of the recording", derived="fixed at 20 (schemas.versions.FPS)"))
    image_format: str = field(default="jpeg", metadata=_setting(
        "how the frames' images are stored", derived="fixed: jpeg"))
    #: Names the renderer too (:mod:`schemas.renderers`): 5.0.0 ``window``.
    dataset_version: str = field(default=DATASET_VERSION, metadata=_setting(
        "the dataset version, which names the renderer that draws the frames (5.0.0: window)",
        "--renderer"))
    #: The frames table carries the hand's obstacle clearance (scenes may hold obstacles).
    obstacle_clearance: bool = field(default=False, metadata=_setting(
        "whether the frames table has the hand's obstacle clearance column (stored only when true)",
        derived="true when the slice's scenes (or the specs file's episodes) may hold obstacles"))
    #: A rollout's evaluation protocol (pipeline.loop.conditions.EvalProtocol.to_dict), None
    #: for the plain closed loop and for builds.
    protocol: dict | None = field(default=None, metadata=_setting(
        "a run's evaluation protocol: latency, real time, perturbation, disturbance, repeat (stored only when "
        "not the plain loop)", "--latency-frames", "--realtime", "--perturb", "--disturb", "--repeats"))
    #: A run's hand model (schemas.versions.HAND_MODEL); empty for builds, whose ground truth
    #: the body passes unchanged, and for runs recorded before the hand was a body.
    hand_model: str = field(default="", metadata=_setting(
        "a run's hand model: body-1, a pybullet body with speed, acceleration and joint limits (stored only for "
        "runs)", derived="set by pipeline eval (schemas.versions.HAND_MODEL)"))
    #: What is stored: Parquet always, MCAP (for viewing) unless left out.
    formats: tuple[str, ...] = field(default=ALL_FORMATS, metadata=_setting(
        "what is stored: parquet,mcap or parquet (the MCAP files are for viewing)", "--formats"))

    def __post_init__(self) -> None:
        object.__setattr__(self, "formats", parse_formats(self.formats))
        if isinstance(self.resolution, bool) or not isinstance(self.resolution, int) or not 16 <= self.resolution <= 1024:
            raise SpecError(f"resolution must be an integer in [16, 1024], got {shorten(repr(self.resolution))}")
        if isinstance(self.jpeg_quality, bool) or not isinstance(self.jpeg_quality, int) or not 1 <= self.jpeg_quality <= 100:
            raise SpecError(f"jpeg_quality must be an integer in [1, 100], got {shorten(repr(self.jpeg_quality))}")
        if renderer_of(self.dataset_version) is None:
            raise SpecError(f"dataset_version {self.dataset_version!r} is not one this code writes")
        if not isinstance(self.hand_model, str) or (self.hand_model and self.hand_model != HAND_MODEL):
            raise SpecError(f"hand_model must be {HAND_MODEL!r} (or absent: a run from before the hand body), "
                            f"got {shorten(repr(self.hand_model))}")
        if self.protocol is not None and not isinstance(self.protocol, dict):
            raise SpecError(f"protocol must be an object or None, got {shorten(repr(self.protocol))}")

    @property
    def renderer(self) -> str:
        """The renderer that draws this dataset version's frames."""
        renderer = renderer_of(self.dataset_version)
        assert renderer is not None  # checked in __post_init__
        return renderer

    def to_dict(self) -> dict[str, Any]:
        """The manifest's settings; ``obstacle_clearance``, ``protocol`` and ``hand_model`` only
        when set, so builds without obstacles and plain runs keep the settings (and hashes)
        they always had."""
        out = asdict(self)
        if not self.obstacle_clearance:
            del out["obstacle_clearance"]
        if self.protocol is None:
            del out["protocol"]
        if not self.hand_model:
            del out["hand_model"]
        out["formats"] = list(self.formats)
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> BuildSettings:
        """The settings a manifest stores (:meth:`to_dict`'s object); SpecError naming an
        unknown or missing key, or a bad value."""
        if not isinstance(data, Mapping):
            raise SpecError(f"settings must be an object, got {shorten(repr(data))}")
        unknown = sorted(set(data) - set(setting_names()))
        if unknown:
            raise SpecError(f"unknown settings {unknown}: written by another version of Dyana?")
        missing = [name for name in ("resolution", "jpeg_quality", "dataset_version") if name not in data]
        if missing:
            raise SpecError(f"settings lack {missing[0]!r}")
        return cls(**dict(data))


def setting_names() -> tuple[str, ...]:
    """The names of :class:`BuildSettings`' fields, in order."""
    return tuple(f.name for f in fields(BuildSettings))


def setting_docs() -> dict[str, Setting]:
    """Each byte setting's :class:`Setting`, by name, in field order."""
    return {f.name: f.metadata["setting"] for f in fields(BuildSettings)}


def setting_flags() -> dict[str, str]:
    """CLI flag -> the byte setting it chooses."""
    return {flag: name for name, doc in setting_docs().items() for flag in doc.flags}


__all__ = ["JPEG_QUALITY", "BuildSettings", "Setting", "setting_docs", "setting_flags",
           "setting_names"]

"""The dataset card of a LeRobot export (``README.md``): the Hugging Face Hub's YAML header,
whose ``configs`` point `datasets` at the frames' Parquet files (so
``datasets.load_dataset(EXPORT)`` loads the frames, not the metadata tables beside them),
then what the export holds, how it was built (each source's slice hash), its license and
the paper's citation. Its bytes depend only on the sources and settings.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from typing import Any

from catalog.export.camera import CAMERA_META
from catalog.export.croissant import CROISSANT, DATA_FILES
from catalog.export.layout import DYANA_META, VECTOR_NAMES, vector_names
from catalog.loader.lerobot_names import IMAGE_KEY
from catalog.tables.reader import FolderReader
from schemas.renderers import DEFAULT_RENDERER, renderer_of
from schemas.runs import is_run

#: Dyana's license (pyproject.toml), which the data it generates is released under.
LICENSE = "Apache-2.0"
LICENSE_HUB = "apache-2.0"
LICENSE_URL = "https://spdx.org/licenses/Apache-2.0.html"
#: The paper, as its text names it: an anonymous submission (no title line, no authors).
CITATION = """@misc{dgs_dyana12m_2026,
  title  = {Dynamic Grasp Suite (DGS) and Dyana-12M},
  author = {Anonymous},
  note   = {Under review as a conference paper at ICLR 2026},
  year   = {2026}
}"""
KEYWORDS = ("LeRobot", "robotics", "dynamic grasping", "dexterous hand", "simulation", "Dyana")


def title(readers: Sequence[FolderReader]) -> str:
    """The dataset's name: its sources' slices."""
    slices = [r.manifest.slice for r in readers]
    named = ", ".join(slices[:3]) + (f" and {len(slices) - 3} more" if len(slices) > 3 else "")
    return f"Dyana LeRobot export: {named}"


def description(readers: Sequence[FolderReader], episodes: int, frames: int, version: str) -> str:
    """One paragraph: what the dataset is."""
    kind = "evaluated runs" if any(is_run(r.manifest.extra) for r in readers) else "built episodes"
    return (f"{episodes} episodes ({frames} frames at 20 fps) of simulated dynamic grasping by a 15-joint hand, "
            f"{kind} of Dyana (a deterministic implementation of the paper's Dynamic Grasp Suite / Dyana-12M "
            f"recipe), as one LeRobot {version} dataset: an egocentric camera video, the hand's state and its actions.")


def _shard_size(reader: FolderReader) -> int:
    first, end = reader.manifest.shards[0].episodes
    return end - first


def _source_lines(reader: FolderReader) -> list[str]:
    m = reader.manifest
    settings = json.dumps(dict(m.settings), sort_keys=True)
    lines = [f"- `{m.slice}`: slice hash `{m.hash}`, {m.episodes} episodes, {m.frames} frames, seed {m.seed}; "
             f"settings `{settings}`"]
    if is_run(m.extra):
        lines.append(f"  (an evaluated run of policy `{m.extra['policy']}`: `pipeline eval`)")
    else:
        lines.append(f"  (`{_build_command(reader)}` builds it: a folder of this slice hash)")
    return lines


def _build_command(reader: FolderReader) -> str:
    """The ``pipeline build`` that makes a folder of this slice hash (the byte settings' flags)."""
    m = reader.manifest
    flags = [f"--slice {m.slice}", f"--episodes {m.episodes}", f"--shard-size {_shard_size(reader)}",
             f"--resolution {m.settings.get('resolution')}"]
    renderer = renderer_of(m.settings.get("dataset_version"))
    if renderer is not None and renderer != DEFAULT_RENDERER:
        flags.append(f"--renderer {renderer}")
    formats = m.settings.get("formats")
    if isinstance(formats, (list, tuple)) and list(formats) != ["parquet", "mcap"]:
        flags.append(f"--formats {','.join(formats)}")
    return "pipeline build " + " ".join(flags) + " --out out"


def _export_command(settings: Mapping[str, Any], readers: Sequence[FolderReader]) -> str:
    flags = [f"--format {settings['format']}"]
    if settings["codec"] != "h264":
        flags.append(f"--codec {settings['codec']}")
    if settings["environment_state"]:
        flags.append("--environment-state")
    folders = " ".join(f"out/{r.manifest.slice}" for r in readers)
    return f"catalog export {folders} {' '.join(flags)} --out EXPORT"


def readme(readers: Sequence[FolderReader], settings: Mapping[str, Any], version: str, episodes: int, frames: int,
           height: int, width: int) -> str:
    """``README.md``: the YAML header, then the card in Markdown."""
    header = [
        "---",
        f"license: {LICENSE_HUB}",
        "task_categories:",
        "- robotics",
        "tags:",
        *(f"- {tag}" for tag in ("LeRobot", "dyana", "dynamic-grasping", "simulation")),
        "configs:",
        "- config_name: default",
        f"  data_files: {DATA_FILES}",
        "---",
    ]
    vectors = vector_names(bool(settings["environment_state"]))
    features = [f"- `{key}` ({len(names)}): {', '.join(VECTOR_NAMES[key])}" for key, names in vectors.items()]
    body = [
        f"# {title(readers)}",
        "",
        description(readers, episodes, frames, version),
        "",
        "## Contents",
        "",
        f"- `{IMAGE_KEY}`: the egocentric camera, {width}x{height} px, "
        f"{settings['codec']} video under `videos/`",
        *features,
        "- `timestamp`, `frame_index`, `episode_index`, `index`, `task_index`; the task texts in `meta/tasks`",
        "- per episode (`meta/episodes`): LeRobot's columns and `dyana/...` facts (slice, motion type, object, "
        "seed, the episode's spec and its source)",
        f"- `{CAMERA_META}`: the camera's intrinsics at {width}x{height} (fx, fy, cx, cy, K) and its fixed pose "
        "(`world_to_camera`, in the frame of the state and actions)",
        f"- `{CROISSANT}`: Croissant 1.0 metadata (every file with its sha256; the frames and episodes record sets)",
        f"- `{DYANA_META}`: the sources, versions, codec build and every file's sha256",
        "",
        "## Loading",
        "",
        "```python",
        "import datasets",
        "",
        'frames = datasets.load_dataset("EXPORT", split="train")  # the frames; videos are separate',
        "```",
        "",
        f"With LeRobot {'0.4 or later' if version == 'v3.0' else '0.3.x (or convert it to v3.0 for later releases)'}:",
        "",
        "```python",
        "from lerobot.datasets.lerobot_dataset import LeRobotDataset",
        "",
        'dataset = LeRobotDataset("dyana/export", root="EXPORT")',
        "```",
        "",
        "## How it was built",
        "",
        "Deterministic: the same sources and settings give the same bytes (the videos with the same codec build, "
        f"recorded in `{DYANA_META}`). Sources, in export order:",
        "",
        *(line for reader in readers for line in _source_lines(reader)),
        "",
        "Exported with:",
        "",
        "```bash",
        _export_command(settings, readers),
        "```",
        "",
        "## License",
        "",
        f"{LICENSE}, Dyana's license (its `pyproject.toml`), for this data generated by Dyana. The paper states that "
        "its own code and data are released \"under a research license with an explicit non-misuse clause\" without "
        "naming it; this export is not that release.",
        "",
        "## Citation",
        "",
        "The paper Dyana implements. Its text names no title line and no authors (an anonymous submission); "
        "this entry names it by its suite and benchmark:",
        "",
        "```bibtex",
        CITATION,
        "```",
        "",
    ]
    return "\n".join(header + body)

"""LeRobot's key names are written once (catalog.loader.lerobot_names): the export, the keyed reader
and the closed loop's LeRobot policies import them, so they cannot drift apart."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np

from catalog.export.layout import VECTOR_NAMES, VIDEO_KEY, features
from catalog.loader.lerobot_keys import lerobot_item
from catalog.loader.lerobot_names import (
    ACTION_KEY,
    ENV_KEY,
    IMAGE_KEY,
    INDEX_FEATURES,
    STATE_KEY,
    VECTOR_SOURCES,
    pad_key,
)

ROOT = Path(__file__).resolve().parents[2]
HOME = ROOT / "catalog" / "loader" / "lerobot_names.py"
NAMES = ("observation.images", "observation.state", "observation.environment_state")


def _docstrings(tree: ast.AST) -> set[int]:
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                found.add(id(first.value))
    return found


def spelled_out(path: Path) -> list[str]:
    """The code strings (not docstrings or comments) of ``path`` that spell a LeRobot key."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skip = _docstrings(tree)
    return [f"{path.relative_to(ROOT)}:{node.lineno}: {node.value!r}" for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in skip
            and any(name in node.value for name in NAMES)]


def test_no_module_but_the_home_spells_a_lerobot_key():
    files = [p for package in ("schemas", "catalog", "generators", "scoring", "pipeline") for p in (ROOT / package).rglob("*.py")]
    assert HOME in files
    assert spelled_out(HOME)  # the scan sees the names where they are
    assert [line for path in files if path != HOME for line in spelled_out(path)] == []


def test_the_export_and_the_keyed_reader_use_the_one_mapping():
    assert VIDEO_KEY == IMAGE_KEY and set(VECTOR_NAMES) == set(VECTOR_SOURCES) == {STATE_KEY, ENV_KEY, ACTION_KEY}
    info = features(4, 6, 30, "h264", "v3.0", environment_state=True)
    assert list(info) == [IMAGE_KEY, STATE_KEY, ENV_KEY, ACTION_KEY, *INDEX_FEATURES]
    rng = np.random.default_rng(0)
    item = {"image": np.zeros((4, 6, 3), np.uint8), "timestamp": 0.5, "frame_index": 3, "episode_index": 1, "text": "t"}
    item |= {name: rng.random(n).astype(np.float32) for name, n in
             (("palm_pose", 6), ("joint_angles", 15), ("object_pose", 7), ("action", 18))}
    out = lerobot_item(item, index=9, task_index=0, image_dtype="float32")
    for key, sources in VECTOR_SOURCES.items():
        np.testing.assert_array_equal(out[key], np.concatenate([item[name] for name in sources]))
        assert len(info[key]["names"]) == out[key].shape[-1]
    assert out[IMAGE_KEY].shape == (3, 4, 6) and set(INDEX_FEATURES) <= set(out)
    assert pad_key(ACTION_KEY) == "action_is_pad"

"""One test says whether a folder is a run (schemas.runs.is_run): the reader, `catalog info`,
the episodes tables' kind, verify and the eval summary all ask it, and none tests the
``policy`` key itself."""

from __future__ import annotations

import ast
from pathlib import Path

from schemas.runs import RUN_KEY, is_run
from schemas.tables import EPISODES_SCHEMA, ROLLOUT_EPISODES_SCHEMA

ROOT = Path(__file__).resolve().parents[2]
HOME = ROOT / "schemas" / "runs.py"


def membership_tests(source: str) -> list[int]:
    """The lines of ``"policy" in X`` / ``"policy" not in X`` in ``source``."""
    return [node.lineno for node in ast.walk(ast.parse(source))
            if isinstance(node, ast.Compare) and isinstance(node.left, ast.Constant) and node.left.value == RUN_KEY
            and any(isinstance(op, (ast.In, ast.NotIn)) for op in node.ops)]


def test_a_run_names_its_policy_in_its_manifest_and_its_episodes_tables():
    assert is_run({"policy": "chase", "privileged": False}) and not is_run({"held_out": {}})
    assert is_run(ROLLOUT_EPISODES_SCHEMA.names) and not is_run(EPISODES_SCHEMA.names)


def test_no_module_but_the_home_tests_the_policy_key():
    files = [p for package in ("schemas", "catalog", "generators", "scoring", "pipeline") for p in (ROOT / package).rglob("*.py")]
    assert membership_tests('x = 1\nif "policy" in m.extra or "policy" not in names:\n    pass\n') == [2, 2]
    hits = [f"{path.relative_to(ROOT)}:{line}" for path in files if path != HOME
            for line in membership_tests(path.read_text(encoding="utf-8"))]
    assert hits == []

"""The house rules a reviewer would otherwise check by hand: no private name crosses a
module boundary, and no production module grows past 500 lines. (Layers and import
cycles are import-linter's contract in pyproject.toml, run by .ci/run.)"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("schemas", "generators", "catalog", "pipeline", "scoring")
MAX_LINES = 500


def _modules() -> list[tuple[str, Path]]:
    out = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            name = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
            out.append((name, path))
    return out


def test_no_private_name_imported_across_modules() -> None:
    crossings = []
    for name, path in _modules():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                if node.module.split(".")[0] in PACKAGES and node.module != name:
                    crossings += [f"{name} imports {node.module}.{a.name}" for a in node.names if a.name.startswith("_")]
    assert not crossings, "\n".join(crossings)


def test_every_module_is_at_most_500_lines() -> None:
    """All modules in one test: its failure lists every module over the cap."""
    too_long = []
    for _, path in _modules():
        lines = len(path.read_text(encoding="utf-8").splitlines())
        if lines > MAX_LINES:
            too_long.append(f"{path.relative_to(ROOT)} has {lines} lines")
    assert not too_long, f"at most {MAX_LINES} lines a module, split these by job:\n" + "\n".join(too_long)

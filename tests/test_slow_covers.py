"""A test marked ``slow`` names the faster test, run by ``.ci/run``, that covers it.

``slow`` is for end-to-end runs that repeat at more cost what a faster test checks
(README.md, on command 2): ``@pytest.mark.slow(cover="tests/x/test_y.py::test_z")``; the cover
runs in the default run or in another step of ``.ci/run`` (the manual's pages).
This reads every test file's source (no import, no collection) and checks each
``pytest.mark.slow`` has a ``cover`` naming a test function defined in that file,
one that is not itself marked slow.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"


def _is_slow(node: ast.AST) -> bool:
    """``pytest.mark.slow`` (bare or called)."""
    target = node.func if isinstance(node, ast.Call) else node
    return isinstance(target, ast.Attribute) and target.attr == "slow" and ast.unparse(target) == "pytest.mark.slow"


def _slow_marks(tree: ast.AST) -> list[ast.AST]:
    """Every ``pytest.mark.slow`` expression, counted once (a call, not also its callee)."""
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call) and _is_slow(n)]
    callees = {id(c.func) for c in calls}
    bare = [n for n in ast.walk(tree) if isinstance(n, ast.Attribute) and _is_slow(n) and id(n) not in callees]
    return sorted([*calls, *bare], key=lambda n: (n.lineno, n.col_offset))


def _functions(path: Path) -> dict[str, ast.FunctionDef]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return {n.name: n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}


def _marked_slow(function: ast.FunctionDef) -> bool:
    return any(_is_slow(d) for d in function.decorator_list)


def cover_problems(path: Path, root: Path = ROOT) -> list[str]:
    """What is wrong with the ``slow`` marks of one test file (empty: nothing)."""
    problems = []
    where = path.relative_to(root).as_posix()
    for mark in _slow_marks(ast.parse(path.read_text(encoding="utf-8"))):
        at = f"{where}:{mark.lineno}"
        covers = [k.value for k in mark.keywords if k.arg == "cover"] if isinstance(mark, ast.Call) else []
        if not covers or not isinstance(covers[0], ast.Constant) or not isinstance(covers[0].value, str):
            problems.append(f'{at}: pytest.mark.slow without cover="tests/...py::test_name" (the faster test that covers it)')
            continue
        cover = covers[0].value
        file, sep, name = cover.partition("::")
        name = name.split("[")[0]
        target = root / file
        if not sep or not file.startswith("tests/") or not name.startswith("test_") or not target.is_file():
            problems.append(f"{at}: cover {cover!r} is not tests/...py::test_name of an existing file")
            continue
        function = _functions(target).get(name)
        if function is None:
            problems.append(f"{at}: cover {cover!r}: {file} defines no {name}")
        elif _marked_slow(function):
            problems.append(f"{at}: cover {cover!r} is itself marked slow")
    return problems


def test_every_slow_test_names_its_faster_cover() -> None:
    problems = [p for path in sorted(TESTS.rglob("*.py")) for p in cover_problems(path)]
    assert not problems, "\n".join(problems)


def test_a_slow_mark_without_a_valid_cover_is_named(tmp_path: Path) -> None:
    tests = tmp_path / "tests"
    tests.mkdir()
    (tests / "test_fast.py").write_text("import pytest\n\n\ndef test_quick():\n    pass\n\n\n"
                                        "@pytest.mark.slow(cover='tests/test_fast.py::test_quick')\n"
                                        "def test_also_slow():\n    pass\n")
    (tests / "test_slow.py").write_text(
        "import pytest\n\n\n@pytest.mark.slow\ndef test_a():\n    pass\n\n\n"
        "@pytest.mark.slow(cover='tests/test_fast.py::test_missing')\ndef test_b():\n    pass\n\n\n"
        "@pytest.mark.parametrize('x', [pytest.param(1, marks=pytest.mark.slow(cover='tests/test_fast.py::test_quick[1]'))])\n"
        "def test_c(x):\n    pass\n\n\n"
        "@pytest.mark.slow(cover='tests/test_fast.py::test_also_slow')\ndef test_d():\n    pass\n"
    )
    problems = [p for path in sorted(tests.glob("*.py")) for p in cover_problems(path, tmp_path)]
    assert problems == [
        "tests/test_slow.py:4: pytest.mark.slow without cover=\"tests/...py::test_name\" (the faster test that covers it)",
        "tests/test_slow.py:9: cover 'tests/test_fast.py::test_missing': tests/test_fast.py defines no test_missing",
        "tests/test_slow.py:19: cover 'tests/test_fast.py::test_also_slow' is itself marked slow",
    ], problems

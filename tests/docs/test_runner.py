"""The runner itself, on small made-up pages: what the conventions promise page authors."""

from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path

import pytest

from tests.docs import build_cache
from tests.docs.build_cache import cache_key
from tests.docs.pages import ROOT, Marker, parse
from tests.docs.runner import BlockFailed, PageRun

PAGE = """# A page

<!-- docs-setup: echo set-up > setup.txt -->

```bash
export GREETING=hello
mkdir sub && cd sub && echo "$GREETING" > note.txt
```

```text
not run: output
```

```python
import os
seen = open("note.txt").read().strip()
os.environ["FROM_PYTHON"] = seen + "!"
```

<!-- docs-test: skip needs a cloud bucket -->
```bash
exit 3
```

<!-- docs-test: needs a_module_that_is_not_installed -->
```python
raise SystemExit("must not run")
```

<!-- docs-test: slow -->
```bash
echo slow > slow.txt
```

```bash
test "$FROM_PYTHON" = "hello!" && test -f ../setup.txt && echo "$GREETING" > done.txt
```
"""


def _run(text: str, tmp_path: Path, with_slow: bool = False) -> tuple[Path, list[str]]:
    folder = tmp_path / "page"
    folder.mkdir()
    skipped = PageRun(parse("page.md", text), folder, dict(os.environ)).run(with_slow)
    return folder, skipped


def test_blocks_markers_and_setup_are_parsed() -> None:
    page = parse("page.md", PAGE)
    assert [(b.line, b.language) for b in page.blocks] == [
        (5, "bash"), (14, "python"), (21, "bash"), (26, "python"), (31, "bash"), (35, "bash")]
    assert page.setup == ("echo set-up > setup.txt",)
    assert page.blocks[2].marker == Marker("skip", "needs a cloud bucket")
    assert page.blocks[3].marker == Marker("needs", "a_module_that_is_not_installed")
    assert page.has_slow


def test_a_slow_block_may_need_a_module_too() -> None:
    from tests.docs.pages import Block
    from tests.docs.runner import runnable

    marker = Marker.parse("slow needs a_module_that_is_not_installed (covered by tests/docs/test_runner.py)")
    assert (marker.kind, marker.module, marker.cover) == ("slow", "a_module_that_is_not_installed",
                                                         "(covered by tests/docs/test_runner.py)")
    block = Block("p.md", 1, "python", "pass", marker)
    assert runnable(block, with_slow=False) == "slow (runs under -m slow)"
    assert runnable(block, with_slow=True) == "needs a_module_that_is_not_installed, not installed"
    assert Marker.parse("slow (covered by tests/x.py)").module is None


def test_blocks_share_folder_environment_and_namespace_in_page_order(tmp_path: Path) -> None:
    folder, skipped = _run(PAGE, tmp_path)
    assert (folder / "sub" / "done.txt").read_text() == "hello\n"
    assert not (folder / "sub" / "slow.txt").exists()
    assert [s.split(": ", 1)[0] for s in skipped] == ["page.md:21", "page.md:26", "page.md:31"]


def test_slow_blocks_run_when_asked(tmp_path: Path) -> None:
    folder, skipped = _run(PAGE, tmp_path, with_slow=True)
    assert (folder / "sub" / "slow.txt").exists()
    assert len(skipped) == 2


@pytest.mark.parametrize("block,line", [
    ("```bash\ntrue\nfalse | cat\n```", 3),  # pipefail: a failure inside a pipeline fails the block
    ("```python\nx = 1\nraise ValueError(x)\n```", 3),
    ("```bash\necho $UNSET_VARIABLE\n```", 3),  # nounset
])
def test_a_failing_block_names_its_page_and_line(block: str, line: int, tmp_path: Path) -> None:
    with pytest.raises(BlockFailed, match=f"^page.md:{line}: "):
        _run("# t\n\n" + block + "\n", tmp_path)


def test_background_processes_end_with_the_page(tmp_path: Path) -> None:
    started = time.monotonic()
    folder, _ = _run("```bash\nsleep 300 &\necho $! > pid\n```\n", tmp_path)
    assert time.monotonic() - started < 60, "a block waited for the process it left in the background"
    pid = int((folder / "pid").read_text())
    for _ in range(100):
        stat = Path(f"/proc/{pid}/stat")
        if not stat.exists() or stat.read_text().split()[2] == "Z":
            return  # ended (a zombie until its reaper collects it)
        time.sleep(0.05)
    pytest.fail("a process left in the background by a block outlived its page")


@pytest.mark.parametrize("argv,cacheable", [
    (["build", "--slice", "linear-fast", "--episodes", "32", "--shard-size", "16", "--out", "out"], True),
    (["build", "--slice", "linear-fast", "--episodes", "32", "--out", "s3://bucket/x"], False),
    (["build", "--specs", "mine.jsonl", "--out", "out"], False),
    (["build", "--slice", "linear-fast", "--overwrite"], False),
    (["eval", "--policy", "still", "--out", "run"], False),
])
def test_build_cache_keys_only_what_the_command_line_determines(argv: list[str], cacheable: bool) -> None:
    assert (cache_key(argv) is not None) == cacheable


def _key(argv: list[str]) -> str:
    found = cache_key(argv)
    assert found is not None, argv
    return found[0]


def test_build_cache_key_ignores_only_the_output_folder_and_quiet() -> None:
    base = ["build", "--slice", "linear-fast", "--episodes", "32"]
    assert _key([*base, "--out", "a"]) == _key([*base, "--out", "b", "--quiet"])
    assert _key([*base, "--out", "a"]) != _key([*base, "--shard-size", "8", "--out", "a"])
    assert _key([*base, "--workers", "1"]) != _key([*base, "--workers", "2"])


def test_the_shim_becomes_the_real_command(tmp_path: Path) -> None:
    """Anything but a cacheable build execs the real `pipeline` (same pid, so `kill $!` reaches it)."""
    real = tmp_path / "real"
    real.write_text("#!/bin/sh\necho real $$ \"$@\"\n")
    real.chmod(0o755)
    env = build_cache.install(tmp_path, tmp_path, str(real), ROOT)
    out = subprocess.run(["bash", "-c", f"{tmp_path / 'pipeline'} serve --port 0 & echo shim $!; wait"],
                         env={**os.environ, **env}, capture_output=True, text=True, check=True).stdout.split()
    assert out[0] == "shim" and out[2] == "real" and out[1] == out[3] and out[4:] == ["serve", "--port", "0"]

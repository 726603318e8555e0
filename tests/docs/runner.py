"""Running one page's blocks: bash and python in page order, in one temporary folder.

``python -m tests.docs.runner PAGE [PAGE ...] FOLDER [--with-slow]`` runs one page (or
several in order, in one folder, as a reader follows the manual) in a process of its
own (so pages run side by side and a page's imports, folder and environment stay out of
pytest), printing the blocks it did not run as JSON; a failure exits 1 with the page, line
and output on stderr.

- Each ``bash`` block is a ``bash -euo pipefail`` process started in the page's current
  folder; the variables it exports and the folder it ends in carry over to the next block
  (as in one terminal). ``python`` blocks run in this process, in one namespace per page,
  with the same folder and environment.
- The venv's ``bin/`` is first on PATH, behind a ``pipeline`` shim (build_cache.py) that
  copies the output of an identical earlier ``pipeline build`` instead of building again.
- Processes a block leaves in the background (a local S3 server) are ended with the page.
- A failure names the page and the line of the block's opening fence.
"""

from __future__ import annotations

import argparse
import importlib.util
import io
import json
import os
import signal
import subprocess
import sys
import traceback
from collections.abc import Iterator
from contextlib import contextmanager, redirect_stderr, redirect_stdout
from pathlib import Path

from tests.docs.pages import Block, Page, load

#: One block may take this long before it fails the page.
BLOCK_TIMEOUT_S = 600
#: The most of a failed block's output quoted in the failure.
OUTPUT_TAIL = 4000


class BlockFailed(AssertionError):
    pass


def runnable(block: Block, with_slow: bool) -> str | None:
    """None if the block runs, else why it does not."""
    marker = block.marker
    if marker is None:
        return None
    if marker.kind == "skip":
        return f"skip: {marker.argument}"
    if marker.kind == "slow" and not with_slow:
        return "slow (runs under -m slow)"
    if marker.module is not None and importlib.util.find_spec(marker.module) is None:
        return f"needs {marker.module}, not installed"
    return None


class PageRun:
    """The state one page's blocks share: folder, environment, namespace, background processes."""

    def __init__(self, page: Page, workdir: Path, env: dict[str, str]) -> None:
        self.page = page
        self.cwd = workdir
        self.state = workdir.parent / f"{workdir.name}.state"
        self.state.mkdir(exist_ok=True)
        self.env = dict(env)
        self.namespace: dict[str, object] = {"__name__": "__docs__"}
        self.groups: list[int] = []

    def bash(self, code: str, where: str) -> None:
        env0, cwd = self.state / "env0", self.state / "cwd"
        script = (f"trap 'env -0 > {_quote(env0)}; pwd > {_quote(cwd)}' EXIT\n"
                  f"cd {_quote(self.cwd)}\n{code}")
        log = self.state / "output"
        # Output goes to a file, not a pipe: a process the block leaves in the background
        # (a server) keeps its copy open, and a pipe would not end until that process does.
        with open(log, "wb") as sink:
            process = subprocess.Popen(
                ["bash", "-euo", "pipefail", "-c", script], cwd=self.cwd, env=self.env, stdin=subprocess.DEVNULL,
                stdout=sink, stderr=subprocess.STDOUT, start_new_session=True,
            )
        self.groups.append(process.pid)
        try:
            process.wait(timeout=BLOCK_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self._kill(process.pid)
            process.wait()
            raise BlockFailed(f"{where}: bash block still running after {BLOCK_TIMEOUT_S} s\n{_tail(log.read_bytes())}") from None
        if process.returncode != 0:
            raise BlockFailed(f"{where}: bash block failed (exit {process.returncode})\n{_tail(log.read_bytes())}")
        if env0.exists():
            pairs = (item.partition("=") for item in env0.read_bytes().decode(errors="replace").split("\0") if item)
            self.env = {key: value for key, _, value in pairs if key not in ("PWD", "OLDPWD", "SHLVL", "_")}
        if cwd.exists():
            self.cwd = Path(cwd.read_text().strip())

    def python(self, block: Block) -> None:
        code = compile("\n" * block.line + block.code, block.page, "exec")
        output = io.StringIO()
        with _process_state(self.cwd, self.env), redirect_stdout(output), redirect_stderr(output):
            try:
                exec(code, self.namespace)
            except BaseException as exc:  # a block's failure of any kind fails the page, with its place
                trace = output.getvalue() + "".join(traceback.format_exception(exc))
                raise BlockFailed(f"{block.where}: python block failed\n{_tail(trace)}") from None
            self.env = dict(os.environ)
            self.cwd = Path.cwd()

    def run(self, with_slow: bool) -> list[str]:
        """Run the setup commands and the blocks; the blocks not run, with why."""
        skipped = []
        try:
            for command in self.page.setup:
                self.bash(command, f"{self.page.path}: docs-setup {command!r}")
            for block in self.page.blocks:
                why = runnable(block, with_slow)
                if why is not None:
                    skipped.append(f"{block.where}: {why}")
                elif block.language == "bash":
                    self.bash(block.code, block.where)
                else:
                    self.python(block)
        finally:
            for group in self.groups:
                self._kill(group)
        return skipped

    @staticmethod
    def _kill(group: int) -> None:
        try:
            os.killpg(group, signal.SIGTERM)
        except (ProcessLookupError, PermissionError):
            pass


@contextmanager
def _process_state(cwd: Path, env: dict[str, str]) -> Iterator[None]:
    """This process's folder and environment set for a python block, and restored after."""
    old_cwd, old_env, old_path = os.getcwd(), dict(os.environ), list(sys.path)
    os.chdir(cwd)
    os.environ.clear()
    os.environ.update(env)
    sys.path.insert(0, str(cwd))
    try:
        yield
    finally:
        os.chdir(old_cwd)
        os.environ.clear()
        os.environ.update(old_env)
        sys.path[:] = old_path


def _quote(path: Path) -> str:
    return "'" + str(path).replace("'", "'\\''") + "'"


def _tail(output: bytes | str) -> str:
    text = output.decode(errors="replace") if isinstance(output, bytes) else output
    return text if len(text) <= OUTPUT_TAIL else "...\n" + text[-OUTPUT_TAIL:]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="run pages' ```bash and ```python blocks")
    parser.add_argument("page", nargs="+", help="the page (or pages, run in order as a reader follows them: "
                                                "one folder, the environment carried on), relative to the repository")
    parser.add_argument("folder", help="an empty folder to run them in")
    parser.add_argument("--with-slow", action="store_true", help="run the blocks marked slow too")
    args = parser.parse_args(argv)
    folder, env = Path(args.folder).resolve(), dict(os.environ)
    # Stopped (pytest interrupted, a timeout): still end the processes the page started.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(f"{' '.join(args.page)}: stopped"))
    skipped: list[str] = []
    for page in args.page:  # each page starts in the folder, as a reader opens it in their working folder
        run = PageRun(load(page), folder, env)
        try:
            skipped += run.run(args.with_slow)
        except BlockFailed as failed:
            print(failed, file=sys.stderr)
            return 1
        env = run.env
    print(json.dumps(skipped))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""How long the README's two first-screen commands take on a fresh clone of this commit.

Clones the repository's HEAD into a temporary folder, runs README command 1 (make a venv,
install, build 32 linear-fast episodes) and command 2 (``.ci/run``: install the extras,
lint, type-check, build the docs, run the tests), timing each and each ``== phase`` of
``.ci/run``, with the load average (``uptime``) and the bare baseline (``bench_setup.bare_probe``:
this machine's speed, which moves between runs) at the start and the end, and the machine's
CPU seconds in each phase (``bench_setup.machine_cpu``: busy, idle, and stolen by the host,
a load ``uptime`` does not show). Writes
``benchmarks/results/first_screen.json`` (the README's timing sentence and the benchmarks
page are generated from it) and, with ``--update-readme``, rewrites that sentence. The
commands run in this shell's environment less what a newcomer's lacks (:data:`NOT_A_NEWCOMERS`).

    python benchmarks/first_screen.py --update-readme

Several minutes on 2 cores, and it uses the network unless pip's cache holds everything.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Variables of this shell that a newcomer's does not have: another checkout on the path, an
#: active venv, and Python told not to write bytecode (command 1's build and every process
#: of ``.ci/run`` outside the tests would compile Dyana's modules at each start).
NOT_A_NEWCOMERS = ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONDONTWRITEBYTECODE")
COMMAND_1 = ("python3 -m venv .venv && .venv/bin/pip install -c .ci/constraints.txt -e . && "
             ".venv/bin/pipeline build --slice linear-fast --episodes 32 --shard-size 16 --out out")
COMMAND_2 = ".ci/run"
README_MARK = re.compile(r"(<!-- first-screen -->\n).*?(\n<!-- /first-screen -->)", re.S)


def _uptime() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def _timed(command: str, cwd: Path, env: dict[str, str]) -> tuple[float, dict[str, float], str, dict[str, str], dict]:
    """Seconds, seconds per ``== phase`` line printed, the output's last lines, each
    phase's pytest summary line (``N passed ...``), if it printed one, and each phase's
    machine CPU seconds (busy, idle, steal)."""
    import bench_setup

    start = time.monotonic()
    cpu_start = bench_setup.machine_cpu()
    phase_cpu: dict[str, dict | None] = {}
    process = subprocess.Popen(["bash", "-euo", "pipefail", "-c", command], cwd=cwd, env=env, text=True,
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    assert process.stdout is not None
    phases: dict[str, float] = {}
    phase, phase_start = "install", start
    tail: list[str] = []
    summaries: dict[str, str] = {}
    log = tempfile.NamedTemporaryFile("w", prefix="dyana-first-screen-", suffix=".log", delete=False)
    for line in process.stdout:
        log.write(line)
        tail = (tail + [line.rstrip()])[-20:]
        if re.search(r"\d+ passed", line):
            summaries[phase] = line.strip()
        if line.startswith("== "):
            now, cpu_now = time.monotonic(), bench_setup.machine_cpu()
            phases[phase] = round(now - phase_start, 1)
            phase_cpu[phase] = bench_setup.cpu_between(cpu_start, cpu_now)
            phase, phase_start, cpu_start = line[3:].strip().split(" ")[0], now, cpu_now
    log.close()
    if process.wait() != 0:
        sys.exit(f"{command!r} failed in {cwd} (its whole output: {log.name}):\n" + "\n".join(tail))
    os.unlink(log.name)
    end = time.monotonic()
    phases[phase] = round(end - phase_start, 1)
    phase_cpu[phase] = bench_setup.cpu_between(cpu_start, bench_setup.machine_cpu())
    return round(end - start, 1), phases, "\n".join(tail), summaries, phase_cpu


def measure(python: str) -> dict:
    import bench_setup  # the script's folder is first on sys.path

    where = bench_setup.provenance()  # the clone below is of this commit: a changed tree is not in it
    env = {k: v for k, v in os.environ.items() if k not in NOT_A_NEWCOMERS}
    env["PATH"] = f"{Path(python).parent}{os.pathsep}{env.get('PATH', '')}"
    record: dict = {"benchmark": "first_screen", "commit": where["commit"], "tree_changed": where["tree_changed"],
                    "dataset_version": where["dataset_version"],
                    "date_utc": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
                    "cores": len(os.sched_getaffinity(0)), "pip_cache": "as found on this machine",
                    "load_average_start": [round(x, 2) for x in os.getloadavg()], "uptime_start": _uptime(),
                    "bare_probe_s_start": bench_setup.bare_probe(), "bare_probe_terms": bench_setup.PROBE_TERMS}
    with tempfile.TemporaryDirectory(prefix="dyana-first-screen-") as tmp:
        clone = Path(tmp) / "dyana"
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        seconds, _, tail, _, _ = _timed(COMMAND_1, clone, env)
        found = re.search(r"hash ([0-9a-f]{16})", tail)
        record["command_1"] = {"command": COMMAND_1, "seconds": seconds, "hash": found.group(1) if found else None}
        seconds, phases, _, summaries, phase_cpu = _timed(COMMAND_2, clone, env)
        # the default test run's line ("== tests"), the manual's pages' and the peer run's
        record["command_2"] = {"command": COMMAND_2, "seconds": seconds, "phases": phases, "phases_machine_cpu": phase_cpu,
                               "tests_summary": summaries.get("tests"), "manual_summary": summaries.get("manual"),
                               "peer_summary": summaries.get("real")}
    record["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
    record["uptime_end"] = _uptime()
    record["bare_probe_s_end"] = bench_setup.bare_probe()
    return record


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--python", default=sys.executable, help="the python3 that makes the venvs (3.11+)")
    parser.add_argument("--update-readme", action="store_true", help="rewrite README.md's timing sentence")
    args = parser.parse_args()
    # Its commands start as in a newcomer's terminal, with Ctrl-C's default action, even where this
    # script was started with SIGINT ignored (`cmd &` in a script), which every process under it would keep.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    record = measure(args.python)
    out = ROOT / "benchmarks" / "results" / "first_screen.json"
    out.write_text(json.dumps(record, indent=1) + "\n")
    if args.update_readme:
        sys.path.insert(0, str(ROOT / "docs" / "hooks"))
        from results_pages import first_screen_sentence  # docs/hooks is no package: found by path

        readme = ROOT / "README.md"
        text = readme.read_text(encoding="utf-8")
        readme.write_text(README_MARK.sub(lambda m: m.group(1) + first_screen_sentence(ROOT) + m.group(2), text))
    print(json.dumps(record))


if __name__ == "__main__":
    main()

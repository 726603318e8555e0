"""Do the bytes depend on the CPU's SIMD features? Builds and runs with AVX-512 shown to and hidden from numpy.

numpy picks, at import, the SIMD code of many functions by the CPU it runs on; on another
host (another CPU) the same call can take another path. ``NPY_DISABLE_CPU_FEATURES`` hides
features from numpy, so one machine can show what a host without them would compute. This
script runs, in fresh processes, with the features as found and with ``--hidden`` hidden:

* README command 1's build (``linear-fast``, 32 episodes, shards of 16) and small ``oracle``,
  ``predictive`` and ``chase`` runs on test-1k, comparing the slice hashes;
* a probe of numpy's transcendental functions: each on 256 inputs one at a time and in one
  array, so a function whose value depends on the CPU (a hash that differs between the
  modes) or on the array's length (the two hashes of one mode differ) is named.

It writes ``benchmarks/results/cpu_dispatch.json`` with its commit, dataset version, CPU
features and load. On a CPU without the hidden features both modes are the same run.

    python benchmarks/cpu_dispatch.py
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import bench_setup  # noqa: F401  (first: fixes sys.path, see bench_setup)

ROOT = Path(__file__).resolve().parents[1]
#: What a host without AVX-512 lacks, in numpy 2.x's names.
HIDDEN = "X86_V4 AVX512_ICL AVX512_SPR"
JOBS = {
    "build linear-fast 32": ["build", "--slice", "linear-fast", "--episodes", "32", "--shard-size", "16"],
    "eval oracle test-1k 4 @64": ["eval", "--policy", "oracle", "--slice", "test-1k", "--episodes", "4",
                                  "--resolution", "64", "--workers", "1"],
    "eval chase test-1k 4 @64": ["eval", "--policy", "chase", "--slice", "test-1k", "--episodes", "4",
                                 "--resolution", "64", "--workers", "1"],
    "eval predictive test-1k 6 @96": ["eval", "--policy", "predictive", "--slice", "test-1k", "--episodes", "6",
                                      "--resolution", "96", "--workers", "1"],
}
PROBE = """
import hashlib, json, numpy as np
from numpy._core._multiarray_umath import __cpu_features__ as features
rng = np.random.default_rng(0)
x, y, u = rng.uniform(-3, 3, 256), rng.uniform(-3, 3, 256), rng.uniform(-1, 1, 256)
funcs = {"sin": lambda a, b, c: np.sin(a), "cos": lambda a, b, c: np.cos(a), "tan": lambda a, b, c: np.tan(a),
         "sqrt": lambda a, b, c: np.sqrt(np.abs(a)), "exp": lambda a, b, c: np.exp(a),
         "log": lambda a, b, c: np.log(np.abs(a) + 1), "power": lambda a, b, c: np.power(np.abs(a), 1.7),
         "arctan": lambda a, b, c: np.arctan(a), "arctan2": lambda a, b, c: np.arctan2(a, b),
         "arcsin": lambda a, b, c: np.arcsin(c), "arccos": lambda a, b, c: np.arccos(c),
         "hypot": lambda a, b, c: np.hypot(a, b)}
out = {}
for name, f in funcs.items():
    one = np.concatenate([f(x[i:i + 1], y[i:i + 1], u[i:i + 1]) for i in range(256)])
    whole = f(x, y, u)
    out[name] = [hashlib.sha256(one.tobytes()).hexdigest()[:16], hashlib.sha256(whole.tobytes()).hexdigest()[:16]]
print(json.dumps({"functions": out, "avx512f": bool(features["AVX512F"]), "avx512_spr": bool(features["AVX512_SPR"])}))
"""


def _env(hidden: str | None) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "NPY_DISABLE_CPU_FEATURES"}
    if hidden:
        env["NPY_DISABLE_CPU_FEATURES"] = hidden
    return env


def _job(args: list[str], out: Path, env: dict[str, str]) -> str:
    done = subprocess.run([sys.executable, "-m", "pipeline.cli", *args, "--out", str(out), "--quiet"], cwd=ROOT,
                          env=env, capture_output=True, text=True, timeout=1800)
    found = re.search(r"hash ([0-9a-f]{16})", done.stdout + done.stderr)
    if done.returncode != 0 or found is None:
        sys.exit(f"{' '.join(args)} failed:\n{done.stderr[-2000:]}")
    return found.group(1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--hidden", default=HIDDEN, help=f"the features hidden from numpy (default: {HIDDEN!r})")
    args = parser.parse_args()
    where = bench_setup.provenance()
    record: dict = {"benchmark": "cpu_dispatch", **{k: v for k, v in where.items() if k != "load_average"},
                    "hidden": args.hidden, "load_average_start": where["load_average"]}
    print(f"{len(JOBS)} jobs and a probe, each with numpy's CPU features as found and with {args.hidden!r} hidden",
          flush=True)
    start = time.monotonic()
    modes = {"as found": None, "hidden": args.hidden}
    with tempfile.TemporaryDirectory(prefix="dyana-dispatch-") as tmp:
        record["hashes"] = {}
        for name, job in JOBS.items():
            record["hashes"][name] = {mode: _job(job, Path(tmp) / f"{mode}-{len(record['hashes'])}".replace(" ", "-"),
                                                 _env(hidden)) for mode, hidden in modes.items()}
            same = len(set(record["hashes"][name].values())) == 1
            print(f"[{time.monotonic() - start:.0f} s] {name}: {'same bytes' if same else 'DIFFERENT bytes'} "
                  f"{record['hashes'][name]}", flush=True)
    probes = {mode: json.loads(subprocess.run([sys.executable, "-c", PROBE], env=_env(hidden), capture_output=True,
                                              text=True, check=True).stdout) for mode, hidden in modes.items()}
    record["cpu"] = {mode: {k: v for k, v in p.items() if k != "functions"} for mode, p in probes.items()}
    record["functions"] = {
        name: {"depends_on_cpu": probes["as found"]["functions"][name] != probes["hidden"]["functions"][name],
               "depends_on_array_length": any(p["functions"][name][0] != p["functions"][name][1] for p in probes.values())}
        for name in probes["as found"]["functions"]
    }
    for name, flags in record["functions"].items():
        print(f"  {name:8} cpu-dependent: {flags['depends_on_cpu']!s:5}  length-dependent: {flags['depends_on_array_length']}")
    record["seconds"] = round(time.monotonic() - start, 1)
    record["load_average_end"] = [round(v, 2) for v in os.getloadavg()]
    out = ROOT / "benchmarks" / "results" / "cpu_dispatch.json"
    out.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
    print(f"-> {out}")


if __name__ == "__main__":
    main()

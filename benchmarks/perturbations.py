"""How negligible the robustness perturbations are: each one's PSNR against the clean
decoded frame, over every frame of some test-1k episodes (224 px), at its default
strength. The last line printed is JSON.

    python benchmarks/perturbations.py --episodes 20
"""

from __future__ import annotations

import argparse
import json
import sys

import bench_setup  # noqa: F401  (first: fixes sys.path)
import numpy as np

from generators.encode import decode_jpeg  # noqa: E402
from generators.recipe import spec_for  # noqa: E402
from pipeline.loop.perturb import PERTURBATIONS, Perturbation, perturbation_rng, psnr  # noqa: E402
from pipeline.stages.episode import episode  # noqa: E402
from pipeline.stages.record import encoded_frames  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--resolution", type=int, default=224)
    args = parser.parse_args(argv)
    values: dict[str, list[float]] = {name: [] for name in PERTURBATIONS}
    for index in range(args.episodes):
        spec = spec_for("test-1k", index)
        for k, data in enumerate(encoded_frames(spec, episode(spec), args.resolution, 90)):
            clean = decode_jpeg(data)
            for name in PERTURBATIONS:
                perturbed = Perturbation(name).apply(clean, perturbation_rng(spec.spec_hash, 0, k))
                values[name].append(psnr(clean, perturbed))
    result = {}
    for name, psnrs in values.items():
        finite = np.array([v for v in psnrs if np.isfinite(v)])
        result[name] = {
            "strength": Perturbation(name).strength,
            "frames": len(psnrs),
            "psnr_min": round(float(finite.min()), 2),
            "psnr_median": round(float(np.median(finite)), 2),
            "identical_frames": len(psnrs) - len(finite),
        }
        r = result[name]
        print(f"{name:7s} strength {r['strength']:5g}: PSNR min {r['psnr_min']:.1f} dB, median {r['psnr_median']:.1f} dB"
              f" over {r['frames']} frames", file=sys.stderr)
    print(json.dumps({"benchmark": "perturbations", "episodes": args.episodes, "resolution": args.resolution,
                      "perturbations": result}))
    return 0


if __name__ == "__main__":
    sys.exit(main())

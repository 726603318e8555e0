"""Fit ``blind-fitted``'s paths from training episodes only: ``python -m pipeline.policies.blind_fit``.

For each interception setting, the ground truth of the first :data:`EPISODES_PER_SLICE`
episodes of each training slice with that setting (``linear-``, ``circular-``,
``harmonic-<setting>``, parts of Dyana-12M; never test-1k, test-complex or any held-out
slice) gives, per acting frame, the mean palm position (an episode shorter than the
longest holds its last position), and the median acting frame at which it starts to
close the hand (its first ``grasp`` frame). Writes ``blind_path.json`` beside this module
(rounded to 1e-4), which :class:`pipeline.policies.blind.FittedPolicy` reads. A pure
function of the public recipe: running it again writes the same bytes.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence

import numpy as np

from generators.recipe import spec_for
from pipeline.policies.blind import PATH_FILE
from pipeline.stages.episode import episode
from schemas.scene import INTERCEPT_SECONDS, MOTION_TYPES, PHASES
from schemas.slices import ATOMIC_SLICES

#: Ground-truth episodes read from each training slice.
EPISODES_PER_SLICE = 40
GRASP = PHASES.index("grasp")


def training_slices(setting: str) -> tuple[str, ...]:
    """The training slices of one interception setting (atomic slices of Dyana-12M)."""
    names = tuple(f"{motion}-{setting}" for motion in MOTION_TYPES)
    assert all(name in ATOMIC_SLICES for name in names)
    return names


def fit_setting(setting: str, episodes_per_slice: int = EPISODES_PER_SLICE) -> dict[str, object]:
    """The mean palm path and median closing frame of one setting's training episodes."""
    paths, closes = [], []
    for name in training_slices(setting):
        for index in range(episodes_per_slice):
            spec = spec_for(name, index)
            gt = episode(spec)
            first = spec.observe_frames
            paths.append(np.asarray(gt.palm_pose, dtype=np.float64)[first:, :3])
            closes.append(int(np.flatnonzero(np.asarray(gt.phase)[first:] == GRASP)[0]))
    longest = max(len(p) for p in paths)
    padded = np.stack([np.concatenate([p, np.repeat(p[-1:], longest - len(p), axis=0)]) for p in paths])
    mean = np.round(padded.mean(axis=0), 4)
    return {"palm": mean.tolist(), "close_frame": int(np.median(closes))}


def fit(episodes_per_slice: int = EPISODES_PER_SLICE) -> dict[str, object]:
    """The whole file's content: where it came from and one path per setting."""
    return {
        "made_by": "python -m pipeline.policies.blind_fit",
        "training_slices": [name for setting in INTERCEPT_SECONDS for name in training_slices(setting)],
        "episodes_per_slice": episodes_per_slice,
        "paths": {setting: fit_setting(setting, episodes_per_slice) for setting in INTERCEPT_SECONDS},
    }


def main(argv: Sequence[str] | None = None) -> int:
    PATH_FILE.write_text(json.dumps(fit(), separators=(",", ":")) + "\n")
    print(f"wrote {PATH_FILE}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

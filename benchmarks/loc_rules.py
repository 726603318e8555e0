"""Candidate S_loc rules, computed offline from a recorded run's palm and object per frame.

Reads a run as scoring does (:func:`scoring.io.load_run`: the acting frames, the episode
errors, the tops) and applies, per episode, the frame test of the ``dyana`` reading
("over": XZ distance d <= ``LOC_TOLERANCE`` and 0 <= h <= ``TOP_BAND`` above the top; d in
3D to the hover point and no band for a flying object, as :func:`scoring.metrics.episode_metrics`)
and then one of the rules of :data:`RULES`. An episode in error never counts (as scoring).
Nothing here changes :mod:`scoring`; it is a measurement for choosing a rule (issue 38).
``python benchmarks/loc_rules.py RUN [RUN ...]`` prints every rule's S_loc per run;
``benchmarks/blind_adversaries.py`` tabulates them with intervals.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

try:
    import bench_setup  # noqa: F401  (run as a script: puts the repository first on sys.path)
except ModuleNotFoundError:  # imported as benchmarks.loc_rules
    pass

from generators.ground_truth import episode_grasp
from generators.recipe import spec_for
from schemas import events
from scoring.io import RunData
from scoring.metrics import TOP_BAND, wilson_interval

#: Relative XZ speed (units per frame) under which the palm counts as holding over the
#: object (0.1 = 2 units/s = 0.2 m/s, a tenth of the body's top speed).
TRACK_SPEED = 0.1


def longest_run(flags: np.ndarray) -> int:
    """The longest run of True in ``flags`` (k,)."""
    best = run = 0
    for flag in flags:
        run = run + 1 if flag else 0
        best = max(best, run)
    return best


class Episode:
    """One episode's acting frames: ``over`` (k,), the palm/object XZ velocities, the grasp frame."""

    def __init__(self, data: RunData, e: int, grasp: np.ndarray):
        lo, hi = int(data.offsets[e]), int(data.offsets[e + 1])
        palm = np.asarray(data.palm_xyz[lo:hi], dtype=np.float64)
        obj = np.asarray(data.object_xyz[lo:hi], dtype=np.float64)
        hover = None if data.hover_offset is None else float(data.hover_offset[e])
        flying = hover is not None and not np.isnan(hover)
        if flying:
            d = events.palm_distance(palm, obj, np.full(len(palm), hover))
            over = events.within_tolerance(d)
        else:
            top = 0.0 if data.top_offset is None else float(data.top_offset[e])
            h = palm[:, 1] - obj[:, 1] - top
            over = events.within_tolerance(events.palm_xz_distance(palm, obj)) & (h >= 0) & (h <= TOP_BAND)
        self.over = np.asarray(over, dtype=bool)
        self.relative = np.zeros(len(palm))
        if len(palm) > 1:  # relative XZ speed of the step into each frame (frame 0: the palm rests, 0)
            step = np.diff(palm[:, [0, 2]] - obj[:, [0, 2]], axis=0)
            self.relative[1:] = np.linalg.norm(step, axis=1)
        closed = events.grasp_closed(np.asarray(data.joint_angles[lo:hi], dtype=np.float64), grasp)
        self.t_gra = int(np.argmax(closed)) if closed.any() else -1
        self.ok = not bool(data.error[e])


def today(ep: Episode) -> bool:
    return bool(ep.over.any())


def dwell(k: int) -> Callable[[Episode], bool]:
    def rule(ep: Episode) -> bool:
        return longest_run(ep.over) >= k
    return rule


def at_grasp(ep: Episode) -> bool:
    return ep.t_gra >= 0 and bool(ep.over[ep.t_gra])


def at_grasp_dwell(k: int) -> Callable[[Episode], bool]:
    """Over the object on the ``k`` frames ending where the grasp first closes."""
    def rule(ep: Episode) -> bool:
        return ep.t_gra >= k - 1 and bool(ep.over[ep.t_gra - k + 1: ep.t_gra + 1].all())
    return rule


def tracking(k: int, speed: float = TRACK_SPEED) -> Callable[[Episode], bool]:
    """Over the object with the palm moving with it (relative XZ speed <= ``speed``) on ``k`` consecutive frames."""
    def rule(ep: Episode) -> bool:
        return longest_run(ep.over & (ep.relative <= speed)) >= k
    return rule


def endpoint(ep: Episode) -> bool:
    return len(ep.over) > 0 and bool(ep.over[-1])


#: name -> (rule, what it says).
RULES: dict[str, tuple[Callable[[Episode], bool], str]] = {
    "today": (today, "some acting frame over the object (d <= 0.3, 0 <= h <= 0.65): the dyana reading"),
    **{f"dwell-{k}": (dwell(k), f"over on at least {k} consecutive frames ({k / 20:.2f} s)") for k in range(2, 9)},
    "at-grasp": (at_grasp, "over at the frame the grasp first closes (schemas.events.grasp_closed, episode_grasp)"),
    **{f"at-grasp-dwell-{k}": (at_grasp_dwell(k), f"over on the {k} frames ending where the grasp first closes")
       for k in (2, 3, 4)},
    **{f"track-{k}": (tracking(k), f"over and moving with the object (relative XZ speed <= {TRACK_SPEED} per "
                      f"frame) on {k} consecutive frames") for k in (1, 2, 3)},
    "endpoint": (endpoint, "over at the last acting frame"),
}


def episodes_of(data: RunData) -> list[Episode]:
    """Every episode of a test-1k run, with the ground truth's grasp from its spec."""
    out = []
    for e, index in enumerate(data.episode_index):
        grasp = episode_grasp(spec_for(data.slice, int(index)))
        out.append(Episode(data, e, grasp))
    return out


def score(episodes: list[Episode]) -> dict[str, dict]:
    """Per rule: S_loc (%), its 95% Wilson interval (%), the count and the episodes."""
    n = len(episodes)
    out = {}
    for name, (rule, _) in RULES.items():
        hits = sum(1 for ep in episodes if ep.ok and rule(ep))
        lo, hi = wilson_interval(hits, n)
        out[name] = {"S_loc": round(100 * hits / n, 1), "ci95": [round(100 * lo, 1), round(100 * hi, 1)],
                     "count": hits, "episodes": n}
    return out


def main() -> None:
    """Print each rule's S_loc for the runs named on the command line (one JSON line per run)."""
    import argparse
    import json

    from scoring.io import load_run

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="run or built slice folders (catalog.json + shards)")
    for folder in parser.parse_args().runs:
        table = score(episodes_of(load_run(folder)))
        print(json.dumps({"run": folder, **{rule: row["S_loc"] for rule, row in table.items()}}))


if __name__ == "__main__":
    main()

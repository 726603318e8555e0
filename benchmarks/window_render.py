"""How much cheaper is the ``window`` renderer's draw than the ``full`` one's, and how far
are its frames from ``full``'s (dataset 4.0.0 against 3.0.0, :mod:`schemas.renderers`)?

:meth:`generators.render.Renderer.render` draws each frame's moving bodies (hand and
object) in a pybullet client of their own and composites them over the static plate.
``full`` draws them over the whole viewport (``Renderer._draw``); ``window`` first finds
their screen window from boxes around their visual shapes and draws only that window with
an off-centre projection (:mod:`generators.window`, ``Renderer.window``). Most of a full
draw's CPU time is per-pixel overhead (an empty client costs ~2.1 ms at 224 px), while
the moving bodies cover ~11% of the image on average. This script runs the production
code of both (two renderers, ``kind="full"`` and ``kind="window"``) side by side.

Two ways to find the window are compared:

- ``aabb``: ``pybullet.getAABB`` of every link of both bodies. Those are *collision*
  bounds: the objects are visual-only multibodies (their AABB is a point) and the hand's
  wrist and joint spheres have no collision shapes, so this window misses pixels.
- ``visual``: the 8 corners of an oriented box around each *visual* shape
  (``getVisualShapeData``, read once per scene), placed with the links' frames
  (``getLinkStates`` with forward kinematics, one call per body per frame), projected,
  padded by ``--pad`` pixels (the production window: ``generators.window.PAD``).

Per frame, on real episodes of ``--slices`` (``slice_specs`` + ``episode``), two
renderers hold the same scene: one draws the full viewport (``Renderer._draw``), the
other draws the window, so each client draws exactly once per frame, as in a build
(a client's draw count perturbs its shading, see :mod:`generators.render`). Measured:

1. CPU time (``time.thread_time``) of the full draw against the window (bounds +
   draw, including pybullet's conversion of the returned buffers);
2. misses: moving pixels of the full draw outside the window (each method);
3. inside the window, the window draw against the full draw: pixels covered by one but
   not the other, pixels covered by both whose RGBA differs (fraction, max level
   difference), depth values not bit-equal; and the composited frames (each draw
   through ``Renderer._composite`` over the same plate, as each renderer makes its frames)
   that differ, with their largest level difference.

    python benchmarks/window_render.py [--episodes 8] [--slices circular-medium,...] [--pad 2]

Prints a table per slice and overall, then one JSON line.

Measured (benchmarks/results/window_render.txt, 16 episodes per slice, 3,063 frames, load
average ~9): the window covers ~13% of the image and never missed a moving pixel; full
draw 3.98 ms, window 2.63 ms a frame (0.54 ms bounds + 2.10 ms draw; the rest is
per-triangle work that a window does not remove), 1.5x (1.6x in the first measurement, at
a lower load, with 3.35 and 2.10 ms). Not pixel-identical: ~15% of covered depths are not
bit-equal (the barycentric weights are computed from differently rounded screen
coordinates), RGBA differs by up to 3 levels on ~0.008% of covered pixels, 4 pixels'
coverage differs, and 8.8% of composited frames differ from the full-viewport composite
(280 pixels, 0.09 a frame: 276 by 1-3 levels, 4 silhouette pixels by up to 105).
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from generators.bullet import p
from generators.recipe import slice_specs
from generators.render import Renderer
from generators.window import PAD, WindowCamera, world_corners
from pipeline.stages.episode import episode

SLICES = ("circular-medium", "linear-fast", "harmonic-slow")
_CUBE = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)


def aabb_corners(client: int, bodies) -> np.ndarray:
    """World corners of ``pybullet.getAABB`` of every link of ``bodies`` (collision bounds)."""
    boxes = []
    for body in bodies:
        for link in range(-1, p.getNumJoints(body, physicsClientId=client)):
            lo, hi = p.getAABB(body, link, physicsClientId=client)
            boxes.append((lo, hi))
    b = np.asarray(boxes, dtype=np.float64)  # (n, 2, 3)
    sel = (_CUBE > 0).astype(np.intp)  # (8, 3): 0 -> lo, 1 -> hi
    return b[:, sel, np.arange(3)].reshape(-1, 3)


def outside(mask: np.ndarray, win) -> int:
    """Pixels of ``mask`` outside the window."""
    if win is None:
        return int(mask.sum())
    r0, r1, c0, c1 = win
    return int(mask.sum() - mask[r0:r1, c0:c1].sum())


def new_stats() -> dict:
    keys = (
        "frames episodes t_full t_bounds t_window_draw t_aabb window_px moving_px "
        "miss_frames_visual miss_px_visual miss_frames_aabb miss_px_aabb "
        "cover_only_full cover_only_window both_px rgba_diff_px max_level_diff depth_not_bit_equal "
        "frames_any_diff composite_diff_frames composite_diff_px composite_max_level composite_px_over_3 fallbacks"
    ).split()
    return dict.fromkeys(keys, 0)


def run_slice(name: str, count: int, pad: int, res: int, stats: dict) -> None:
    full, win = Renderer(res, kind="full"), Renderer(res, kind="window")
    # the production window (generators.window), with this run's padding
    camera = WindowCamera(res, res, pad)
    try:
        for spec in slice_specs(name, count):
            frames = episode(spec)
            for r in (full, win):
                r.set_scene(spec.object, spec.object_size, spec.hand, spec.obstacles)
            bodies = [b.body for b in (win._hand, win._object) if b is not None]
            stats["episodes"] += 1
            for i in range(frames.num_frames):
                args = (frames.object_pose[i], frames.palm_pose[i], frames.joint_angles[i])
                full._pose(*args)
                win._pose(*args)
                # window: bounds, then the window draw (alternating which renderer draws first)
                order = (0, 1) if i % 2 == 0 else (1, 0)
                for which in order:
                    if which == 0:
                        t = time.thread_time()
                        rgba_f, depth_f = full._draw(full._client)
                        stats["t_full"] += time.thread_time() - t
                    else:
                        t = time.thread_time()
                        wv = win.window() if pad == PAD else camera.window(world_corners(win._boxes))
                        t1 = time.thread_time()
                        if wv is not None:
                            r0, r1, c0, c1 = wv
                            rgba_w, depth_w = win._draw(win._client, camera.projection(wv), c1 - c0, r1 - r0)
                        t2 = time.thread_time()
                        stats["t_bounds"] += t1 - t
                        stats["t_window_draw"] += t2 - t1
                t = time.thread_time()
                wa = camera.window(aabb_corners(win._client, bodies))
                stats["t_aabb"] += time.thread_time() - t
                stats["frames"] += 1

                moving_f = depth_f < full._empty_depth
                stats["moving_px"] += int(moving_f.sum())
                for key, wnd in (("visual", wv), ("aabb", wa)):
                    miss = outside(moving_f, wnd)
                    stats[f"miss_px_{key}"] += miss
                    stats[f"miss_frames_{key}"] += miss > 0

                # the window draw placed into an empty full frame
                # (outside the window only the depth matters: nothing there is compared)
                rgba_p = np.zeros_like(rgba_f)
                depth_p = np.full_like(depth_f, np.float32(win._empty_depth))
                if wv is not None:
                    rgba_p[r0:r1, c0:c1] = rgba_w
                    depth_p[r0:r1, c0:c1] = depth_w
                    stats["window_px"] += (r1 - r0) * (c1 - c0)
                    sl = np.s_[r0:r1, c0:c1]
                else:
                    sl = np.s_[0:0, 0:0]
                mf, mw = moving_f[sl], depth_p[sl] < win._empty_depth
                both = mf & mw
                only_f, only_w = int((mf & ~mw).sum()), int((mw & ~mf).sum())
                diff = np.abs(rgba_f[sl].astype(np.int16) - rgba_p[sl].astype(np.int16)).max(axis=-1)
                rgba_diff = int((diff[both] > 0).sum())
                depth_diff = int((depth_f[sl].view(np.uint32) != depth_p[sl].view(np.uint32))[both].sum())
                stats["cover_only_full"] += only_f
                stats["cover_only_window"] += only_w
                stats["both_px"] += int(both.sum())
                stats["rgba_diff_px"] += rgba_diff
                stats["depth_not_bit_equal"] += depth_diff
                if both.any():
                    stats["max_level_diff"] = max(stats["max_level_diff"], int(diff[both].max()))
                stats["frames_any_diff"] += (only_f + only_w + rgba_diff + depth_diff) > 0

                # the composited frames, as each renderer kind makes them (Renderer._composite)
                fb = full.fallbacks + win.fallbacks
                a = full._composite(rgba_f, depth_f, False)
                b = win._composite(rgba_w, depth_w, False, r0, c0) if wv is not None else win._plate_rgb
                stats["fallbacks"] += full.fallbacks + win.fallbacks - fb
                level = np.abs(a.astype(np.int16) - b.astype(np.int16)).max(axis=-1)
                d = int((level > 0).sum())
                stats["composite_diff_px"] += d
                stats["composite_diff_frames"] += d > 0
                stats["composite_max_level"] = max(stats["composite_max_level"], int(level.max()))
                stats["composite_px_over_3"] += int((level > 3).sum())
    finally:
        full.close()
        win.close()


def summary(s: dict, res: int) -> dict:
    n = max(s["frames"], 1)
    both = max(s["both_px"], 1)
    moving = max(s["moving_px"], 1)
    full_ms = 1000 * s["t_full"] / n
    win_ms = 1000 * (s["t_bounds"] + s["t_window_draw"]) / n
    return {
        "episodes": s["episodes"],
        "frames": s["frames"],
        "full_draw_ms": round(full_ms, 3),
        "window_ms": round(win_ms, 3),
        "window_bounds_ms": round(1000 * s["t_bounds"] / n, 3),
        "window_draw_ms": round(1000 * s["t_window_draw"] / n, 3),
        "speedup": round(full_ms / win_ms, 2) if win_ms else None,
        "aabb_bounds_ms": round(1000 * s["t_aabb"] / n, 3),
        "window_area_frac": round(s["window_px"] / (n * res * res), 4),
        "miss_frames_visual": s["miss_frames_visual"],
        "miss_px_visual": s["miss_px_visual"],
        "miss_frames_aabb": s["miss_frames_aabb"],
        "miss_px_frac_aabb": round(s["miss_px_aabb"] / moving, 4),
        "cover_only_full_px": s["cover_only_full"],
        "cover_only_window_px": s["cover_only_window"],
        "cover_diff_frac": round((s["cover_only_full"] + s["cover_only_window"]) / moving, 5),
        "both_px": s["both_px"],
        "rgba_diff_frac": round(s["rgba_diff_px"] / both, 5),
        "max_level_diff": s["max_level_diff"],
        "depth_not_bit_equal_frac": round(s["depth_not_bit_equal"] / both, 5),
        "frames_any_diff_frac": round(s["frames_any_diff"] / n, 4),
        "composite_diff_frames_frac": round(s["composite_diff_frames"] / n, 4),
        "composite_diff_px_per_frame": round(s["composite_diff_px"] / n, 2),
        "composite_max_level_diff": s["composite_max_level"],
        "composite_diff_px": s["composite_diff_px"],
        "composite_px_over_3_levels": s["composite_px_over_3"],
        "fallbacks": s["fallbacks"],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--episodes", type=int, default=8, help="episodes per slice")
    ap.add_argument("--slices", default=",".join(SLICES))
    ap.add_argument("--pad", type=int, default=PAD, help=f"pixels added around the projected bounds (production: {PAD})")
    ap.add_argument("--resolution", type=int, default=224)
    a = ap.parse_args()
    load_start = os.getloadavg()
    total = new_stats()
    rows = {}
    for name in a.slices.split(","):
        s = new_stats()
        run_slice(name, a.episodes, a.pad, a.resolution, s)
        rows[name] = summary(s, a.resolution)
        for k, v in s.items():
            total[k] = max(total[k], v) if k in ("max_level_diff", "composite_max_level") else total[k] + v
    rows["all"] = summary(total, a.resolution)
    cols = [
        ("frames", "frames"),
        ("full_draw_ms", "full ms"),
        ("window_ms", "win ms"),
        ("window_bounds_ms", "bounds"),
        ("speedup", "x"),
        ("window_area_frac", "area"),
        ("miss_frames_visual", "miss"),
        ("miss_frames_aabb", "missAABB"),
        ("cover_only_full_px", "onlyFull"),
        ("cover_only_window_px", "onlyWin"),
        ("rgba_diff_frac", "rgba≠"),
        ("max_level_diff", "maxlvl"),
        ("depth_not_bit_equal_frac", "depth≠"),
        ("frames_any_diff_frac", "frames≠"),
        ("composite_diff_frames_frac", "comp≠"),
        ("composite_max_level_diff", "compLvl"),
        ("composite_diff_px", "compPx"),
        ("composite_px_over_3_levels", "comp>3"),
    ]
    load = f"load average (1, 5, 15 min) {' '.join(f'{v:.2f}' for v in load_start)} at the start, " \
        f"{' '.join(f'{v:.2f}' for v in os.getloadavg())} at the end"
    print(f"resolution {a.resolution}, pad {a.pad}, {a.episodes} episodes per slice; CPU ms per frame (thread_time); {load}")
    print(f"{'slice':16s}" + "".join(f"{h:>10s}" for _, h in cols))
    for name, row in rows.items():
        print(f"{name:16s}" + "".join(f"{str(row[k]):>10s}" for k, _ in cols))
    print(
        "columns: win ms = visual bounds + window draw; area = window / image; miss = frames with moving "
        "pixels outside the visual-bounds window (missAABB: getAABB window); onlyFull, onlyWin = pixels "
        "covered by only the full or only the window draw; rgba≠, depth≠ = fraction of pixels covered by both that differ (depth: not "
        "bit-equal); frames≠ = frames with any difference; comp≠ = frames whose composited RGB differs "
        "(compLvl: the largest level difference; compPx: pixels that differ; comp>3: of them, by more than 3 levels)"
    )
    print(json.dumps({"resolution": a.resolution, "pad": a.pad, "episodes_per_slice": a.episodes, "load": load,
                      **{k: v for k, v in rows.items()}}))


if __name__ == "__main__":
    main()

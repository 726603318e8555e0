"""Hand-built episode specs for the hand/interception tests: one-token lines, arcs and
harmonics inside the workspace, with their closed-form XZ position, velocity and
acceleration (independent of ``generators.motion``, so the two can be checked
against each other), and hypothesis strategies over them."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import strategies as st

from schemas.motion import ArcToken, HarmonicToken, LineToken, Motion
from schemas.objects import OBJECTS
from schemas.scene import (
    GRASP_FRAMES,
    HOLD_FRAMES,
    INTERCEPT_SECONDS,
    WORKSPACE_X,
    WORKSPACE_Z,
)
from schemas.spec import EpisodeSpec
from schemas.versions import FPS

MOTION_OF = {"L": "linear", "A": "circular", "H": "harmonic"}


def closed_form(token, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """XZ position, velocity, acceleration (n, 2) of a single token at times ``t``."""
    t = np.asarray(t, dtype=np.float64)[:, None]
    if isinstance(token, LineToken):
        u = np.array([math.cos(token.direction), math.sin(token.direction)])
        s = token.speed * t + 0.5 * token.acceleration * t * t
        return np.asarray(token.start) + u * s, u * (token.speed + token.acceleration * t), u * token.acceleration + 0 * t
    if isinstance(token, ArcToken):
        w = token.turn * token.angular_velocity
        th = token.start_angle + w * t
        c, s = np.cos(th), np.sin(th)
        r = token.radius
        pos = np.asarray(token.centre) + r * np.hstack([c, s])
        return pos, r * w * np.hstack([-s, c]), -r * w * w * np.hstack([c, s])
    if isinstance(token, HarmonicToken):
        e = np.array([math.cos(token.axis), math.sin(token.axis)])
        om = 2.0 * math.pi * token.frequency
        ph = om * t + token.phase
        drift = np.asarray(token.drift)
        pos = np.asarray(token.centre) + e * token.amplitude * np.sin(ph) + drift * t
        return pos, e * token.amplitude * om * np.cos(ph) + drift, -e * token.amplitude * om * om * np.sin(ph)
    raise TypeError(token)


def frame_times(spec: EpisodeSpec) -> np.ndarray:
    return np.arange(spec.num_frames) / FPS


def spec_motion(spec: EpisodeSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return closed_form(spec.motion.base.tokens[0], frame_times(spec))


def in_workspace(xz: np.ndarray, margin: float = 0.0) -> bool:
    return bool(
        np.all(xz[:, 0] >= WORKSPACE_X[0] + margin)
        and np.all(xz[:, 0] <= WORKSPACE_X[1] - margin)
        and np.all(xz[:, 1] >= WORKSPACE_Z[0] + margin)
        and np.all(xz[:, 1] <= WORKSPACE_Z[1] - margin)
    )


def make_spec(token_kind: str, params: dict, *, object_name: str = "orange", size_factor: float = 1.0,
              hand: str = "right", rollout_format: str = "observe-before-act", setting: str = "medium",
              observe_frames: int = 20, index: int = 0) -> EpisodeSpec:
    """A spec whose motion is a single token of ``token_kind`` ("L", "A", "H") with ``params``
    (all fields but ``duration``, which is set to cover the episode)."""
    observe = observe_frames if rollout_format == "observe-before-act" else 0
    num_frames = observe + round(INTERCEPT_SECONDS[setting] * FPS) + GRASP_FRAMES + HOLD_FRAMES
    duration = (num_frames - 1) / FPS + 0.05
    cls = {"L": LineToken, "A": ArcToken, "H": HarmonicToken}[token_kind]
    token = cls(duration=duration, **params)
    return EpisodeSpec(
        slice="test-hand",
        episode_index=index,
        seed=0,
        motion_type=MOTION_OF[token_kind],
        motion=Motion.of(token),
        object=object_name,
        object_size=round(OBJECTS[object_name].nominal_size * size_factor, 4),
        hand=hand,
        rollout_format=rollout_format,
        intercept_setting=setting,
        observe_frames=observe,
        num_frames=num_frames,
        text=f"grasp the moving {object_name.replace('_', ' ')}",
    )


def _angle():
    return st.floats(0.0, 2.0 * math.pi, allow_nan=False)


def token_params(kind: str):
    """Strategy of a token's parameters of ``kind``, in the recipe's ranges."""
    if kind == "L":
        return st.fixed_dictionaries(
            {
                "start": st.tuples(st.floats(-2.5, 2.5), st.floats(2.5, 6.5)),
                "direction": _angle(),
                "speed": st.floats(0.6, 2.0),
                "acceleration": st.floats(-0.4, 0.4),
            }
        )
    if kind == "A":
        return st.fixed_dictionaries(
            {
                "centre": st.tuples(st.floats(-1.5, 1.5), st.floats(3.5, 5.5)),
                "radius": st.floats(0.5, 2.0),
                "angular_velocity": st.floats(0.5, 2.0),
                "start_angle": _angle(),
                "turn": st.sampled_from([1, -1]),
            }
        )
    return st.fixed_dictionaries(
        {
            "centre": st.tuples(st.floats(-1.5, 1.5), st.floats(3.5, 5.5)),
            "axis": st.floats(0.0, math.pi),
            "amplitude": st.floats(0.5, 1.8),
            "frequency": st.floats(0.2, 0.6),
            "phase": _angle(),
            "drift": st.tuples(st.floats(-0.1, 0.1), st.floats(-0.1, 0.1)),
        }
    )


@st.composite
def specs(draw, kinds: str = "LAH"):
    """Random specs whose object stays inside the workspace (others are filtered out)."""
    kind = draw(st.sampled_from(list(kinds)))
    spec = make_spec(
        kind,
        draw(token_params(kind)),
        object_name=draw(st.sampled_from(sorted(OBJECTS))),
        size_factor=draw(st.sampled_from([0.85, 1.0, 1.15])),
        hand=draw(st.sampled_from(["right", "left"])),
        rollout_format=draw(st.sampled_from(["observe-before-act", "direct-act"])),
        setting=draw(st.sampled_from(sorted(INTERCEPT_SECONDS))),
        observe_frames=draw(st.integers(1, 30)),
    )
    return spec


def random_specs(rng: np.random.Generator, count: int, kind: str) -> list[EpisodeSpec]:
    """``count`` seeded specs of one token kind that keep the object in the workspace."""
    out: list[EpisodeSpec] = []
    objects = sorted(OBJECTS)
    settings = sorted(INTERCEPT_SECONDS)
    while len(out) < count:
        if kind == "L":
            params = {
                "start": (float(rng.uniform(-2.5, 2.5)), float(rng.uniform(2.5, 6.5))),
                "direction": float(rng.uniform(0, 2 * math.pi)),
                "speed": float(rng.uniform(0.6, 2.0)),
                "acceleration": float(rng.uniform(-0.4, 0.4)),
            }
        elif kind == "A":
            params = {
                "centre": (float(rng.uniform(-1.5, 1.5)), float(rng.uniform(3.5, 5.5))),
                "radius": float(rng.uniform(0.5, 2.0)),
                "angular_velocity": float(rng.uniform(0.5, 2.0)),
                "start_angle": float(rng.uniform(0, 2 * math.pi)),
                "turn": int(rng.choice([1, -1])),
            }
        else:
            params = {
                "centre": (float(rng.uniform(-1.5, 1.5)), float(rng.uniform(3.5, 5.5))),
                "axis": float(rng.uniform(0, math.pi)),
                "amplitude": float(rng.uniform(0.5, 1.8)),
                "frequency": float(rng.uniform(0.2, 0.6)),
                "phase": float(rng.uniform(0, 2 * math.pi)),
                "drift": (float(rng.uniform(-0.1, 0.1)), float(rng.uniform(-0.1, 0.1))),
            }
        fmt = "observe-before-act" if rng.random() < 0.5 else "direct-act"
        spec = make_spec(
            kind,
            params,
            object_name=objects[int(rng.integers(len(objects)))],
            size_factor=float(rng.choice([0.85, 1.0, 1.15])),
            hand="right" if rng.random() < 0.5 else "left",
            rollout_format=fmt,
            setting=settings[int(rng.integers(len(settings)))],
            observe_frames=int(rng.integers(5, 31)),
            index=len(out),
        )
        if in_workspace(spec_motion(spec)[0]):
            out.append(spec)
    return out

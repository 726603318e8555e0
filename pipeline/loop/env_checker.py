"""``check_env(env)``: does an environment honour the closed loop's contract?

Like Gymnasium's env checker, but for what Dyana promises (:mod:`pipeline.loop.env`):
observation keys, dtypes and shapes, each value inside its Gymnasium space as it is
(no cast); the observe window (K images, the hand held still); invalid actions
refused with :class:`~schemas.errors.PolicyError` without advancing; recordings that
match what the policy saw, byte for byte; determinism (the same actions twice give
identical arrays and JPEG bytes); truncation exactly at the horizon. Raises
AssertionError naming the first broken promise.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from generators.encode import decode_jpeg
from generators.hand import REST_JOINTS, REST_PALM
from generators.recipe import spec_for
from pipeline.loop.env import horizon
from pipeline.loop.spaces import INFO_KEYS, OBSERVATION_KEYS, Observation
from pipeline.loop.wrappers import RecordEpisode
from schemas.errors import DyanaError, PolicyError
from schemas.frames import FRAME_ARRAYS, EpisodeFrames
from schemas.spec import EpisodeSpec
from schemas.versions import FPS

_VECTORS = {"palm_pose": 6, "joint_angles": 15, "joint_poses": 90, "keypoints": 36}
#: Actions the environment must refuse (some are not even arrays, hence ``Any``).
_BAD_ACTIONS: tuple[tuple[str, Callable[[np.ndarray], Any]], ...] = (
    ("NaN", lambda a: np.where(np.arange(18) == 4, np.nan, a)),
    ("inf", lambda a: np.where(np.arange(18) == 0, np.inf, a)),
    ("short", lambda a: a[:17]),
    ("chunk", lambda a: np.stack([a, a])),
    ("text", lambda a: "open the hand"),
)


def _hold(obs: Observation) -> np.ndarray:
    return np.concatenate([obs["palm_pose"][:3], obs["joint_angles"]]).astype(np.float32)


def _check_observation(env: RecordEpisode, obs: Observation, frame: int, window: int) -> None:
    assert set(obs) == set(OBSERVATION_KEYS), f"observation keys {sorted(obs)} != {sorted(OBSERVATION_KEYS)}"
    res = env.resolution
    image = obs["image"]
    assert isinstance(image, np.ndarray) and image.dtype == np.uint8 and image.shape == (res, res, 3), (
        f"image must be ({res}, {res}, 3) uint8, got {getattr(image, 'dtype', type(image))} {getattr(image, 'shape', '')}"
    )
    values: Mapping[str, Any] = obs
    for key, width in _VECTORS.items():
        value = values[key]
        assert isinstance(value, np.ndarray) and value.dtype == np.float32 and value.shape == (width,), (
            f"{key} must be ({width},) float32, got {getattr(value, 'dtype', type(value))} {getattr(value, 'shape', '')}"
        )
        assert np.isfinite(value).all(), f"{key} is not finite"
    assert isinstance(obs["text"], str), "text must be a string"
    assert obs["frame_index"] == frame, f"frame_index {obs['frame_index']} != {frame}"
    stamp = obs["timestamp"]
    assert isinstance(stamp, np.ndarray) and stamp.dtype == np.float64 and stamp.shape == (), (
        f"timestamp must be a 0-d float64 array, got {getattr(stamp, 'dtype', type(stamp))} {getattr(stamp, 'shape', '')}"
    )
    assert stamp == frame / FPS, f"timestamp {stamp} != {frame} / {FPS}"
    seen = obs["observe_images"]
    assert isinstance(seen, np.ndarray) and seen.dtype == np.uint8 and seen.shape == (window, res, res, 3), (
        f"observe_images must be ({window}, {res}, {res}, 3) uint8, got {getattr(seen, 'shape', type(seen))}"
    )
    space = getattr(env, "observation_space", None)
    if space is not None:  # exactly: no casting (Gymnasium's passive checker warns on a cast)
        assert set(space.spaces) == set(OBSERVATION_KEYS), f"observation space keys {sorted(space.spaces)}"
        for key, sub in space.spaces.items():
            assert sub.contains(values[key]), f"observation {key!r} is outside its space {sub}"


def _check_info(info: dict[str, Any]) -> None:
    assert set(info) == set(INFO_KEYS), f"info keys {sorted(info)} != {sorted(INFO_KEYS)}"
    assert info["localized"] == (info["t_loc"] >= 0) and info["grasped"] == (info["t_gra"] >= 0), (
        f"events and their times disagree: {info}"
    )


def _check_recording(env: RecordEpisode, last_obs: Observation, frames_expected: int) -> tuple[EpisodeFrames, list[bytes]]:
    frames, images = env.recording()
    assert frames.num_frames == frames_expected == len(images), (
        f"recording has {frames.num_frames} frames and {len(images)} images, expected {frames_expected}"
    )
    for name in FRAME_ARRAYS + ("fingertip_distance", "palm_distance", "grasp_angles"):
        assert getattr(frames, name).dtype == np.float32, f"recorded {name} is not float32"
    assert np.array_equal(decode_jpeg(images[-1]), last_obs["image"]), "the last image differs from what the policy saw"
    shown: Mapping[str, Any] = last_obs
    for key in _VECTORS:
        assert np.array_equal(getattr(frames, key)[-1], shown[key]), f"recorded {key} differs from the observation"
    state = np.concatenate([frames.palm_pose[-1, :3], frames.joint_angles[-1]])
    assert np.array_equal(frames.action[-1], state), "the last frame's action must repeat its own state"
    return frames, images


def check_env(env: RecordEpisode, spec: EpisodeSpec | None = None, steps: int | None = None) -> None:
    """Check a recorded environment (:func:`pipeline.loop.wrappers.loop_env`) on ``spec``
    (default: test-1k episode 4, which has an observe window).

    Runs the episode twice with a fixed sequence of actions (the hand moving toward
    the table centre, fingers half closed, then held) until the horizon or grasp,
    or ``steps`` steps.
    """
    if spec is None:
        spec = spec_for("test-1k", 4)
    a = spec.observe_frames
    obs, info = env.reset(options={"spec": spec})
    _check_observation(env, obs, a, a)
    _check_info(info)
    frames, images = _check_recording(env, obs, a + 1)
    rest = np.concatenate([REST_PALM[:3], REST_JOINTS]).astype(np.float32)
    still = np.concatenate([frames.palm_pose[:, :3], frames.joint_angles], axis=1)
    assert np.array_equal(still, np.broadcast_to(rest, still.shape)), "the hand moved during the observe window"
    for k in range(a):
        assert np.array_equal(decode_jpeg(images[k]), obs["observe_images"][k]), f"observe image {k} != recorded frame {k}"
    if a >= 2:
        assert not np.array_equal(frames.object_pose[0], frames.object_pose[a]), "the object did not move while observed"

    for label, corrupt in _BAD_ACTIONS:
        try:
            env.step(corrupt(_hold(obs)))
        except PolicyError:
            pass
        else:
            raise AssertionError(f"a {label} action was accepted")
        assert env.recording()[0].num_frames == a + 1, f"a refused {label} action advanced the episode"

    def actions(first_obs: Observation, count: int) -> list[np.ndarray]:
        start = _hold(first_obs)
        goal = np.concatenate([[0.0, 2.0, 4.5], np.full(15, 0.3)]).astype(np.float32)
        return [(start + (goal - start) * min(1.0, (j + 1) / 10)).astype(np.float32) for j in range(count)]

    limit = horizon(spec) - 1 if steps is None else steps
    plan = actions(obs, limit)
    runs = []
    for _attempt in range(2):
        obs, info = env.reset(options={"spec": spec})
        taken = 0
        ended = (False, False)
        for action in plan:
            obs, reward, terminated, truncated, info = env.step(action)
            taken += 1
            _check_observation(env, obs, a + taken, 0)
            _check_info(info)
            assert reward == (1.0 if terminated else 0.0), f"reward {reward} with terminated={terminated}"
            assert terminated == (info["t_gra"] == taken), "terminated must mean the grasp completed on this step"
            ended = (terminated, truncated)
            if terminated or truncated:
                break
        frames, images = _check_recording(env, obs, a + 1 + taken)
        assert np.array_equal(frames.action[a : a + taken], np.stack(plan[:taken])), "recorded actions differ from the issued ones"
        if steps is None and not ended[0]:
            assert ended[1] and a + 1 + taken == a + horizon(spec), (
                f"expected truncation after {horizon(spec)} acting frames, got {taken + 1} (ended {ended})"
            )
            try:
                env.step(plan[0])
            except DyanaError:
                pass
            else:
                raise AssertionError("step() after the horizon was accepted")
        runs.append((frames, images))
    (f1, i1), (f2, i2) = runs
    for name in FRAME_ARRAYS + ("phase", "fingertip_distance", "palm_distance", "grasp_angles"):
        assert np.array_equal(getattr(f1, name), getattr(f2, name)), f"{name} differs between two identical runs"
    assert i1 == i2, "JPEG bytes differ between two identical runs"

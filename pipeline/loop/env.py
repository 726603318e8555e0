"""The closed-loop environment: a policy's actions drive the hand, at 20 FPS, through
the same stages as the build (object motion, hand kinematics, render, JPEG).

:class:`DyanaEnv` follows Gymnasium's API (a ``gymnasium.Env`` when Gymnasium is
installed, registered as :data:`ENV_ID`; otherwise a plain class with the same
methods):

* ``reset(seed=None, options={"spec": spec})`` runs the observe window inside (the
  hand held still at rest while the object moves) and returns the observation of the
  first acting frame ``a = spec.observe_frames``. The spec may be an
  :class:`~schemas.spec.EpisodeSpec`, its dict or its JSON; without one, ``seed``
  picks test-1k episode ``seed % 1000`` (no seed: the episode after the last one
  picked that way, starting at 0).
* ``step(action)`` takes one (18,) action, the dataset's ``action`` meaning: the
  palm position and the 15 joint angles of the NEXT frame. Joints are clipped to the
  hand's limits and the palm to :data:`PALM_BOX`; the palm keeps the rest
  orientation, as in the ground truth. The action is cast to float32 first (what the
  recording keeps), so a replay of the recorded actions gives the same states. A
  wrong shape or a NaN/inf raises :class:`~schemas.errors.PolicyError`: the
  environment never repairs an action, and the frame does not advance.
  :func:`run_chunk` executes an (H, 18) chunk open loop, one row per step.

Observation (every step, same keys): ``image`` (H, W, 3) uint8 RGB, the JPEG-decoded
frame, so that the pixels a policy sees in process, over the wire and in the
recorded shard are the same; ``palm_pose`` (6,), ``joint_angles`` (15,),
``joint_poses`` (90,), ``keypoints`` (36,) float32; ``text``; ``frame_index`` int;
``timestamp`` a 0-d float64 array (``frame_index / 20``; ``float(obs["timestamp"])``
gives the number); ``observe_images`` (K, H, W, 3) uint8: the K = ``observe_frames``
frames of the observe window in the first observation, empty (0, H, W, 3)
afterwards.

Spaces (every observation lies in ``observation_space`` exactly, dtypes and shapes
included, so Gymnasium's passive checker runs under ``gymnasium.make`` and stays
silent):

* Observations are bounded by what the environment itself enforces: the palm
  position by :data:`PALM_BOX` (actions are clipped to it), the joint angles by the
  hand's limits (``generators.hand.JOINT_LOWER`` / ``JOINT_UPPER``), the joint and
  keypoint positions by the palm box grown by :data:`HAND_REACH` on every side (the
  longest chain from the palm centre, finger root plus segments, is 1.42 units), the
  Euler angles (roll, pitch, yaw) by [-pi, pi] x [-pi/2, pi/2] x [-pi, pi] (the range
  of ``schemas.rotations.matrix_to_euler``), ``frame_index`` by
  ``Discrete(MAX_FRAMES)`` and the timestamp by ``(MAX_FRAMES - 1) / 20``; ``text``
  is ``Text`` of printable ASCII up to ``schemas.spec.MAX_TEXT`` characters (all the
  built-in slices' instructions are; a custom spec with other characters is outside
  it, and Gymnasium's checker says so).
* The action space is the Box [palm box, joint limits], deliberately NOT normalised
  to [-1, 1]: an action is the dataset's ``action`` column (absolute palm xyz in
  scene units, joint angles in radians), so the actions a policy issues, the
  recorded ones, the ground truth's and a replay's are the same numbers. Values
  outside the Box are accepted and clipped, never rescaled. A learner that wants
  [-1, 1] wraps the env in ``gymnasium.wrappers.RescaleAction(env, np.float32(-1),
  np.float32(1))``, a linear map onto this finite Box. Gymnasium's ``check_env``
  recommends a normalised action space: that one warning is this choice.
* ``observe_images`` is an :class:`ObserveWindow`, a stacked ``Sequence`` of images:
  its length is the episode's ``observe_frames`` at reset (0 for direct-act, up to
  100 in the built-in slices) and 0 afterwards. It stays in the observation because
  policies read it there (``predictive`` fits the object's motion to every frame of
  the window; the wire protocol sends it once, with the first observation). A
  fixed-shape Box would have to be padded to the longest window on every step (15 MB
  per step at 224 px) with padding every policy would have to know to skip.
  Instead, an ``ObserveWindow`` flattens to zero entries, so the observation is
  flattenable: ``gymnasium.wrappers.FlattenObservation`` gives the current frame's
  state (image, poses, text, frame index, timestamp) on every step, reset included,
  without the window; an agent that needs the window reads the unflattened
  observation. Flattened, ``frame_index`` is one-hot (``MAX_FRAMES`` entries) and
  ``text`` ``MAX_TEXT`` character indices.

Events are checked on every acting frame from the recorded float32 values with the
functions ``scoring`` uses (:mod:`schemas.events`: localization when the palm's XZ
distance to the object's centre is within the tolerance, grasp completion when every
joint reaches 0.8 of the ground-truth grasp angles).
``info``: ``localized``, ``grasped``, ``t_loc``, ``t_gra`` (acting frames from the
first acting frame to the event, -1 before it), ``palm_distance`` and
``fingertip_distance`` of the current frame. Reward: 1.0 on the step where the grasp
completes, else 0.0. ``terminated`` = grasp completion; ``truncated`` = the horizon
(:func:`horizon` acting frames, the first acting frame included) is reached.

:meth:`DyanaEnv.recording` returns every frame so far in the dataset's format, with
the JPEG bytes exactly as encoded. Phases: ``observe`` in the window, then
``approach`` until the localization frame, ``grasp`` from it on (``hold`` would
follow grasp completion, but completion ends the episode). The ground truth labels
by its plan instead (``grasp`` from the planned interception frame for
``GRASP_FRAMES`` frames, then ``hold``), and its palm is often within tolerance a
frame or two before that: fed the ground truth's actions, the environment
reproduces its states and images exactly, and labels localization where it happens
(its joint poses, keypoints and distances come from forward kinematics of the
float32 states it records, the ground truth's from its float64 plan: they agree to
a float32 rounding step).
``action`` per frame is the action issued at that frame (observe frames: the rest
pose, as in the ground truth); the last frame, which has issued none, repeats its
own state, as in the ground truth.

Deterministic: the same spec and the same actions give identical arrays and bytes.
"""

from __future__ import annotations

import math
import string
from dataclasses import dataclass
from typing import Any

import numpy as np

from generators.contact import fingertip_distance
from generators.encode import JPEG_QUALITY, decode_jpeg, encode_jpeg
from generators.grasp import grasp_angles
from generators.hand import (
    JOINT_LOWER,
    JOINT_UPPER,
    REST_JOINTS,
    REST_PALM,
    SEGMENT_LENGTHS,
    WRIST_OFFSET,
    forward_kinematics,
    root_positions,
)
from generators.motion import object_pose
from pipeline.loop.conditions import EvalProtocol
from pipeline.loop.perturb import perturbation_rng
from pipeline.stages.episode import obstacle_clearance
from schemas.errors import DyanaError, PolicyError, SpecError
from schemas.events import grasp_closed, localized, palm_distance, spec_hover_offset
from schemas.frames import EpisodeFrames
from schemas.objects import object_category
from schemas.scene import DEFAULT_RESOLUTION, PALM_REST, PHASES, TABLE_X, TABLE_Z
from schemas.spec import MAX_TEXT, EpisodeSpec
from schemas.versions import FPS

try:  # Gymnasium is optional: without it the environment is a plain class
    import gymnasium
    from gymnasium import spaces
    from gymnasium.spaces import utils as space_utils
except ImportError:  # pragma: no cover - exercised only without gymnasium
    gymnasium = None
    spaces = None
    space_utils = None

ENV_ID = "Dyana/Grasp-v0"
#: Where the palm may go (x, y, z ranges): above the table, up to 6 units high, from
#: behind the rest pose (at the view's bottom edge) to the table's far edge.
PALM_BOX = (TABLE_X, (0.0, 6.0), (min(TABLE_Z[0], PALM_REST[2] - 1.0), TABLE_Z[1]))
ACTION_WIDTH = 18
OBSERVATION_KEYS = (
    "image", "palm_pose", "joint_angles", "joint_poses", "keypoints", "text", "frame_index", "timestamp", "observe_images",
)
INFO_KEYS = ("localized", "grasped", "t_loc", "t_gra", "palm_distance", "fingertip_distance")
#: The test slice a seed picks from when reset gets no spec.
DEFAULT_SLICE = "test-1k"
_PHASE = {name: i for i, name in enumerate(PHASES)}
_PALM_LOW = np.array([r[0] for r in PALM_BOX])
_PALM_HIGH = np.array([r[1] for r in PALM_BOX])
_REST_STATE = np.concatenate([REST_PALM[:3], REST_JOINTS]).astype(np.float32)
#: Frame indices the observation space allows (``frame_index`` < MAX_FRAMES).
MAX_FRAMES = 100_000
#: How far any joint or keypoint lies from the palm centre, at most (the longest chain,
#: finger root plus its three segments, rounded up to 0.1 unit; the wrist is 0.5 away).
HAND_REACH = math.ceil(10 * max(
    float(np.max(np.linalg.norm(root_positions("right"), axis=1) + SEGMENT_LENGTHS.sum(axis=1))),
    float(np.linalg.norm(WRIST_OFFSET)),
)) / 10
#: Euler angle ranges (roll, pitch, yaw) of ``schemas.rotations.matrix_to_euler``.
_EULER_LOW = np.array([-np.pi, -np.pi / 2, -np.pi])
_EULER_HIGH = np.array([np.pi, np.pi / 2, np.pi])


def horizon(spec: EpisodeSpec) -> int:
    """Acting frames a rollout may take: ``ceil(1.2 x (num_frames - observe_frames))``."""
    return spec.acting_horizon


def as_spec(value: Any) -> EpisodeSpec:
    """An EpisodeSpec from a spec, its dict or its JSON text."""
    if isinstance(value, EpisodeSpec):
        return value
    if isinstance(value, dict):
        return EpisodeSpec.from_dict(value)
    if isinstance(value, (str, bytes)):
        return EpisodeSpec.from_json(value.decode() if isinstance(value, bytes) else value)
    raise SpecError(f"options['spec'] must be an EpisodeSpec, a dict or JSON text, got {type(value).__name__}")


def _float32(action: Any) -> np.ndarray:
    """``action`` as a float32 array, or PolicyError: whatever the conversion raises (a
    tensor that refuses ``__array__``, ragged lists, ...) and complex values (whose
    imaginary part a cast would silently drop) are the policy's fault, not the run's.
    Values too large for float32 become inf, which the callers refuse. Always a copy, so
    a policy that refills the array it returned cannot rewrite recorded actions."""
    try:
        if np.iscomplexobj(action):
            raise PolicyError(f"action is not a real array (complex values: {np.asarray(action).dtype})")
        with np.errstate(over="ignore", invalid="ignore"):  # a copy: the policy may reuse its buffer
            return np.array(action, dtype=np.float32, copy=True)
    except PolicyError:
        raise
    except Exception as exc:
        raise PolicyError(f"action is not a numeric array ({type(action).__name__}: {type(exc).__name__}: {exc})") from None


def as_action(action: Any) -> np.ndarray:
    """One action as float32 (18,), or PolicyError naming what is wrong."""
    arr = _float32(action)
    if arr.shape != (ACTION_WIDTH,):
        raise PolicyError(f"action must have shape ({ACTION_WIDTH},), got {tuple(arr.shape)}")
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        raise PolicyError(f"action contains NaN/inf at index {int(bad[0])} (value {arr[bad[0]]})")
    return arr


def as_chunk(action: Any) -> np.ndarray:
    """An action or a chunk as float32 (H, 18) with H >= 1, or PolicyError."""
    arr = _float32(action)
    if arr.shape == (ACTION_WIDTH,):
        arr = arr[None]
    if arr.ndim != 2 or arr.shape[0] < 1 or arr.shape[1] != ACTION_WIDTH:
        raise PolicyError(f"action must have shape ({ACTION_WIDTH},) or (H, {ACTION_WIDTH}) with H >= 1, got {tuple(arr.shape)}")
    bad = np.argwhere(~np.isfinite(arr))
    if bad.size:
        row, col = (int(v) for v in bad[0])
        raise PolicyError(f"action contains NaN/inf at row {row}, column {col} (value {arr[row, col]})")
    return arr


def _pose_bounds(count: int, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """float32 (low, high) of ``count`` poses (x, y, z, roll, pitch, yaw): positions in
    the palm box grown by ``reach``, angles in the Euler ranges."""
    low = np.tile(np.concatenate([_PALM_LOW - reach, _EULER_LOW]), count)
    high = np.tile(np.concatenate([_PALM_HIGH + reach, _EULER_HIGH]), count)
    return low.astype(np.float32), high.astype(np.float32)


if spaces is not None:

    class ObserveWindow(spaces.Sequence):
        """The observe window: a stacked sequence of (H, W, 3) uint8 images, (K, H, W, 3)
        with K = ``observe_frames`` in the first observation, (0, H, W, 3) afterwards.

        Unlike a plain ``Sequence`` it is flattenable, to zero entries (module
        docstring, "Spaces"): ``flatten`` drops the window, ``unflatten`` gives an empty
        one, so a flattened observation is the current frame's state. Sampling,
        ``contains`` and batching are ``Sequence``'s."""

        def __init__(self, image: spaces.Box, seed: Any = None):
            super().__init__(image, stack=True, seed=seed)
            self.dtype = np.dtype(np.uint8)  # what it flattens to (an empty uint8 Box)

        @property
        def is_np_flattenable(self) -> bool:  # type: ignore[override]  # Sequence says Literal[False]
            return True

        def __repr__(self) -> str:
            return f"ObserveWindow({self.feature_space})"

    # Gymnasium's flattening functions dispatch on the space's type; these apply to
    # ObserveWindow only (a plain Sequence stays unflattenable)
    @space_utils.flatdim.register(ObserveWindow)
    def _flatdim_window(space: ObserveWindow) -> int:
        return 0

    @space_utils.flatten_space.register(ObserveWindow)
    def _flatten_space_window(space: ObserveWindow) -> spaces.Box:
        return spaces.Box(0, 255, (0,), np.uint8)

    @space_utils.flatten.register(ObserveWindow)
    def _flatten_window(space: ObserveWindow, x: Any) -> np.ndarray:
        return np.zeros(0, dtype=np.uint8)

    @space_utils.unflatten.register(ObserveWindow)
    def _unflatten_window(space: ObserveWindow, x: Any) -> np.ndarray:
        return np.zeros((0, *space.feature_space.shape), dtype=np.uint8)


def _spaces(resolution: int):
    if spaces is None:
        return None, None
    image = spaces.Box(0, 255, (resolution, resolution, 3), np.uint8)
    palm_low, palm_high = _pose_bounds(1, 0.0)
    joint_poses_low, joint_poses_high = _pose_bounds(15, HAND_REACH)
    keypoints_low, keypoints_high = _pose_bounds(6, HAND_REACH)

    def box(low: np.ndarray, high: np.ndarray) -> spaces.Box:
        return spaces.Box(low.astype(np.float32), high.astype(np.float32), low.shape, np.float32)

    observation = spaces.Dict(
        {
            "image": image,
            "palm_pose": box(palm_low, palm_high),
            "joint_angles": box(JOINT_LOWER, JOINT_UPPER),
            "joint_poses": box(joint_poses_low, joint_poses_high),
            "keypoints": box(keypoints_low, keypoints_high),
            "text": spaces.Text(max_length=MAX_TEXT, min_length=0, charset=string.printable),
            "frame_index": spaces.Discrete(MAX_FRAMES),
            "timestamp": spaces.Box(0.0, (MAX_FRAMES - 1) / FPS, (), np.float64),
            "observe_images": ObserveWindow(image),
        }
    )
    action = box(np.concatenate([_PALM_LOW, JOINT_LOWER]), np.concatenate([_PALM_HIGH, JOINT_UPPER]))
    return observation, action


_Base = gymnasium.Env if gymnasium is not None else object


class DyanaEnv(_Base):
    """Closed-loop dynamic grasping (module docstring). One episode at a time; frames
    are rendered by this process's shared renderer (:func:`pipeline.stages.record.renderer_for`)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": FPS}

    def __init__(
        self,
        resolution: int = DEFAULT_RESOLUTION,
        jpeg_quality: int = JPEG_QUALITY,
        render_mode: str | None = None,
        protocol: EvalProtocol | None = None,
    ):
        if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)) or resolution < 8:
            raise SpecError(f"resolution must be an integer >= 8, got {resolution!r}")
        if isinstance(jpeg_quality, bool) or not isinstance(jpeg_quality, (int, np.integer)) or not 1 <= jpeg_quality <= 100:
            raise SpecError(f"jpeg_quality must be an integer in [1, 100], got {jpeg_quality!r}")
        if render_mode not in (None, "rgb_array"):
            raise SpecError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.resolution = int(resolution)
        self.jpeg_quality = int(jpeg_quality)
        self.render_mode = render_mode
        if protocol is not None and not isinstance(protocol, EvalProtocol):
            raise SpecError(f"protocol must be an EvalProtocol, got {protocol!r:.80}")
        self.protocol = protocol or EvalProtocol()
        #: Frames of latency of the actions issued next (the protocol's, plus in real-time
        #: mode the last call's measured inference time, set by the rollout).
        self.delay_frames = self.protocol.latency_frames
        self.observation_space, self.action_space = _spaces(self.resolution)
        self.episode_spec: EpisodeSpec | None = None
        self._next_index = 0
        self._done = True
        self._frames: dict[str, list] = {}

    # episode -----------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Start an episode and run its observe window; returns ``(observation, info)``.

        Args:
            seed: picks test-1k episode ``seed % 1000`` when no spec is given (and seeds
                Gymnasium's ``np_random``); without either, the next test-1k episode.
            options: ``{"spec": EpisodeSpec | dict | JSON}`` runs that episode instead.

        Returns:
            observation: the dict described in the module docstring, at the first acting
                frame, with the observe window's frames in ``observe_images``.
            info: ``localized``, ``grasped``, ``t_loc``, ``t_gra``, ``palm_distance``,
                ``fingertip_distance``.
        """
        if gymnasium is not None:
            super().reset(seed=seed)
        options = options or {}
        if options.get("spec") is not None:
            spec = as_spec(options["spec"])
        else:
            from generators.recipe import spec_for

            if seed is not None:
                index = int(seed) % 1000
            else:
                index = self._next_index % 1000
            self._next_index = index + 1
            spec = spec_for(DEFAULT_SLICE, index)
        self.episode_spec = spec
        self._first = spec.observe_frames
        self._limit = spec.observe_frames + horizon(spec)
        times = np.arange(self._limit, dtype=np.float64) / FPS
        poses, velocity = object_pose(spec.motion, object_category(spec.object), spec.object_size, times)
        self._object_pose = poses.astype(np.float32)
        self._object_velocity = velocity.astype(np.float32)
        self._grasp = grasp_angles(spec.object, spec.object_size, spec.hand).astype(np.float32)
        self._frames = {name: [] for name in ("phase", "palm_pose", "joint_angles", "joint_poses", "keypoints",
                                                "action", "fingertip_distance", "palm_distance", "images")}
        self._loc_frame: int | None = None
        self._gra_frame: int | None = None
        self._done = False
        rest = _REST_STATE
        self._applied = rest.copy()
        self._scheduled: list[tuple[int, np.ndarray]] = []
        self.delay_frames = self.protocol.latency_frames
        observe_images = []
        for k in range(self._first):
            image = self._add_frame(k, rest[:3], rest[3:])
            self._frames["action"].append(rest.copy())
            observe_images.append(self._seen(k, image))
        image = self._add_frame(self._first, rest[:3], rest[3:])
        self._done = self._limit <= self._first + 1
        observe = (
            np.stack(observe_images)
            if observe_images
            else np.zeros((0, self.resolution, self.resolution, 3), dtype=np.uint8)
        )
        return self._observation(image, observe), self._info()

    def step(self, action: Any) -> tuple[dict, float, bool, bool, dict]:
        """Apply one action for one frame (1/20 s); returns ``(observation, reward,
        terminated, truncated, info)``.

        Args:
            action: (18,) palm target xyz + 15 joint targets (cast to float32, then
                clipped to the workspace and the joint limits).

        Returns:
            observation: the next frame's observation (``observe_images`` empty).
            reward: 1.0 on the step where the grasp completes, else 0.0.
            terminated: the grasp completed (every joint at 0.8 of its grasp angle).
            truncated: the acting horizon (ceil(1.2 x the ground truth's)) is reached.
            info: as for :meth:`reset`, updated.
        """
        if self.episode_spec is None:
            raise DyanaError("step() before reset(): call reset() first")
        if self._done:
            raise DyanaError("step() after the episode ended (grasp complete or horizon): call reset()")
        act = as_action(action)
        frame = self.current_frame
        self._frames["action"].append(act)
        applied = self._take_effect(frame, act)
        palm = np.clip(applied[:3].astype(np.float64), _PALM_LOW, _PALM_HIGH).astype(np.float32)
        joints = np.clip(applied[3:].astype(np.float64), JOINT_LOWER, JOINT_UPPER).astype(np.float32)
        completed_before = self._gra_frame is not None
        image = self._add_frame(frame + 1, palm, joints)
        terminated = self._gra_frame is not None and not completed_before
        truncated = not terminated and frame + 2 >= self._limit
        self._done = terminated or truncated
        reward = 1.0 if terminated else 0.0
        empty = np.zeros((0, self.resolution, self.resolution, 3), dtype=np.uint8)
        return self._observation(image, empty), reward, terminated, truncated, self._info()

    def _take_effect(self, frame: int, action: np.ndarray) -> np.ndarray:
        """The targets reached at frame ``frame + 1``: the action issued now without latency;
        with a delay of N frames the latest action issued N frames ago or earlier, else
        the targets applied last (the hand holds)."""
        if self.delay_frames == 0 and not self._scheduled:
            self._applied = action
            return action
        self._scheduled.append((frame + self.delay_frames, action))
        due = [a for at, a in self._scheduled if at <= frame]
        if due:
            self._applied = due[-1]
            self._scheduled = [(at, a) for at, a in self._scheduled if at > frame]
        return self._applied

    def _seen(self, frame: int, image: np.ndarray) -> np.ndarray:
        """Frame ``frame`` as the policy sees it: perturbed under a perturbation protocol."""
        perturb = self.protocol.perturb
        if perturb is None or self.episode_spec is None:
            return image
        return perturb.apply(image, perturbation_rng(self.episode_spec.spec_hash, self.protocol.repeat, frame))

    @property
    def current_frame(self) -> int:
        """Index of the latest frame (the one the last observation showed)."""
        return len(self._frames.get("phase", ())) - 1

    @property
    def done(self) -> bool:
        """Whether the episode has ended (or none was started)."""
        return self._done

    def recording(self) -> tuple[EpisodeFrames, list[bytes]]:
        """Every frame so far in the dataset's format and the JPEG bytes of each."""
        if self.episode_spec is None:
            raise DyanaError("recording() before reset(): nothing was recorded")
        f = self._frames
        n = len(f["phase"])
        actions = list(f["action"][: n - 1])
        actions.append(np.concatenate([f["palm_pose"][-1][:3], f["joint_angles"][-1]]).astype(np.float32))
        frames = EpisodeFrames(
            phase=np.asarray(f["phase"], dtype=np.int8),
            object_pose=self._object_pose[:n].copy(),
            object_velocity=self._object_velocity[:n].copy(),
            palm_pose=np.stack(f["palm_pose"]),
            joint_angles=np.stack(f["joint_angles"]),
            joint_poses=np.stack(f["joint_poses"]),
            keypoints=np.stack(f["keypoints"]),
            action=np.stack(actions).astype(np.float32),
            fingertip_distance=np.asarray(f["fingertip_distance"], dtype=np.float32),
            palm_distance=np.asarray(f["palm_distance"], dtype=np.float32),
            grasp_angles=self._grasp.copy(),
            obstacle_clearance=obstacle_clearance(self.episode_spec, np.stack(f["palm_pose"]), np.stack(f["joint_angles"])),
        )
        return frames, list(f["images"])

    def render(self) -> np.ndarray | None:
        """The latest frame as the policy saw it (``render_mode="rgb_array"``), else None."""
        if self.render_mode != "rgb_array" or not self._frames.get("images"):
            return None
        return decode_jpeg(self._frames["images"][-1])

    def close(self) -> None:
        """Nothing to release: the renderer is shared by the process."""

    # internals ---------------------------------------------------------------
    def _add_frame(self, k: int, palm_xyz: np.ndarray, joints: np.ndarray) -> np.ndarray:
        """Append frame ``k`` with this hand state; returns the decoded image."""
        from pipeline.stages.record import renderer_for

        spec = self.episode_spec
        palm_pose = np.concatenate([palm_xyz, REST_PALM[3:].astype(np.float32)]).astype(np.float32)
        joint_poses, keypoints = forward_kinematics(palm_pose[None].astype(np.float64), joints[None].astype(np.float64), spec.hand)
        obj = self._object_pose[k]
        tips = keypoints.reshape(1, 6, 6)[:, :5, :3]
        tip_distance = np.float32(fingertip_distance(tips, spec.object, spec.object_size, obj[None].astype(np.float64))[0])
        offset = spec_hover_offset(spec)
        distance = float(palm_distance(palm_pose, obj, offset))
        f = self._frames
        f["palm_pose"].append(palm_pose)
        f["joint_angles"].append(joints.astype(np.float32))
        f["joint_poses"].append(joint_poses[0].astype(np.float32))
        f["keypoints"].append(keypoints[0].astype(np.float32))
        f["fingertip_distance"].append(tip_distance)
        f["palm_distance"].append(np.float32(distance))

        if k < self._first:
            phase = _PHASE["observe"]
        else:
            if self._loc_frame is None and localized(palm_pose, obj, offset):
                self._loc_frame = k
            if self._gra_frame is None and grasp_closed(joints, self._grasp):
                self._gra_frame = k
            if self._gra_frame is not None and k > self._gra_frame:
                phase = _PHASE["hold"]
            elif self._loc_frame is not None:
                phase = _PHASE["grasp"]
            else:
                phase = _PHASE["approach"]
        f["phase"].append(phase)

        renderer = renderer_for(self.resolution)
        renderer.set_scene(spec.object, spec.object_size, spec.hand, spec.obstacles)
        data = encode_jpeg(renderer.render(obj, palm_pose, joints), self.jpeg_quality)
        f["images"].append(data)
        return decode_jpeg(data)

    def _observation(self, image: np.ndarray, observe_images: np.ndarray) -> dict[str, Any]:
        f = self._frames
        k = self.current_frame
        return {
            "image": self._seen(k, image),
            "palm_pose": f["palm_pose"][-1].copy(),
            "joint_angles": f["joint_angles"][-1].copy(),
            "joint_poses": f["joint_poses"][-1].copy(),
            "keypoints": f["keypoints"][-1].copy(),
            "text": self.episode_spec.text,
            "frame_index": k,
            "timestamp": np.array(k / FPS, dtype=np.float64),
            "observe_images": observe_images,
        }

    def _info(self) -> dict[str, Any]:
        f = self._frames
        return {
            "localized": self._loc_frame is not None,
            "grasped": self._gra_frame is not None,
            "t_loc": -1 if self._loc_frame is None else self._loc_frame - self._first,
            "t_gra": -1 if self._gra_frame is None else self._gra_frame - self._first,
            "palm_distance": float(f["palm_distance"][-1]),
            "fingertip_distance": float(f["fingertip_distance"][-1]),
        }


@dataclass(frozen=True)
class ChunkResult:
    """What :func:`run_chunk` did: the last step's observation and info, the summed
    reward, how the episode stands, and how many rows ran."""

    observation: dict
    reward: float
    terminated: bool
    truncated: bool
    info: dict
    steps: int


def run_chunk(env: DyanaEnv, action: Any) -> ChunkResult:
    """Execute an action (18,) or a chunk (H, 18) open loop, one row per step, stopping
    at termination or truncation (later rows are dropped). The whole chunk is checked
    before any row runs: an invalid chunk raises PolicyError and changes nothing."""
    chunk = as_chunk(action)
    reward, steps = 0.0, 0
    for row in chunk:
        obs, r, terminated, truncated, info = env.step(row)
        reward += r
        steps += 1
        if terminated or truncated:
            break
    return ChunkResult(obs, reward, terminated, truncated, info, steps)


def register() -> bool:
    """Register :data:`ENV_ID` with Gymnasium (idempotent); False without Gymnasium.

    Runs on import, so ``gymnasium.make("pipeline.loop.env:Dyana/Grasp-v0")`` works in
    a fresh interpreter (Gymnasium imports the module named before the colon), and
    ``gymnasium.make("Dyana/Grasp-v0")`` once this module is imported. It is also the
    ``gymnasium.envs`` entry point in pyproject.toml (named ``Dyana``, the namespace),
    which Gymnasium 0.26-0.29 call on ``import gymnasium``; Gymnasium 1.x no longer
    loads such plugins. The passive env checker stays on: observations match their
    spaces exactly.
    """
    if gymnasium is None:
        return False
    # from the submodule: a plugin runs while ``gymnasium`` itself is still importing
    from gymnasium.envs.registration import register as register_env
    from gymnasium.envs.registration import registry

    if ENV_ID not in registry:
        register_env(id=ENV_ID, entry_point="pipeline.loop.env:DyanaEnv")
    return True


register()

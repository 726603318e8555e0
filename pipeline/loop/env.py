"""The closed-loop environment :class:`DyanaEnv`, registered as :data:`ENV_ID` (the learners'
defaults) and :data:`FULL_ENV_ID` (the full observation): a policy's
actions drive the hand at 20 FPS through the build's stages (object motion, hand
kinematics, render, JPEG); the hand is a body (:mod:`generators.hand_body`) that follows
each action within speed and acceleration limits and does not enter the table, an
obstacle or, with its palm and wrist, the object. It only simulates; recording and the
evaluation protocols wrap it (:mod:`pipeline.loop.wrappers`). The same spec and actions give the same bytes.
Observation, spaces, events and recording: docs/guides/your-policy.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, cast

import gymnasium
import numpy as np
from gymnasium import spaces

from generators.encode import JPEG_QUALITY, decode_jpeg, encode_bgr_jpeg
from generators.ground_truth import episode_grasp
from generators.hand import JOINT_LOWER, JOINT_UPPER, REST_PALM, forward_kinematics
from generators.hand_body import HandBody
from generators.motion import object_pose
from generators.recipe import spec_for
from generators.render import Renderer, check_resolution
from pipeline.loop.actions import as_action
from pipeline.loop.registration import ENV_ID, FULL_ENV_ID, register
from pipeline.loop.spaces import PALM_HIGH, PALM_LOW, REST_STATE, Observation, action_space, empty_window
from pipeline.loop.views import VIEWS, absolute_action, normalized_action_space
from pipeline.stages.episode import measure_hand
from schemas.errors import DyanaError, SpecError
from schemas.events import grasp_closed, localized, spec_hover_offset
from schemas.names import shorten
from schemas.objects import object_category
from schemas.renderers import DEFAULT_RENDERER, RENDERERS, check_renderer
from schemas.scene import DEFAULT_RESOLUTION, PHASES
from schemas.slices import get_slice
from schemas.spec import EpisodeSpec
from schemas.versions import FPS

__all__ = ["ENV_ID", "FULL_ENV_ID", "DyanaEnv", "EpisodeSource", "SimFrame", "SliceEpisodes", "as_spec", "horizon", "register"]
PHASE = {name: i for i, name in enumerate(PHASES)}


def horizon(spec: EpisodeSpec) -> int:
    """Acting frames a rollout may take: ``ceil(1.2 x (num_frames - observe_frames))``."""
    return spec.acting_horizon


def as_spec(value: object) -> EpisodeSpec:
    """An EpisodeSpec from a spec, its dict or its JSON text."""
    if isinstance(value, EpisodeSpec):
        return value
    if isinstance(value, dict):
        return EpisodeSpec.from_dict(value)
    if isinstance(value, (str, bytes)):
        return EpisodeSpec.from_json(value.decode() if isinstance(value, bytes) else value)
    raise SpecError(f"options['spec'] must be an EpisodeSpec, a dict or JSON text, got {type(value).__name__}")


class EpisodeSource(Protocol):
    """Where a ``reset`` without a spec takes its episode: ``len`` episodes, by index."""

    def __len__(self) -> int: ...

    def __getitem__(self, index: int) -> EpisodeSpec: ...


@dataclass(frozen=True)
class SliceEpisodes:
    """The episodes of a built-in slice as an :class:`EpisodeSource`."""

    slice_name: str = "test-1k"

    def __post_init__(self) -> None:
        get_slice(self.slice_name)  # an unknown name fails here, naming it

    def __len__(self) -> int:
        return get_slice(self.slice_name).episodes

    def __getitem__(self, index: int) -> EpisodeSpec:
        return spec_for(self.slice_name, index)


@dataclass(frozen=True)
class SimFrame:
    """One simulated frame: the hand's state, what it implies, and the JPEG the camera gave."""

    index: int
    phase: int
    palm_pose: np.ndarray
    joint_angles: np.ndarray
    joint_poses: np.ndarray
    keypoints: np.ndarray
    fingertip_distance: np.float32
    palm_distance: np.float32
    jpeg: bytes


class DyanaEnv(gymnasium.Env[Observation, np.ndarray]):
    """Closed-loop dynamic grasping: simulates one episode at a time (docs/guides/your-policy.md).

    Args:
        resolution: image side in pixels, 8 to 1024 (``generators.render.MAX_RESOLUTION``,
            the largest a build writes; checked before anything is allocated).
        jpeg_quality: the frames' JPEG quality (what a policy sees is the decoded JPEG).
        render_mode: None or ``"rgb_array"`` (:meth:`render` gives the latest frame).
        renderer: the :class:`~generators.render.Renderer` to draw with, at ``resolution``
            (the caller keeps and closes it); or a renderer's name (:mod:`schemas.renderers`:
            ``"window"``, what None means, or ``"full"``, dataset 3.0.0's frames): the env
            makes its own of that kind on first use and closes it in :meth:`close`.
        episodes: where ``reset`` without a spec takes its episode (:class:`EpisodeSource`,
            or a built-in slice's name for its :class:`SliceEpisodes`); None: such a reset
            is refused.
        obs: the observation's view (:mod:`pipeline.loop.views`): ``"full"`` (the policy
            contract, :class:`~pipeline.policies.base.Observation`), ``"image"``, ``"state"`` or ``"both"``
            (the registered :data:`ENV_ID`'s default; :data:`FULL_ENV_ID`'s is ``"full"``).
        normalize_actions: actions in [-1, 1], mapped linearly onto the real action Box
            (False: the dataset's absolute targets; :data:`ENV_ID` defaults to True).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": FPS}

    def __init__(
        self,
        resolution: int = DEFAULT_RESOLUTION,
        jpeg_quality: int = JPEG_QUALITY,
        render_mode: str | None = None,
        renderer: Renderer | str | None = None,
        episodes: EpisodeSource | str | None = None,
        obs: str = "full",
        normalize_actions: bool = False,
    ):
        check_resolution("resolution", resolution)
        if isinstance(jpeg_quality, bool) or not isinstance(jpeg_quality, (int, np.integer)) or not 1 <= jpeg_quality <= 100:
            raise SpecError(f"jpeg_quality must be an integer in [1, 100], got {shorten(repr(jpeg_quality))}")
        if render_mode not in (None, "rgb_array"):
            raise SpecError(f"render_mode must be None or 'rgb_array', got {shorten(repr(render_mode))}")
        if renderer is not None and not isinstance(renderer, (Renderer, str)):
            raise SpecError(f"renderer must be a generators.render.Renderer or one of {list(RENDERERS)}, "
                            f"got {type(renderer).__name__}")
        kind = check_renderer(renderer) if isinstance(renderer, str) else DEFAULT_RENDERER
        if not isinstance(obs, str) or obs not in VIEWS:
            raise SpecError(f"obs must be one of {', '.join(map(repr, VIEWS))}, got {obs!r:.80}")
        if not isinstance(normalize_actions, (bool, np.bool_)):
            raise SpecError(f"normalize_actions must be True or False, got {normalize_actions!r:.80}")
        if isinstance(episodes, str):
            episodes = SliceEpisodes(episodes)  # an unknown name fails here, naming it
        elif episodes is not None and (isinstance(episodes, (bytes, dict)) or not all(
                hasattr(episodes, name) for name in ("__len__", "__getitem__")) or len(episodes) == 0):
            raise SpecError(f"episodes must be a slice name, a non-empty sequence of EpisodeSpec (an EpisodeSource) or None, "
                            f"got {shorten(repr(episodes))}")
        self.resolution = int(resolution)
        self.jpeg_quality = int(jpeg_quality)
        self.render_mode = render_mode
        self.episodes = episodes
        self.obs, self.normalize_actions = obs, bool(normalize_actions)
        self._view = VIEWS[obs]
        # "full": a Dict space whose samples are Observation dicts (Gymnasium types it Space[dict])
        self.observation_space = cast("spaces.Space[Observation]", self._view.space(self.resolution))
        self.action_space = normalized_action_space() if self.normalize_actions else action_space()
        self.episode_spec: EpisodeSpec | None = None
        #: The frames the last ``reset`` (the observe window and the first acting frame)
        #: or ``step`` (one) made: what a recorder reads.
        self.new_frames: tuple[SimFrame, ...] = ()
        self._renderer = renderer if isinstance(renderer, Renderer) else None
        self._body: HandBody | None = None
        self._own_renderer = self._renderer is None
        self._kind = kind
        self._next_index = 0
        self._done = True
        self._frame = -1
        self._first = 0
        self._limit = 0
        self._loc_frame: int | None = None
        self._gra_frame: int | None = None
        self.object_pose = np.zeros((0, 7), dtype=np.float32)
        self.object_velocity = np.zeros((0, 3), dtype=np.float32)
        self.grasp_angles = np.zeros(15, dtype=np.float32)
        self._last_jpeg: bytes | None = None
        #: The last hand state's forward kinematics, keyed by (side, palm pose bytes, joint angle bytes).
        self._kinematics: tuple[tuple[str, bytes, bytes], tuple[np.ndarray, np.ndarray]] | None = None

    # episode -----------------------------------------------------------------
    def pick_episode(self, seed: int | None) -> EpisodeSpec:
        """The episode a reset without a spec runs: ``episodes[seed % len]``, or with no
        seed the one after the last picked."""
        if self.episodes is None:
            raise SpecError("reset() without options['spec'] needs the env's episodes source (DyanaEnv(episodes=...))")
        index = (int(seed) if seed is not None else self._next_index) % len(self.episodes)
        self._next_index = index + 1
        return self.episodes[index]

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Observation, dict[str, Any]]:
        """Start an episode and run its observe window; returns ``(observation, info)``.

        Args:
            seed: picks episode ``seed % len(episodes)`` when no spec is given (and seeds
                Gymnasium's ``np_random``); without either, the next episode of the source.
            options: ``{"spec": EpisodeSpec | dict | JSON}`` runs that episode instead.

        Returns:
            observation: the :class:`~pipeline.policies.base.Observation` dict, at the first acting
                frame, with the observe window's frames in ``observe_images``.
            info: ``localized``, ``grasped``, ``t_loc``, ``t_gra``, ``palm_distance``,
                ``fingertip_distance``.
        """
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0):
            raise SpecError(f"seed must be None or an integer >= 0, got {shorten(repr(seed))}")
        if options is not None and not isinstance(options, dict):
            raise SpecError(f"options must be None or a dict such as {{'spec': EpisodeSpec}}, got {shorten(repr(options))}")
        super().reset(seed=None if seed is None else int(seed))
        options = options or {}
        spec = as_spec(options["spec"]) if options.get("spec") is not None else self.pick_episode(seed)
        self.episode_spec = spec
        self._first = spec.observe_frames
        self._limit = spec.observe_frames + horizon(spec)
        times = np.arange(self._limit, dtype=np.float64) / FPS
        poses, velocity = object_pose(spec.motion, object_category(spec.object), spec.object_size, times)
        self.object_pose = poses.astype(np.float32)
        self.object_velocity = velocity.astype(np.float32)
        # the ground truth's grasp (a lying cylinder's depends on the heading the wrist reflex reaches)
        self.grasp_angles = episode_grasp(spec).astype(np.float32)
        self._loc_frame = self._gra_frame = None
        self._frame = -1
        if self._body is None:
            self._body = HandBody((PALM_LOW, PALM_HIGH))
        self._body.reset(spec.hand, spec.object, spec.object_size, spec.obstacles)
        rest = REST_STATE
        frames = [self._simulate(k, rest[:3], rest[3:]) for k in range(self._first + 1)]
        self.new_frames = tuple(frames)
        self._done = self._limit <= self._first + 1
        observe = (
            np.stack([decode_jpeg(f.jpeg) for f in frames[:-1]]) if len(frames) > 1 else empty_window(self.resolution)
        )
        return self._view.show(self._observation(frames[-1], observe)), self._info(frames[-1])

    def step(self, action: np.ndarray) -> tuple[Observation, float, bool, bool, dict[str, Any]]:
        """Apply one action for one frame (1/20 s); returns ``(observation, reward,
        terminated, truncated, info)``.

        Args:
            action: (18,) palm target xyz + 15 joint targets (cast to float32, then
                clipped to the workspace and the joint limits); the hand follows it
                within the body's limits (:mod:`generators.hand_body`).

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
        act = absolute_action(action) if self.normalize_actions else as_action(action)
        frame = self._frame
        palm = np.clip(act[:3].astype(np.float64), PALM_LOW, PALM_HIGH).astype(np.float32)
        joints = np.clip(act[3:].astype(np.float64), JOINT_LOWER, JOINT_UPPER).astype(np.float32)
        completed_before = self._gra_frame is not None
        assert self._body is not None  # reset makes it
        reached = self._body.step(palm, joints, self.object_pose[frame + 1])
        made = self._simulate(frame + 1, reached[0].astype(np.float32), reached[1].astype(np.float32), self._body.heading)
        self.new_frames = (made,)
        terminated = self._gra_frame is not None and not completed_before
        truncated = not terminated and frame + 2 >= self._limit
        self._done = terminated or truncated
        reward = 1.0 if terminated else 0.0
        obs = self._view.show(self._observation(made, empty_window(self.resolution)))
        return obs, reward, terminated, truncated, self._info(made)

    @property
    def current_frame(self) -> int:
        """Index of the latest frame (the one the last observation showed)."""
        return self._frame

    @property
    def first_acting_frame(self) -> int:
        """The episode's first acting frame (``observe_frames``)."""
        return self._first

    @property
    def done(self) -> bool:
        """Whether the episode has ended (or none was started)."""
        return self._done

    def render(self) -> np.ndarray | None:
        """The latest frame as the camera gave it (``render_mode="rgb_array"``), else None."""
        if self.render_mode != "rgb_array" or self._last_jpeg is None:
            return None
        return decode_jpeg(self._last_jpeg)

    def close(self) -> None:
        """Close the hand's body, and the renderer if the env made it."""
        if self._body is not None:
            self._body.close()
            self._body = None
        if self._own_renderer and self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # internals ---------------------------------------------------------------
    def _simulate(self, k: int, palm_xyz: np.ndarray, joints: np.ndarray, heading: float = 0.0) -> SimFrame:
        """Frame ``k`` with this hand state (``heading``: the palm's turn about the vertical,
        the wrist reflex's, recorded as ``palm_pose[4]``): its measures, events, phase and JPEG."""
        spec = self.episode_spec
        assert spec is not None  # reset sets it before any frame
        turn = REST_PALM[3:] + np.array([0.0, heading, 0.0])
        palm_pose = np.concatenate([palm_xyz, turn.astype(np.float32)]).astype(np.float32)
        joints = joints.astype(np.float32)
        obj = self.object_pose[k]
        # The hand's kinematics depend on its state alone: kept while the state repeats
        # (the observe window's rest pose, a hand holding still), the same arrays.
        state = (spec.hand, palm_pose.tobytes(), joints.tobytes())
        if self._kinematics is None or self._kinematics[0] != state:
            self._kinematics = (state, forward_kinematics(palm_pose[None], joints[None], spec.hand))
        measures = measure_hand(spec, palm_pose[None], joints[None], obj[None], self._kinematics[1])
        if k < self._first:
            phase = PHASE["observe"]
        else:
            offset = spec_hover_offset(spec)
            if self._loc_frame is None and localized(palm_pose, obj, offset):
                self._loc_frame = k
            if self._gra_frame is None and grasp_closed(joints, self.grasp_angles):
                self._gra_frame = k
            if self._gra_frame is not None and k > self._gra_frame:
                phase = PHASE["hold"]
            elif self._loc_frame is not None:
                phase = PHASE["grasp"]
            else:
                phase = PHASE["approach"]
        if self._renderer is None:
            self._renderer = Renderer(self.resolution, kind=self._kind)
        self._renderer.set_scene(spec.object, spec.object_size, spec.hand, spec.obstacles)
        # drawn in OpenCV's channel order, as a build draws it: the same JPEG bytes, one conversion fewer
        data = encode_bgr_jpeg(self._renderer.render_bgr(obj, palm_pose, joints), self.jpeg_quality)
        self._frame = k
        self._last_jpeg = data
        return SimFrame(
            index=k,
            phase=phase,
            palm_pose=palm_pose,
            joint_angles=joints,
            joint_poses=measures.joint_poses[0],
            keypoints=measures.keypoints[0],
            fingertip_distance=measures.fingertip_distance[0],
            palm_distance=measures.palm_distance[0],
            jpeg=data,
        )

    def _observation(self, frame: SimFrame, observe_images: np.ndarray) -> Observation:
        assert self.episode_spec is not None
        return {
            "image": decode_jpeg(frame.jpeg),
            "palm_pose": frame.palm_pose.copy(),
            "joint_angles": frame.joint_angles.copy(),
            "joint_poses": frame.joint_poses.copy(),
            "keypoints": frame.keypoints.copy(),
            "text": self.episode_spec.text,
            "frame_index": frame.index,
            "timestamp": np.array(frame.index / FPS, dtype=np.float64),
            "observe_images": observe_images,
        }

    def _info(self, frame: SimFrame) -> dict[str, Any]:
        return {
            "localized": self._loc_frame is not None,
            "grasped": self._gra_frame is not None,
            "t_loc": -1 if self._loc_frame is None else self._loc_frame - self._first,
            "t_gra": -1 if self._gra_frame is None else self._gra_frame - self._first,
            "palm_distance": float(frame.palm_distance),
            "fingertip_distance": float(frame.fingertip_distance),
        }


register()  # gymnasium.make("pipeline.loop.env:Dyana/Grasp-v0") imports this module, then makes the id

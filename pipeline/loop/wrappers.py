"""What wraps the simulation in an evaluation: the recorder and the protocols.

:class:`DyanaEnv` only simulates; these Gymnasium wrappers add, each in one place:

* :class:`RecordEpisode` (outermost): the episode in the dataset's format,
  :meth:`~RecordEpisode.recording`, with the actions as the policy issued them;
* :class:`Latency`: an action takes effect ``delay`` frames late (the hand holds its
  last targets meanwhile); in real-time mode the delay grows by the policy's measured
  time per call (:func:`note_policy_time`, which the rollout calls);
* :class:`PerturbObservation`: what the policy sees is perturbed, seeded by the
  episode, the repeat and the frame (the recording keeps the clean frames);
* :class:`DisturbMotion`: each episode's motion changes once (:mod:`pipeline.loop.disturb`).

:func:`loop_env` stacks them for an :class:`~pipeline.loop.conditions.EvalProtocol`.
"""

from __future__ import annotations

import math
from typing import Any, SupportsFloat

import gymnasium
import numpy as np

from generators.encode import JPEG_QUALITY
from generators.render import Renderer
from pipeline.loop.actions import as_action
from pipeline.loop.conditions import EvalProtocol
from pipeline.loop.disturb import disturbed_spec
from pipeline.loop.env import DyanaEnv, EpisodeSource, SimFrame, as_spec
from pipeline.loop.perturb import Perturbation, perturbation_rng
from pipeline.loop.spaces import REST_STATE, Observation
from pipeline.stages.episode import assemble_frames
from schemas.errors import DyanaError, SpecError
from schemas.frames import EpisodeFrames
from schemas.scene import DEFAULT_RESOLUTION
from schemas.settings import BuildSettings
from schemas.spec import EpisodeSpec
from schemas.versions import FPS

LoopEnv = gymnasium.Env[Observation, np.ndarray]
Step = tuple[Observation, SupportsFloat, bool, bool, dict[str, Any]]


def simulator(env: LoopEnv) -> DyanaEnv:
    """The :class:`DyanaEnv` inside ``env`` (which may be wrapped)."""
    inner = env.unwrapped
    if not isinstance(inner, DyanaEnv):
        raise DyanaError(f"expected a DyanaEnv inside the wrappers, got {type(inner).__name__}")
    return inner


class LoopWrapper(gymnasium.Wrapper[Observation, np.ndarray, Observation, np.ndarray]):
    """A wrapper of the closed loop's environment, with the simulator's facts at hand.
    It needs the simulator's defaults (``obs="full"``, real actions): it reads the full
    observation and issues real actions."""

    def __init__(self, env: LoopEnv):
        inner = simulator(env)
        if inner.obs != "full" or inner.normalize_actions:
            raise SpecError(
                f"{type(self).__name__} needs DyanaEnv(obs='full', normalize_actions=False), "
                f"got obs={inner.obs!r}, normalize_actions={inner.normalize_actions}"
            )
        super().__init__(env)

    @property
    def simulator(self) -> DyanaEnv:
        return simulator(self.env)

    @property
    def resolution(self) -> int:
        return self.simulator.resolution

    @property
    def episode_spec(self) -> EpisodeSpec | None:
        return self.simulator.episode_spec

    @property
    def done(self) -> bool:
        return self.simulator.done


class RecordEpisode(LoopWrapper):
    """Records every frame of the current episode and the actions issued at them."""

    def __init__(self, env: LoopEnv):
        super().__init__(env)
        self._frames: list[SimFrame] = []
        self._actions: list[np.ndarray] = []

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Observation, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        made = self.simulator.new_frames
        self._frames = list(made)
        self._actions = [REST_STATE.copy() for _ in made[:-1]]  # the observe window: the rest pose
        return obs, info

    def step(self, action: np.ndarray) -> Step:
        act = as_action(action)  # refused before anything changes
        result = self.env.step(act)
        self._actions.append(act)
        self._frames.extend(self.simulator.new_frames)
        return result

    def recording(self) -> tuple[EpisodeFrames, list[bytes]]:
        """Every frame so far in the dataset's format and the JPEG bytes of each: the
        states the simulator reached, assembled by the episode stage's function
        (:func:`pipeline.stages.episode.assemble_frames`)."""
        spec = self.simulator.episode_spec
        if spec is None or not self._frames:
            raise DyanaError("recording() before reset(): nothing was recorded")
        sim, f = self.simulator, self._frames
        n = len(f)
        palm = np.stack([x.palm_pose for x in f])
        joints = np.stack([x.joint_angles for x in f])
        last = np.concatenate([palm[-1, :3], joints[-1]]).astype(np.float32)  # it issued none: its own state
        frames = assemble_frames(
            spec,
            np.array([x.phase for x in f], dtype=np.int8),
            sim.object_pose[:n].copy(),
            sim.object_velocity[:n].copy(),
            palm,
            joints,
            np.stack([*self._actions[: n - 1], last]),
            sim.grasp_angles.copy(),
        )
        return frames, [x.jpeg for x in f]


class Latency(LoopWrapper):
    """Actions take effect ``frames`` frames late: the action issued at frame t is
    applied at t + 1 + delay; until then the latest due action (at first: rest) holds.
    With ``realtime`` the delay of each call's actions also counts the policy's measured
    time, rounded up to frames (:func:`note_policy_time`)."""

    def __init__(self, env: LoopEnv, frames: int, realtime: bool = False):
        super().__init__(env)
        self.frames, self.realtime = frames, realtime
        #: Frames of latency of the actions issued next.
        self.delay_frames = frames
        self._applied = REST_STATE.copy()
        self._scheduled: list[tuple[int, np.ndarray]] = []

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Observation, dict[str, Any]]:
        self._applied = REST_STATE.copy()
        self._scheduled = []
        self.delay_frames = self.frames
        return self.env.reset(seed=seed, options=options)

    def policy_took(self, seconds: float) -> None:
        """In real-time mode, the next actions come ``ceil(seconds x fps)`` frames later still."""
        if self.realtime:
            self.delay_frames = self.frames + math.ceil(seconds * FPS)

    def step(self, action: np.ndarray) -> Step:
        act = as_action(action)  # refused before it is scheduled
        frame = self.simulator.current_frame
        if self.delay_frames == 0 and not self._scheduled:
            self._applied = act
        else:
            self._scheduled.append((frame + self.delay_frames, act))
            due = [a for at, a in self._scheduled if at <= frame]
            if due:
                self._applied = due[-1]
                self._scheduled = [(at, a) for at, a in self._scheduled if at > frame]
        return self.env.step(self._applied)


def note_policy_time(env: LoopEnv, seconds: float) -> None:
    """Tell a real-time :class:`Latency` in ``env``'s wrappers how long the policy took."""
    layer: LoopEnv = env
    while isinstance(layer, gymnasium.Wrapper):
        if isinstance(layer, Latency):
            layer.policy_took(seconds)
        layer = layer.env


class PerturbObservation(LoopWrapper):
    """The policy sees perturbed images (``image`` and the observe window), each seeded
    by the episode's spec hash, the ``repeat`` and its frame index."""

    def __init__(self, env: LoopEnv, perturb: Perturbation, repeat: int = 0):
        super().__init__(env)
        self.perturb, self.repeat = perturb, repeat

    def _seen(self, frame: int, image: np.ndarray) -> np.ndarray:
        spec = self.simulator.episode_spec
        assert spec is not None  # an observation exists only after reset
        return self.perturb.apply(image, perturbation_rng(spec.spec_hash, self.repeat, frame))

    def _perturbed(self, obs: Observation) -> Observation:
        window = obs["observe_images"]
        seen = np.stack([self._seen(k, image) for k, image in enumerate(window)]) if len(window) else window
        return {**obs, "image": self._seen(obs["frame_index"], obs["image"]), "observe_images": seen}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Observation, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        return self._perturbed(obs), info

    def step(self, action: np.ndarray) -> Step:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return self._perturbed(obs), reward, terminated, truncated, info


class DisturbMotion(LoopWrapper):
    """Each episode runs disturbed (:func:`pipeline.loop.disturb.disturbed_spec`): the
    spec given, or the one the simulator's episode source picks."""

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Observation, dict[str, Any]]:
        options = dict(options or {})
        given = options.get("spec")
        spec = as_spec(given) if given is not None else self.simulator.pick_episode(seed)
        options["spec"] = disturbed_spec(spec)[0]
        return self.env.reset(seed=seed, options=options)


def loop_env(
    resolution: int = DEFAULT_RESOLUTION,
    jpeg_quality: int = JPEG_QUALITY,
    protocol: EvalProtocol | None = None,
    renderer: Renderer | str | None = None,
    episodes: EpisodeSource | None = None,
) -> RecordEpisode:
    """A recorded closed-loop environment under ``protocol`` (default: the plain loop):
    :class:`DyanaEnv` wrapped in the protocol's wrappers, then :class:`RecordEpisode`."""
    protocol = EvalProtocol() if protocol is None else protocol
    if not isinstance(protocol, EvalProtocol):
        raise SpecError(f"protocol must be an EvalProtocol, got {protocol!r:.80}")
    env: LoopEnv = DyanaEnv(resolution, jpeg_quality, renderer=renderer, episodes=episodes)
    if protocol.perturb is not None:
        env = PerturbObservation(env, protocol.perturb, protocol.repeat)
    if protocol.latency_frames or protocol.realtime:
        env = Latency(env, protocol.latency_frames, protocol.realtime)
    if protocol.disturb:
        env = DisturbMotion(env)
    return RecordEpisode(env)


def settings_env(settings: BuildSettings, episodes: EpisodeSource | None = None) -> RecordEpisode:
    """:func:`loop_env` with a run's byte settings (:class:`~schemas.settings.BuildSettings`:
    its resolution, JPEG quality, renderer and protocol)."""
    return loop_env(settings.resolution, settings.jpeg_quality, EvalProtocol.from_dict(settings.protocol),
                    renderer=settings.renderer, episodes=episodes)

"""Dyana's closed loop as LeRobot's evaluation steps an environment (``lerobot-eval``).

LeRobot's rollout reads, from each environment of a Gymnasium vector env: observations
``pixels`` (camera name -> (H, W, 3) uint8) and ``agent_pos``, which its
``preprocess_observation`` turns into ``observation.images.<camera>`` and
``observation.state``; the instruction from ``task_description``; ``info["is_success"]`` at
an episode's end (its ``pc_success``); ``_max_episode_steps``; ``render()`` for its videos.
:class:`LeRobotGrasp` gives all of that, under LeRobot's names for Dyana's data (the
export's, :mod:`catalog.loader.lerobot_names`): ``pixels/ego`` is ``observation.images.ego``,
``agent_pos`` the 21-wide ``observation.state`` (palm pose, joint angles). Registered as
:data:`LEROBOT_ENV_ID`.

* **Episodes**: a reset with seed ``s`` runs episode ``s % len`` of the slice ``episodes``
  (default test-1k); lerobot-eval seeds its resets from ``--seed`` (default 1000): episodes
  0, 1, ... of test-1k. An unseeded reset (a vector env's automatic one) runs the next.
* **is_success**: on an episode's last step, whether it reached Dyana's headline success
  (S_hold, scored as ``scoring eval`` scores it); False before.
* **Recording** (``record``, a folder; "" for none): every episode started by a seeded reset
  is staged when it ends (:mod:`pipeline.jobs.staged`); when the last environment of the
  process closes, `pipeline eval`'s job writes them (:func:`pipeline.jobs.evaluate.evaluate`)
  as the run ``pipeline eval --policy lerobot:PATH --slice EPISODES --episodes N`` would
  write at this resolution: same files and bytes (for ``--eval.batch_size=1``: a batch
  computes its actions together, and a batched model may round otherwise). They must be
  the slice's first N episodes. The policy is the checkpoint ``policy`` (default:
  lerobot-eval's ``--policy.path``), on ``policy_device`` (default: its ``--policy.device``,
  else cpu); a folder holding files is refused unless ``overwrite``. Environments in
  other processes (``--eval.use_async_envs=true``) cannot record.
"""

from __future__ import annotations

import argparse
import functools
import multiprocessing
import shutil
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from catalog.loader.lerobot_names import CAMERA, STATE_KEY, VECTOR_SOURCES
from pipeline.jobs.staged import Recorded, stage_result
from pipeline.loop.env import SliceEpisodes
from pipeline.loop.registration import DEFAULT_EPISODES
from pipeline.loop.rollout import RolloutResult
from pipeline.loop.spaces import Observation
from pipeline.loop.wrappers import RecordEpisode, loop_env
from pipeline.policies.lerobot_checkpoint import PREFIX, check_device, configure, policy_name
from schemas.errors import SpecError
from schemas.names import shorten
from schemas.renderers import DEFAULT_RENDERER
from schemas.scene import DEFAULT_RESOLUTION
from schemas.spec import EpisodeSpec
from schemas.versions import FPS

LEROBOT_ENV_ID = "Dyana/LeRobot-v0"
STATE_SOURCES = VECTOR_SOURCES[STATE_KEY]
STATE_WIDTH = 21
#: Where the run is recorded unless ``record`` says otherwise.
DEFAULT_RECORD = "dyana-run"


def lerobot_observation(obs: Observation) -> dict[str, Any]:
    """A Dyana observation under the keys LeRobot's rollout reads (``pixels``, ``agent_pos``)."""
    state = np.concatenate([np.asarray(obs[k], np.float32) for k in STATE_SOURCES])  # type: ignore[literal-required]
    return {"pixels": {CAMERA: obs["image"]}, "agent_pos": state}


def observation_space(resolution: int) -> spaces.Dict:
    image = spaces.Box(0, 255, (resolution, resolution, 3), np.uint8)
    state = spaces.Box(-np.inf, np.inf, (STATE_WIDTH,), np.float32)
    return spaces.Dict({"pixels": spaces.Dict({CAMERA: image}), "agent_pos": state})


@functools.cache
def longest_horizon(slice_name: str) -> int:
    """The most acting frames any episode of the slice may take (lerobot-eval's step limit)."""
    source = SliceEpisodes(slice_name)
    return max(source[i].acting_horizon for i in range(len(source)))


def command_line_policy(argv: Sequence[str]) -> tuple[str | None, str | None]:
    """lerobot-eval's ``--policy.path`` and ``--policy.device`` in ``argv`` (None where absent)."""
    parser = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    parser.add_argument("--policy.path", dest="path")
    parser.add_argument("--policy.device", dest="device")
    known, _ = parser.parse_known_args(list(argv))
    return known.path, known.device


@dataclass(frozen=True)
class RecordPlan:
    """What a recorded run is: its folder, the policy's ``lerobot:PATH`` and device, the
    slice, the byte settings and whether a folder holding files may be replaced."""

    folder: str
    ref: str
    device: str
    episodes: str
    resolution: int
    renderer: str
    overwrite: bool

    def __post_init__(self) -> None:
        if isinstance(self.resolution, bool) or not isinstance(self.resolution, int):
            raise SpecError(f"--env.resolution must be an integer, got {shorten(repr(self.resolution))}")
        if not isinstance(self.overwrite, bool):
            raise SpecError(f"--env.overwrite must be true or false, got {shorten(repr(self.overwrite))}")


class RunRecorder:
    """The seeded episodes of the environments recording into one folder, staged until the
    last of them closes; then written as a run."""

    def __init__(self, plan: RecordPlan):
        folder = Path(plan.folder)
        if folder.exists() and (not folder.is_dir() or any(folder.iterdir())) and not plan.overwrite:
            raise SpecError(f"--env.record {shorten(plan.folder)} holds files: --env.overwrite=true replaces them, "
                            "or record elsewhere")
        self.plan = plan
        self.name = policy_name(configure(plan.ref, {"device": plan.device}))  # the checkpoint is checked here
        folder.parent.mkdir(parents=True, exist_ok=True)
        self.staging = tempfile.mkdtemp(prefix=f".{folder.name}.episodes-", dir=folder.parent)
        self.users = 0
        self.staged: set[int] = set()

    def stage(self, result: RolloutResult) -> None:
        stage_result(self.staging, result)
        self.staged.add(result.spec.episode_index)

    def write(self) -> None:
        """Write the staged episodes as the run (nothing when none was), then drop the staging folder."""
        from pipeline.jobs.evaluate import evaluate  # the job machinery, needed once at the end

        plan, indices = self.plan, sorted(self.staged)
        try:
            if not indices:
                return
            if indices != list(range(len(indices))):
                raise SpecError(f"recorded episodes {shorten(str(indices))} of {plan.episodes}: a run holds a slice's "
                                "first N episodes (lerobot-eval --seed=1000, its default, starts at episode 0)")
            evaluate(plan.ref, plan.episodes, plan.folder, episodes=len(indices), resolution=plan.resolution,
                     renderer=plan.renderer, workers=0, progress=False, overwrite=plan.overwrite,
                     config={"device": plan.device}, recorded=Recorded(self.name, False, self.staging))
        finally:
            shutil.rmtree(self.staging, ignore_errors=True)


#: The recorders of this process, by folder: the environments of one vector env share one.
RECORDERS: dict[str, RunRecorder] = {}


def join_recorder(plan: RecordPlan) -> RunRecorder:
    """The recorder of ``plan``'s folder (made on first use); SpecError when it records another plan."""
    recorder = RECORDERS.get(plan.folder)
    if recorder is None:
        recorder = RECORDERS[plan.folder] = RunRecorder(plan)
    elif recorder.plan != plan:
        raise SpecError(f"{shorten(plan.folder)} is already recording {recorder.plan}, not {plan}")
    recorder.users += 1
    return recorder


def leave_recorder(recorder: RunRecorder) -> None:
    """One environment less; the last one writes the run."""
    recorder.users -= 1
    if recorder.users == 0:
        RECORDERS.pop(recorder.plan.folder, None)
        recorder.write()


class LeRobotGrasp(gymnasium.Env):
    """Dyana's recorded closed loop with LeRobot's observation keys (module docstring).

    Args:
        episodes: the slice whose episodes the resets run (default test-1k).
        resolution: image side in pixels (the checkpoint's, so no resizing happens).
        renderer: the renderer's name (:mod:`schemas.renderers`).
        render_mode: ``"rgb_array"`` (LeRobot's videos) or None.
        record: the run folder ("" or None: no recording).
        overwrite: replace a run folder that holds files.
        policy: the checkpoint folder the run names (default: ``--policy.path`` of the command line).
        policy_device: the device the run records (default: ``--policy.device``, else cpu).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": FPS}

    def __init__(self, episodes: str = DEFAULT_EPISODES, resolution: int = DEFAULT_RESOLUTION,
                 renderer: str = DEFAULT_RENDERER, render_mode: str | None = "rgb_array",
                 record: str | None = DEFAULT_RECORD, overwrite: bool = False, policy: str | None = None,
                 policy_device: str | None = None):
        if render_mode not in (None, "rgb_array"):
            raise SpecError(f"render_mode must be None or 'rgb_array', got {shorten(repr(render_mode))}")
        self.source = SliceEpisodes(episodes)  # an unknown slice fails here, naming it
        self.slice_name = episodes
        self.render_mode = render_mode
        self.loop: RecordEpisode = loop_env(resolution, renderer=renderer, episodes=self.source)
        try:
            self.recorder = self._recorder(record, overwrite, policy, policy_device, resolution, renderer)
        except BaseException:
            self.loop.close()
            raise
        self.observation_space = observation_space(resolution)
        self.action_space = self.loop.action_space
        self._spec: EpisodeSpec | None = None
        self._seeded = False
        self._image: np.ndarray | None = None
        self._steps = 0
        self._waited = 0.0
        self._since = 0.0

    def _recorder(self, record: str | None, overwrite: bool, policy: str | None, device: str | None,
                  resolution: int, renderer: str) -> RunRecorder | None:
        if not record:
            return None
        if multiprocessing.parent_process() is not None:
            raise SpecError("--env.record needs the environments in lerobot-eval's own process "
                            "(--eval.use_async_envs=false, its default), or --env.record='' for no recording")
        argv_path, argv_device = command_line_policy(sys.argv[1:])
        path = policy or argv_path
        if not path:
            raise SpecError("--env.record needs the checkpoint the run names: --policy.path=PATH (or --env.policy=PATH)")
        plan = RecordPlan(str(Path(record).expanduser().absolute()), PREFIX + path,
                          check_device(device or argv_device or "cpu"), self.slice_name, resolution, renderer,
                          overwrite)
        return join_recorder(plan)

    @property
    def task_description(self) -> str:
        """The current episode's instruction (LeRobot's ``task``)."""
        return "" if self._spec is None else self._spec.text

    @property
    def _max_episode_steps(self) -> int:  # lerobot-eval's name for the step limit
        return longest_horizon(self.slice_name)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict[str, Any], dict[str, Any]]:
        super().reset(seed=seed)
        obs, info = self.loop.reset(seed=seed, options=options)
        self._spec = self.loop.episode_spec
        self._seeded = seed is not None and not (options or {}).get("spec")
        self._image, self._steps, self._waited = obs["image"], 0, 0.0
        self._since = time.perf_counter()
        return lerobot_observation(obs), {**info, "is_success": False}

    def step(self, action: np.ndarray) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        self._waited += time.perf_counter() - self._since
        obs, reward, terminated, truncated, info = self.loop.step(action)
        self._image, self._steps = obs["image"], self._steps + 1
        success = False
        if terminated or truncated:
            success = self._finish(info)
        self._since = time.perf_counter()
        return lerobot_observation(obs), float(reward), terminated, truncated, {**info, "is_success": success}

    def _finish(self, info: dict[str, Any]) -> bool:
        """Score the ended episode (its headline success) and stage it when it is recorded."""
        from scoring.io import from_recordings
        from scoring.metrics import failed
        from scoring.registry import success
        from scoring.report import score_run

        spec = self._spec
        assert spec is not None  # a step follows a reset
        frames, images = self.loop.recording()
        data = from_recordings("lerobot-eval", self.slice_name, [spec], [frames], policy="lerobot")
        ok = ~failed(data.error, data.min_clearance, True)
        succeeded = bool(success(score_run(data).per_episode, ok)[0])
        if self.recorder is not None and self._seeded:
            self.recorder.stage(RolloutResult(spec, frames, list(images), "ok", "", self._steps, self._steps,
                                              bool(info["localized"]), bool(info["grasped"]), self._waited))
        return succeeded

    def render(self) -> np.ndarray | None:
        """The latest frame (``render_mode="rgb_array"``), else None."""
        return self._image if self.render_mode == "rgb_array" else None

    def close(self) -> None:
        """Close the simulation; the last recording environment writes the run."""
        self.loop.close()
        recorder, self.recorder = self.recorder, None
        if recorder is not None:
            leave_recorder(recorder)


def register() -> bool:
    """Register :data:`LEROBOT_ENV_ID` (idempotent) with no wrapper around the environment,
    so that LeRobot finds ``task_description`` and ``_max_episode_steps`` on it."""
    from gymnasium.envs.registration import registry

    if LEROBOT_ENV_ID not in registry:
        gymnasium.register(id=LEROBOT_ENV_ID, entry_point="pipeline.envhub.grasp:LeRobotGrasp", order_enforce=False,
                           disable_env_checker=True)
    return True


def make_vector_env(n_envs: int = 1, use_async_envs: bool = False, **options: Any) -> gymnasium.vector.VectorEnv:
    """``n_envs`` of :data:`LEROBOT_ENV_ID` with ``options`` as LeRobot makes them (autoreset in
    the same step, where its rollout reads ``final_info``)."""
    if isinstance(n_envs, bool) or not isinstance(n_envs, int) or n_envs < 1:
        raise SpecError(f"n_envs must be an integer >= 1, got {shorten(repr(n_envs))}")
    register()
    kind = gymnasium.vector.AsyncVectorEnv if use_async_envs else gymnasium.vector.SyncVectorEnv

    def one() -> gymnasium.Env:
        return gymnasium.make(LEROBOT_ENV_ID, **options)

    return kind([one] * n_envs, autoreset_mode=gymnasium.vector.AutoresetMode.SAME_STEP)


register()  # LeRobot imports this module (its EnvConfig's package_name) to find the id

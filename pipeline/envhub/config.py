"""``--env.type=dyana``: Dyana's ``EnvConfig`` for ``lerobot-eval`` (imports lerobot).

LeRobot loads it with ``--env.discover_packages_path=pipeline.envhub`` (its plugin loader
imports this package's modules, and the decorator below registers the type). LeRobot makes
the environments with ``gym.make(gym_id, **gym_kwargs)``: :data:`~pipeline.envhub.grasp.LEROBOT_ENV_ID`,
whose module (``package_name``) registers it. ``features`` / ``features_map`` say what the
environment gives under LeRobot's keys (the export's names). Options (``--env.NAME=VALUE``):
``episodes`` (a slice, default test-1k), ``resolution``, ``renderer``, ``record`` (the run
folder, "" for none), ``overwrite``, ``policy`` and ``policy_device`` (what the run names;
default: ``--policy.path`` and ``--policy.device``): :class:`pipeline.envhub.grasp.LeRobotGrasp`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig

from catalog.loader.lerobot_names import ACTION_KEY, CAMERA, IMAGE_KEY, STATE_KEY
from pipeline.envhub.grasp import DEFAULT_RECORD, LEROBOT_ENV_ID, STATE_WIDTH
from pipeline.loop.registration import DEFAULT_EPISODES
from pipeline.loop.spaces import ACTION_WIDTH
from schemas.renderers import DEFAULT_RENDERER
from schemas.scene import DEFAULT_RESOLUTION
from schemas.versions import FPS

PIXELS = f"pixels/{CAMERA}"
FEATURES_MAP = {ACTION_KEY: ACTION_KEY, "agent_pos": STATE_KEY, PIXELS: IMAGE_KEY}


@EnvConfig.register_subclass("dyana")
@dataclass
class DyanaEnvConfig(EnvConfig):
    """Dyana's closed loop in ``lerobot-eval`` (module docstring)."""

    task: str | None = "Grasp"
    fps: int = FPS
    episodes: str = DEFAULT_EPISODES
    resolution: int = DEFAULT_RESOLUTION
    renderer: str = DEFAULT_RENDERER
    render_mode: str = "rgb_array"
    record: str = DEFAULT_RECORD
    overwrite: bool = False
    policy: str | None = None
    policy_device: str | None = None
    features: dict[str, Any] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=lambda: dict(FEATURES_MAP))

    def __post_init__(self) -> None:
        self.features = {
            ACTION_KEY: PolicyFeature(type=FeatureType.ACTION, shape=(ACTION_WIDTH,)),
            "agent_pos": PolicyFeature(type=FeatureType.STATE, shape=(STATE_WIDTH,)),
            PIXELS: PolicyFeature(type=FeatureType.VISUAL, shape=(self.resolution, self.resolution, 3)),
        }

    @property
    def package_name(self) -> str:
        return "pipeline.envhub.grasp"

    @property
    def gym_id(self) -> str:
        return LEROBOT_ENV_ID

    @property
    def gym_kwargs(self) -> dict[str, Any]:
        return {"episodes": self.episodes, "resolution": self.resolution, "renderer": self.renderer,
                "render_mode": self.render_mode, "record": self.record, "overwrite": self.overwrite,
                "policy": self.policy, "policy_device": self.policy_device}

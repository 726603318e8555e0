"""``vlm:URL``: a vision-language model as the controller (the paper's Table 4 protocol).

Every ``every`` acting frames the policy sends the model, through an OpenAI-compatible
chat-completions endpoint (:mod:`pipeline.policies.vlm_transport`), the prompt of a
versioned template (``vlm_prompts/<template>.txt``, its sha256 in the run's manifest)
filled with the task text, the camera description, the hand's state and timing, and
JPEG images: the current frame and, on the first query, the last ``observe_images``
frames of the observe window. The model answers a palm target and a closure
(:mod:`pipeline.policies.vlm_answer`).

* **Cadence.** An answer takes effect ``latency_frames`` frames after the frame it was
  asked about (a fixed, simulated thinking time: the world moves on, deterministically)
  and the palm then moves to its target in a straight line over ``every`` frames, the
  fingers to their target likewise; until the first answer takes effect the hand rests.
* **Faults** (``http_error``, ``timeout``, ``parse_error``, ``refusal``): with
  ``on_fault="error"`` the episode fails with the reason (its ``status`` is ``error``);
  with ``"hold"`` the hand holds its current plan and the run goes on. Each is counted.
* **Audit.** Every exchange (the request with images replaced by their frame index, the
  reply, tokens, latency, outcome and what was read) is kept and written beside the
  run's shards (``vlm/audit-<first>-<end>.jsonl``); ``pipeline replay`` feeds the
  recorded replies back through this same policy.

Temperature 0 and a seed by default. The API key is read from the environment variable
named by ``api_key_env``.
"""

from __future__ import annotations

import base64
import hashlib
import math
import re
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from pipeline.policies.base import Observation, Task
from pipeline.policies.grip import grip_angles
from pipeline.policies.vlm_answer import OUTPUT_SCHEMA, Answer, AnswerError, parse_answer
from pipeline.policies.vlm_transport import HttpTransport, Reply, request_prompt
from schemas.errors import PolicyError, SpecError
from schemas.names import shorten
from schemas.objects import OBJECTS
from schemas.versions import FPS

TEMPLATES = Path(__file__).with_name("vlm_prompts")
FAULT_MODES = ("error", "hold")
OUTCOMES = ("ok", "http_error", "timeout", "parse_error", "refusal")
IMAGE_JPEG_QUALITY = 90
#: Bounds of VLMConfig (each refused beyond, in one line naming the flag):
#: an answer delay or query interval beyond 1,000 frames (33 s at 30 fps) outlasts any
#: episode, so it can only be a typo;
MAX_FRAMES = 1000
#: observe-window images sent with the first query: each is a base64 JPEG in the request,
#: and endpoints cap images per request;
MAX_OBSERVE_IMAGES = 16
#: the answer is one small JSON object (~50 tokens);
MAX_TOKENS = 4096
#: the OpenAI-compatible sampling temperature range, finite;
MAX_TEMPERATURE = 2.0
#: sampling seeds as endpoints take them: a non-negative signed 64-bit integer;
MAX_SEED = 2**63 - 1
#: a request's timeout: one hour at most, finite;
MAX_TIMEOUT_S = 3600.0
#: and the API key's variable: an environment variable name (never empty, never the key).
ENV_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,127}")


#: A built-in template's name (a file stem in :data:`TEMPLATES`).
TEMPLATE_NAME = re.compile(r"[A-Za-z0-9_-]{1,64}")


def template_path(name: str) -> Path:
    """A template by name (``v1``: a plain name, never a path into or out of the built-in
    folder) or by path to a ``.txt`` file of the user's."""
    if not isinstance(name, str) or "\x00" in name:
        raise SpecError(f"--vlm-template must be a template name or a .txt file, got {shorten(repr(name))}")
    path = Path(name) if name.endswith(".txt") else TEMPLATES / f"{name}.txt" if TEMPLATE_NAME.fullmatch(name) else None
    if path is None or not path.is_file():
        raise SpecError(f"--vlm-template {shorten(repr(name))}: no such template (built in: "
                        f"{sorted(p.stem for p in TEMPLATES.glob('*.txt'))}, or a .txt file)")
    return path


@dataclass(frozen=True)
class VLMConfig:
    """Everything that decides a VLM run besides the model's answers (recorded in the manifest)."""

    url: str
    model: str
    every: int = 5
    latency_frames: int = 0
    observe_images: int = 2
    on_fault: str = "error"
    timeout_s: float = 60.0
    template: str = "v1"
    api_key_env: str = "OPENAI_API_KEY"
    json_schema: bool = True
    temperature: float = 0.0
    seed: int = 0
    max_tokens: int = 200
    template_sha256: str = field(default="", compare=False)

    @classmethod
    def from_dict(cls, settings: object) -> VLMConfig:
        """A configuration from a dict of its settings (the flags', a manifest's); SpecError
        naming a setting that is unknown or missing, where ``cls(**settings)`` would raise TypeError."""
        if not isinstance(settings, dict):
            raise SpecError(f"a VLM policy's config must be a dict of its settings, got {shorten(repr(settings))}")
        known = [f.name for f in fields(cls)]
        unknown = [key for key in settings if key not in known]
        if unknown:
            raise SpecError(f"vlm config: unknown setting {shorten(repr(unknown[0]))} (known: {', '.join(known)})")
        if "model" not in settings:
            raise SpecError("a VLM policy needs --model NAME (the model the endpoint serves)")
        return cls(**settings)

    def __post_init__(self) -> None:
        if not isinstance(self.url, str) or not self.url.startswith(("http://", "https://")):
            raise SpecError(f"vlm URL must start with http:// or https://, got {shorten(repr(self.url))}")
        if not isinstance(self.model, str) or not self.model:
            raise SpecError(f"a VLM policy needs --model NAME (the model the endpoint serves), got {shorten(repr(self.model))}")
        for name, low, high in (
            ("every", 1, MAX_FRAMES), ("latency_frames", 0, MAX_FRAMES), ("observe_images", 0, MAX_OBSERVE_IMAGES),
            ("max_tokens", 1, MAX_TOKENS), ("seed", 0, MAX_SEED),
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
                raise SpecError(f"vlm {name} must be an integer in [{low}, {high}], got {shorten(value)}")
        if self.on_fault not in FAULT_MODES:
            raise SpecError(f"--vlm-on-fault must be one of {list(FAULT_MODES)}, got {shorten(repr(self.on_fault))}")
        for name, low_open, top in (("timeout_s", True, MAX_TIMEOUT_S), ("temperature", False, MAX_TEMPERATURE)):
            number = getattr(self, name)
            if (
                isinstance(number, bool) or not isinstance(number, (int, float)) or not math.isfinite(number)
                or not (0 < number if low_open else 0 <= number) or number > top
            ):
                bound = f"in (0, {top:g}]" if low_open else f"in [0, {top:g}]"
                raise SpecError(f"vlm {name} must be a finite number {bound}, got {shorten(number)}")
        if not isinstance(self.api_key_env, str) or not ENV_NAME.fullmatch(self.api_key_env):
            raise SpecError(
                "vlm api_key_env must name an environment variable (letters, digits, '_', not starting with a digit), "
                f"got {shorten(repr(self.api_key_env))}"
            )
        text = template_path(self.template).read_bytes()
        object.__setattr__(self, "template_sha256", hashlib.sha256(text).hexdigest())

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @property
    def name(self) -> str:
        return f"vlm:{self.model}"


def _object_in(text: str) -> str | None:
    lowered = text.lower()
    for name in sorted(OBJECTS, key=len, reverse=True):
        if name.replace("_", " ") in lowered:
            return name
    return None


def _jpeg_url(image: np.ndarray) -> str:
    ok, data = cv2.imencode(".jpg", np.ascontiguousarray(image[:, :, ::-1]), [cv2.IMWRITE_JPEG_QUALITY, IMAGE_JPEG_QUALITY])
    if not ok:
        raise PolicyError("could not encode a frame as JPEG")
    return "data:image/jpeg;base64," + base64.b64encode(data.tobytes()).decode("ascii")


class VLMPolicy:
    """The controller (module docstring). ``transport`` defaults to HTTP to ``config.url``."""

    privileged = False
    action_horizon = 1

    def __init__(self, config: VLMConfig, transport: Any = None) -> None:
        self.config = config
        self.name = config.name
        self.template = template_path(config.template).read_text(encoding="utf-8")
        self.transport = transport or HttpTransport(config.url, config.api_key_env, config.timeout_s)
        self.audit: list[dict[str, Any]] = []
        self._task: dict[str, Any] = {}

    # protocol ---------------------------------------------------------------------------
    def reset(self, task: Task) -> None:
        self._task = dict(task)
        self._step = 0
        self._pending: list[tuple[int, Answer | None]] = []
        self._palm_from = self._palm_to = np.zeros(3)
        self._joints_from = self._joints_to = np.zeros(15)
        self._moved_at = 0
        self._observe: list[np.ndarray] = []
        self._query = 0
        category = _object_in(str(task.get("text", "")))
        size = None if category is None else OBJECTS[category].nominal_size
        self._grip = grip_angles(category, size, str(task.get("hand", "right")))

    def act(self, obs: Observation) -> np.ndarray:
        palm = np.asarray(obs["palm_pose"], np.float64)[:3]
        joints = np.asarray(obs["joint_angles"], np.float64)
        if self._step == 0:
            self._observe = list(obs.get("observe_images", []))[-self.config.observe_images:] \
                if self.config.observe_images else []
            self._palm_from, self._palm_to = palm.copy(), palm.copy()
            self._joints_from, self._joints_to = joints.copy(), joints.copy()
        if self._step % self.config.every == 0:
            self._pending.append((self._step + self.config.latency_frames, self._ask(obs, palm, joints)))
        while self._pending and self._pending[0][0] <= self._step:
            _, answer = self._pending.pop(0)
            if answer is not None:
                self._start_move(answer, palm, joints)
        action = self._planned(self._step + 1)
        self._step += 1
        return action.astype(np.float32)

    def take_audit(self) -> list[dict[str, Any]]:
        records, self.audit = self.audit, []
        return records

    def close(self) -> None:
        self.transport.close()

    # planning ---------------------------------------------------------------------------
    def _start_move(self, answer: Answer, palm: np.ndarray, joints: np.ndarray) -> None:
        self._palm_from, self._joints_from = palm.copy(), joints.copy()
        self._palm_to = answer.palm_target
        self._joints_to = answer.joint_angles if answer.joint_angles is not None else answer.closure * self._grip
        self._moved_at = self._step

    def _planned(self, step: int) -> np.ndarray:
        """The action for ``step``: along the straight move toward the current targets."""
        fraction = min(1.0, (step - self._moved_at) / self.config.every)
        palm = self._palm_from + fraction * (self._palm_to - self._palm_from)
        joints = self._joints_from + fraction * (self._joints_to - self._joints_from)
        return np.concatenate([palm, joints])

    # asking -----------------------------------------------------------------------------
    def _prompt(self, obs: Observation, palm: np.ndarray, joints: np.ndarray, frames: list[int]) -> str:
        closed = float(np.clip(np.dot(joints, self._grip) / max(np.dot(self._grip, self._grip), 1e-9), 0.0, 1.0))
        names = [f"frame {k}" for k in frames]
        values = {
            "task": self._task.get("text", ""),
            "frame_index": int(obs["frame_index"]),
            "time_s": f"{float(obs['timestamp']):.2f}",
            "palm_x": f"{palm[0]:.3f}", "palm_y": f"{palm[1]:.3f}", "palm_z": f"{palm[2]:.3f}",
            "closure_percent": f"{100 * closed:.0f}",
            "image_list": ", ".join(names),
            "latency_s": f"{self.config.latency_frames / FPS:.2f}",
            "every_s": f"{self.config.every / FPS:.2f}",
        }
        try:
            return self.template.format(**values)
        except (KeyError, IndexError, ValueError) as exc:
            raise PolicyError(f"the prompt template {self.config.template!r} does not fill: {exc}") from None

    def _request(self, obs: Observation, palm: np.ndarray, joints: np.ndarray) -> tuple[dict[str, Any], list[int]]:
        current = int(obs["frame_index"])
        first = self._step == 0
        observed = self._observe if first else []
        start = current - len(observed)
        frames = [start + k for k in range(len(observed))] + [current]
        images = observed + [obs["image"]]
        content: list[dict[str, Any]] = [{"type": "text", "text": self._prompt(obs, palm, joints, frames)}]
        content += [{"type": "image_url", "image_url": {"url": _jpeg_url(image)}} for image in images]
        request: dict[str, Any] = {
            "model": self.config.model,
            "messages": [{"role": "user", "content": content}],
            "temperature": self.config.temperature,
            "seed": self.config.seed,
            "max_tokens": self.config.max_tokens,
        }
        if self.config.json_schema:
            request["response_format"] = {
                "type": "json_schema", "json_schema": {"name": "dyana_action", "schema": OUTPUT_SCHEMA, "strict": True},
            }
        return request, frames

    def _ask(self, obs: Observation, palm: np.ndarray, joints: np.ndarray) -> Answer | None:
        request, frames = self._request(obs, palm, joints)
        self._query += 1
        reply: Reply = self.transport.complete(request)
        outcome, detail, answer = reply.outcome, reply.detail, None
        if outcome == "answered":
            try:
                answer = parse_answer(reply.content, reply.refusal, reply.finish_reason, reply.content_chars)
                outcome = "ok"
            except AnswerError as exc:
                outcome, detail = exc.kind, exc.detail
        self.audit.append({
            "query": self._query,
            "frame_index": int(obs["frame_index"]),
            "images": [{"frame": k} for k in frames],
            "prompt": request_prompt(request),
            "request": {k: v for k, v in request.items() if k != "messages"},
            "reply": reply.to_dict(),
            "outcome": outcome,
            "detail": detail,
            "answer": None if answer is None else answer.to_dict(),
        })
        if answer is None and self.config.on_fault == "error":
            raise PolicyError(f"vlm {outcome} at frame {int(obs['frame_index'])}: {detail}")
        return answer


def audit_summary(records: list[dict[str, Any]]) -> str:
    """Counts of each exchange outcome, tokens and latency, from a run's audit records."""
    counts = {k: sum(1 for r in records if r["outcome"] == k) for k in OUTCOMES}
    prompt = sum(r["reply"]["usage"]["prompt_tokens"] or 0 for r in records)
    completion = sum(r["reply"]["usage"]["completion_tokens"] or 0 for r in records)
    latency = sorted(r["reply"]["latency_ms"] for r in records)
    median = latency[len(latency) // 2] if latency else 0.0
    faults = ", ".join(f"{k} {v}" for k, v in counts.items() if k != "ok")
    return (f"{len(records)} queries, {counts['ok']} answered ({faults}); {prompt} prompt + {completion} completion "
            f"tokens; median latency {median:.0f} ms")

"""What a VLM must answer, and how an answer is read.

The requested output is one JSON object (:data:`OUTPUT_SCHEMA`, sent as the request's
JSON schema where the server supports structured output)::

    {"palm_target": [x, y, z], "closure": c}

``palm_target`` is where the palm centre should go, in scene units; ``closure`` in
[0, 1] is mapped onto the grasp synergy of the object the task names. An answer may
instead give ``"joint_angles": [15 numbers]`` (radians), which are used as they are.

Reading is lenient (:func:`parse_answer`): code fences and prose around the object are
ignored, the first balanced ``{...}`` is read, a closure outside [0, 1] is clipped.
It is bounded and linear in the answer's length (one pass, no rescans): at most
:data:`MAX_ANSWER_CHARS` characters and :data:`MAX_ANSWER_DEPTH` levels of nesting are
read, so no answer can hold an episode (no deadline thread is needed).
What cannot be read raises :class:`AnswerError` with its kind: ``refusal`` when the
model declined (the API's ``refusal`` field, a ``content_filter`` finish, or a reply
with no JSON that reads as a refusal), ``parse_error`` otherwise.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass

import numpy as np

OUTPUT_SCHEMA = {
    "type": "object",
    "properties": {
        "palm_target": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3},
        "closure": {"type": "number", "minimum": 0, "maximum": 1},
    },
    "required": ["palm_target", "closure"],
    "additionalProperties": False,
}
_REFUSAL = re.compile(r"\b(i can(?:no|')t|i am unable|i'm unable|i'm sorry|i am sorry|unable to help|cannot assist)\b", re.I)
_FENCE = re.compile(r"```(?:json)?", re.I)
#: Longest answer read (characters): the answer is one small object (~50 tokens), and
#: ``max_tokens`` is at most 4,096 tokens; a longer text is a parse_error, not read.
MAX_ANSWER_CHARS = 65_536
#: Deepest nesting of braces and brackets read (the answer's object holds one list).
MAX_ANSWER_DEPTH = 32


class AnswerError(Exception):
    """An answer that gives no action; ``kind`` is ``parse_error`` or ``refusal``."""

    def __init__(self, kind: str, detail: str) -> None:
        super().__init__(detail)
        self.kind = kind
        self.detail = detail


@dataclass(frozen=True)
class Answer:
    """A read answer: the palm target and either a closure or 15 joint angles."""

    palm_target: np.ndarray
    closure: float | None = None
    joint_angles: np.ndarray | None = None

    def to_dict(self) -> dict:
        out: dict = {"palm_target": self.palm_target.tolist()}
        if self.joint_angles is not None:
            out["joint_angles"] = self.joint_angles.tolist()
        else:
            out["closure"] = self.closure
        return out


def _first_object(text: str) -> str | None:
    """The first balanced ``{...}`` of ``text`` (the outermost one completed first), in one
    pass: a stack of open braces, string-aware; AnswerError when braces and brackets nest
    deeper than :data:`MAX_ANSWER_DEPTH` (the answer is two levels deep)."""
    start = text.find("{")
    if start < 0:
        return None
    opened: list[int] = []
    brackets, in_string, escaped = 0, False, False
    best: tuple[int, int] | None = None
    for k in range(start, len(text)):
        ch = text[k]
        if in_string:
            if escaped:
                escaped = False
            elif ch == "\\":
                escaped = True
            elif ch == '"':
                in_string = False
        elif ch == '"':
            in_string = True
        elif ch in "{[":
            if ch == "{":
                opened.append(k)
            else:
                brackets += 1
            if len(opened) + brackets > MAX_ANSWER_DEPTH:
                raise AnswerError("parse_error", f"the answer nests deeper than {MAX_ANSWER_DEPTH} levels")
        elif ch == "]":
            brackets = max(brackets - 1, 0)
        elif ch == "}" and opened:
            first = opened.pop()
            if best is None or first < best[0]:
                best = (first, k)
            if not opened:  # the outermost object is complete: nothing later starts earlier
                break
    return None if best is None else text[best[0] : best[1] + 1]


def _numbers(value: object, count: int, name: str) -> np.ndarray:
    if not isinstance(value, list) or len(value) != count:
        raise AnswerError("parse_error", f"{name} must be a list of {count} numbers, got {str(value)[:80]}")
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise AnswerError("parse_error", f"{name} must hold finite numbers, got {str(value)[:80]}")
        out.append(float(v))
    return np.array(out, dtype=np.float64)


def parse_answer(
    content: str | None, refusal: str | None = None, finish_reason: str | None = None, length: int | None = None
) -> Answer:
    """Read a chat completion's message (see the module docstring). ``length``: the whole
    answer's length when ``content`` is only its stored prefix."""
    if refusal:
        raise AnswerError("refusal", f"the model refused: {refusal[:120]}")
    if finish_reason == "content_filter":
        raise AnswerError("refusal", "the answer was withheld by the server's content filter")
    chars = len(content or "") if length is None else length
    if chars > MAX_ANSWER_CHARS:
        raise AnswerError("parse_error", f"the answer is {chars:,} characters; at most {MAX_ANSWER_CHARS:,} are read")
    text = _FENCE.sub("", content or "")
    block = _first_object(text)
    if block is None:
        kind = "refusal" if _REFUSAL.search(text) else "parse_error"
        raise AnswerError(kind, f"no JSON object in the answer: {text.strip()[:120]!r}")
    try:
        data = json.loads(block)
    except json.JSONDecodeError as exc:
        raise AnswerError("parse_error", f"the answer's JSON does not parse ({exc.msg}): {block[:120]!r}") from None
    except ValueError:  # an integer of more digits than Python converts (sys.int_info.str_digits_check_threshold)
        raise AnswerError("parse_error", f"the answer's JSON holds a number too long to read: {block[:120]!r}") from None
    except RecursionError:  # unreachable below MAX_ANSWER_DEPTH; kept as the last guard
        raise AnswerError("parse_error", "the answer's JSON nests too deep") from None
    if not isinstance(data, dict):
        raise AnswerError("parse_error", f"the answer is not a JSON object: {block[:120]!r}")
    palm = _numbers(data.get("palm_target"), 3, "palm_target")
    if "joint_angles" in data:
        return Answer(palm, joint_angles=_numbers(data["joint_angles"], 15, "joint_angles"))
    closure = data.get("closure")
    if isinstance(closure, bool) or not isinstance(closure, (int, float)) or not math.isfinite(closure):
        raise AnswerError("parse_error", f"closure must be a number in [0, 1], got {str(closure)[:40]}")
    return Answer(palm, closure=min(max(float(closure), 0.0), 1.0))

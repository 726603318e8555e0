"""How a VLM request travels: to an OpenAI-compatible chat-completions endpoint through the
``openai`` client, or back from a run's recorded answers (``pipeline replay``).

Both return a :class:`Reply`; transport faults come back as replies with ``outcome``
``http_error`` or ``timeout``, never as exceptions, so that the policy decides what a
fault does to its episode. The client makes no retries of its own (one request, one
answer: what the audit trail shows is what happened), over :mod:`pipeline.policies.vlm_http`,
which bounds the whole exchange by the timeout and the reply's bytes. The API key comes from the
environment variable the run names, never from a flag or a file, and never reaches what
the run stores: every text of a reply (answer, refusal, error detail) has the key and any
``Bearer ...`` credential replaced by ``[redacted]`` (an endpoint may echo its headers),
token counts that are not whole numbers (NaN from a broken endpoint) are dropped, and an
answer longer than the parser reads is kept as a prefix with its length and sha256.
"""

from __future__ import annotations

import hashlib
import os
import re
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

from pipeline.policies.vlm_answer import MAX_ANSWER_CHARS
from schemas.errors import PolicyError

REDACTED = "[redacted]"
_BEARER = re.compile(r"(?i)bearer\s+[^\s\"',;]+")
#: Longest refusal or finish reason kept (characters; the rest is cut).
MAX_NOTE_CHARS = 1000
#: Largest token count kept from a reply's ``usage`` (anything else is recorded as unknown).
MAX_TOKENS_COUNTED = 10**9


@dataclass(frozen=True)
class Reply:
    """One exchange's result. ``outcome`` is ``answered``, ``http_error`` or ``timeout``."""

    outcome: str
    content: str | None = None
    refusal: str | None = None
    finish_reason: str | None = None
    detail: str = ""
    prompt_tokens: int | None = None
    completion_tokens: int | None = None
    latency_ms: float = 0.0
    #: When ``content`` is a prefix (a longer answer than is kept): the whole's length and sha256.
    content_chars: int | None = None
    content_sha256: str | None = None

    def to_dict(self) -> dict[str, Any]:
        out = {
            "outcome": self.outcome, "content": self.content, "refusal": self.refusal,
            "finish_reason": self.finish_reason, "detail": self.detail,
            "usage": {"prompt_tokens": self.prompt_tokens, "completion_tokens": self.completion_tokens},
            "latency_ms": round(self.latency_ms, 2),
        }
        if self.content_chars is not None:
            out |= {"content_chars": self.content_chars, "content_sha256": self.content_sha256}
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Reply:
        usage = data.get("usage") or {}
        return cls(data["outcome"], data.get("content"), data.get("refusal"), data.get("finish_reason"),
                   data.get("detail", ""), usage.get("prompt_tokens"), usage.get("completion_tokens"),
                   float(data.get("latency_ms", 0.0)), data.get("content_chars"), data.get("content_sha256"))


class HttpTransport:
    """Chat completions over HTTP with the ``openai`` client (base URL, timeout, no retries)."""

    def __init__(self, url: str, api_key_env: str, timeout_s: float) -> None:
        try:  # lazy: the client and its HTTP stack load when a VLM run needs them
            import openai

            from pipeline.policies import vlm_http
        except ImportError:  # pragma: no cover - openai is a dependency
            raise PolicyError("VLM policies need the openai package: pip install openai") from None
        self._openai, self._http = openai, vlm_http
        key = os.environ.get(api_key_env) or "not-needed"  # local servers accept any key
        self._key = key
        self.client = openai.OpenAI(base_url=url, api_key=key, timeout=timeout_s, max_retries=0,
                                    http_client=vlm_http.bounded_client(timeout_s))

    def complete(self, request: dict[str, Any]) -> Reply:
        """One request; the reply as stored (secrets redacted, usage checked)."""
        return stored_reply(self._exchange(request), self._key)

    def _exchange(self, request: dict[str, Any]) -> Reply:
        openai, http = self._openai, self._http
        start = time.perf_counter()
        try:
            response = self.client.chat.completions.create(**request)
        except http.ReplyTooLarge as exc:
            return Reply("http_error", detail=f"reply too large: {exc}", latency_ms=_ms(start))
        except openai.APITimeoutError:
            return Reply("timeout", detail="no whole answer within the timeout", latency_ms=_ms(start))
        except openai.APIStatusError as exc:
            return Reply("http_error", detail=f"HTTP {exc.status_code}: {str(exc.message)[:160]}", latency_ms=_ms(start))
        except openai.APIConnectionError as exc:
            cause = exc.__cause__
            if isinstance(cause, http.UnreadableReply):
                return Reply("http_error", detail=f"unreadable reply ({str(cause)[:160]})", latency_ms=_ms(start))
            return Reply("http_error", detail=f"connection failed: {str(cause or exc)[:160]}", latency_ms=_ms(start))
        except openai.OpenAIError as exc:
            return Reply("http_error", detail=f"{type(exc).__name__}: {str(exc)[:160]}", latency_ms=_ms(start))
        except (ValueError, RecursionError) as exc:  # a body that is not JSON, or nested past the parser's depth
            return Reply("http_error", detail=f"unreadable reply ({type(exc).__name__}: {str(exc)[:160]})", latency_ms=_ms(start))
        latency = _ms(start)
        try:  # a null body, a null message, ...: a fault of the endpoint, recorded like any other
            if not response.choices:
                return Reply("http_error", detail="the response has no choices", latency_ms=latency)
            choice = response.choices[0]
            usage = response.usage
            return Reply(
                "answered",
                content=choice.message.content,
                refusal=getattr(choice.message, "refusal", None),
                finish_reason=choice.finish_reason,
                prompt_tokens=None if usage is None else usage.prompt_tokens,
                completion_tokens=None if usage is None else usage.completion_tokens,
                latency_ms=latency,
            )
        except (AttributeError, TypeError, IndexError) as exc:
            return Reply("http_error", detail=f"malformed reply ({type(exc).__name__}: {str(exc)[:160]})", latency_ms=latency)

    def close(self) -> None:
        self.client.close()


class RecordedTransport:
    """The answers of a recorded run, in order; the prompt of each request must be the
    recorded one (a replay that asks something else has diverged)."""

    def __init__(self, records: Sequence[dict[str, Any]]) -> None:
        self._records = list(records)
        self._next = 0

    def complete(self, request: dict[str, Any]) -> Reply:
        if self._next >= len(self._records):
            raise PolicyError(f"replay asked for answer {self._next + 1} but the trail holds {len(self._records)}")
        record = self._records[self._next]
        self._next += 1
        if record["prompt"] != request_prompt(request):
            raise PolicyError(f"replay diverged: request {self._next} differs from the recorded one")
        return Reply.from_dict(record["reply"])

    def close(self) -> None:
        return None


def redact(text: str, key: str) -> str:
    """``text`` without the API key or any ``Bearer`` credential."""
    if key:
        text = text.replace(key, REDACTED)
    return _BEARER.sub(f"Bearer {REDACTED}", text)


def _count(value: object) -> int | None:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_TOKENS_COUNTED:
        return None
    return value


def stored_reply(reply: Reply, key: str) -> Reply:
    """``reply`` as the run may store it: every text redacted, token counts whole numbers or
    None, and an answer longer than the parser reads (:data:`MAX_ANSWER_CHARS`) kept as its
    prefix with the whole's length and sha256 (the policy reads the stored reply, so a replay
    sees what the run saw); a refusal or finish reason is cut to :data:`MAX_NOTE_CHARS`."""

    def clean(value: str | None, limit: int) -> str | None:
        return None if value is None else redact(str(value)[:limit], key)

    content, chars, digest = clean(reply.content, len(reply.content or "")), None, None
    if content is not None and len(content) > MAX_ANSWER_CHARS:
        chars, digest = len(content), hashlib.sha256(content.encode("utf-8", "surrogatepass")).hexdigest()
        content = content[:MAX_ANSWER_CHARS]
    return replace(
        reply,
        content=content, refusal=clean(reply.refusal, MAX_NOTE_CHARS),
        finish_reason=clean(reply.finish_reason, MAX_NOTE_CHARS), detail=redact(reply.detail, key),
        prompt_tokens=_count(reply.prompt_tokens), completion_tokens=_count(reply.completion_tokens),
        content_chars=chars, content_sha256=digest,
    )


def request_prompt(request: dict[str, Any]) -> str:
    """The request's text parts, joined: what a replay must ask again."""
    parts = []
    for message in request["messages"]:
        content = message["content"]
        if isinstance(content, str):
            parts.append(content)
        else:
            parts.extend(part["text"] for part in content if part.get("type") == "text")
    return "\n".join(parts)


def _ms(start: float) -> float:
    return (time.perf_counter() - start) * 1e3

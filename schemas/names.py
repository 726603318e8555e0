"""Names that come from input, and how input is echoed back in messages.

A slice name, a policy name or an episode id from a spec, a manifest or the command
line is a *name*, never a path: :func:`validate_name` accepts a short lower-case word
(letters, digits, ``.``, ``_``, ``-``; no separator, no leading dot, not ``.``/``..``),
so joining it under an output folder cannot leave that folder. :func:`shorten` keeps
an echoed value short, so a 100 MB field gives a one-line error; it and :func:`printable`
also hide a URL's password (:func:`redact_credentials`), so no message prints one.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Iterable
from typing import Any

from schemas.errors import SpecError

NAME_PATTERN = re.compile(r"[a-z0-9][a-z0-9._-]{0,63}")
ECHO_LIMIT = 120
#: ``scheme://userinfo@``: what a URL's credentials look like anywhere in a text.
_USERINFO = re.compile(r"\b([A-Za-z][A-Za-z0-9+.-]*://)([^/?#@\s]*)@")


def redact_credentials(text: str) -> str:
    """``text`` with every URL's ``user:password@`` as ``user:***@`` (a bare ``token@`` as
    ``***@``): a URL given on the command line may carry a secret, and messages, progress
    and stored reasons repeat URLs."""
    def hide(found: re.Match[str]) -> str:
        user, colon, _ = found.group(2).partition(":")
        return f"{found.group(1)}{user + ':***' if colon else '***'}@"

    return _USERINFO.sub(hide, text) if "@" in text else text


def shorten(value: Any, limit: int = ECHO_LIMIT) -> str:
    """``value`` as text of at most ``limit`` characters (``...`` and the full length when cut),
    credentials redacted."""
    text = value if isinstance(value, str) else repr(value)
    if len(text) <= limit:
        return redact_credentials(text)
    head = redact_credentials(text[: limit + 4096])  # a password across the cut is still found
    return f"{head[: limit - 3]}... ({len(text):,} characters)"


def printable(value: Any, limit: int = ECHO_LIMIT) -> str:
    """A peer's text (a server's error, a policy's name) safe to print on a terminal:
    characters that are not printable (escape sequences, newlines) become backslash
    escapes (``\\x1b``, ``\\n``), and the result is cut to ``limit`` characters; credentials redacted."""
    text = value if isinstance(value, str) else repr(value)
    head = redact_credentials(text[: limit + 4096])[: limit + 1]
    safe = "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in head)
    if len(text) <= limit and len(safe) <= limit:
        return safe
    return f"{safe[: limit - 3]}... ({len(text):,} characters)"


def validate_name(kind: str, value: Any) -> str:
    """``value`` if it is a valid name; SpecError naming ``kind`` and the value otherwise."""
    if not isinstance(value, str) or not NAME_PATTERN.fullmatch(value) or set(value) <= {"."}:
        raise SpecError(
            f"{kind} must be a name of 1-64 characters a-z, 0-9, '.', '_', '-' starting with a letter or digit "
            f"(never a path), got {shorten(value)!r}" if isinstance(value, str) else
            f"{kind} must be a name (a string), got {shorten(value)}"
        )
    return value


def did_you_mean(value: Any, choices: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` for the choice closest to a mistyped ``value`` (difflib's
    ratio of at least 0.6), else ``""``: appended to an "unknown name" message."""
    if not isinstance(value, str) or len(value) > 200:
        return ""
    close = difflib.get_close_matches(value, list(choices), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""

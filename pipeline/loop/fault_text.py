"""How a policy's exception is written down: one line saying what raised, then a short
traceback, so that the episode's error record shows where the policy failed.

Frames name files by their base name only (no folders, no machine paths), so the
same fault records the same text on every machine and a run stays reproducible;
only the policy's frames are kept (those after Dyana's worker thread), so a policy in
process and one in a child process record the same text. The whole text keeps its last
:data:`TRACEBACK_CHARS` characters (the innermost frames matter most).
"""

from __future__ import annotations

import traceback
from pathlib import Path

#: Most characters of traceback kept in an error record (the innermost ones).
TRACEBACK_CHARS = 2000
#: What separates the one-line reason from its traceback in an error record.
TRACEBACK_HEADER = "\nTraceback (innermost last):\n"
_OWN_FRAMES = {"worker_thread.py"}


def raised(what: str, exc: BaseException) -> str:
    """``policy <what> raised <Type>: <message>`` and, on the next lines, its traceback."""
    text = str(exc)
    head = f"policy {what} raised {type(exc).__name__}" + (f": {text}" if text else "")
    stack = traceback.extract_tb(exc.__traceback__)
    own = [i for i, f in enumerate(stack) if Path(f.filename).name in _OWN_FRAMES]
    frames = list(stack)[own[-1] + 1 :] if own else list(stack)  # the policy's frames: after Dyana's worker thread
    if not frames:
        return head
    lines = [f"  {Path(f.filename).name}:{f.lineno} in {f.name}" + (f": {f.line}" if f.line else "") for f in frames]
    body = "\n".join(lines)
    if len(body) > TRACEBACK_CHARS:
        body = "  ..." + body[-TRACEBACK_CHARS:]
    return f"{head}{TRACEBACK_HEADER}{body}"


def split_reason(reason: str) -> tuple[str, list[str]]:
    """An error record as its reason and its traceback lines (none when it has no traceback)."""
    head, _, body = reason.partition(TRACEBACK_HEADER)
    return head, body.split("\n") if body else []

"""What runs inside a sealed policy's sandbox (:mod:`pipeline.remote.sandbox` starts it):

    python -m pipeline.sealed_main serve REF FD        # serve REF (dyana/1) on the inherited socket FD
    python -m pipeline.sealed_main configure REF JSON  # print REF's kind's configuration as JSON

Both make the policy as ``pipeline serve`` makes it (:func:`pipeline.policy_registry.serving_factory`:
its kind's configuration, in this process).
"""

from __future__ import annotations

import json
import socket
import sys
from collections.abc import Sequence

from pipeline.policy_registry import kind_of, serving_factory
from pipeline.remote.serve import checked_factory, serve
from schemas.errors import DyanaError


def serve_sealed(ref: str, fd: int) -> None:
    """Serve ``ref`` (dyana/1, one connection) on the inherited listening socket ``fd``."""
    serve(checked_factory(serving_factory(ref, {}), None, ref), max_connections=1, sock=socket.socket(fileno=fd),
          label=ref)


def configure_sealed(ref: str, config_json: str) -> int:
    """Print ``ref``'s kind's configuration as JSON; its refusal on stderr, exit 2."""
    try:
        print(json.dumps(kind_of(ref).configure(ref, json.loads(config_json))), flush=True)
    except DyanaError as exc:
        print(exc, file=sys.stderr, flush=True)
        return 2
    return 0


def main(argv: Sequence[str]) -> int:
    if len(argv) == 3 and argv[0] == "serve" and argv[2].isdigit():
        serve_sealed(argv[1], int(argv[2]))
        return 0
    if len(argv) == 3 and argv[0] == "configure":
        return configure_sealed(argv[1], argv[2])
    print("usage: python -m pipeline.sealed_main serve REF FD | configure REF CONFIG", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

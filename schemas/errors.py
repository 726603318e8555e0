"""The one exception hierarchy every Dyana package raises from.

CLIs catch :class:`DyanaError`, print its one-line message and exit with code 2.
"""


class DyanaError(Exception):
    """Base of every error Dyana raises on purpose."""


class SpecError(DyanaError, ValueError):
    """A token, motion or episode spec is malformed or out of range."""


class SliceError(DyanaError, KeyError):
    """An unknown slice name."""

    def __str__(self) -> str:  # KeyError quotes its message; keep it plain
        return str(self.args[0]) if self.args else ""


class InfeasibleError(DyanaError):
    """A spec cannot be executed: the target leaves the workspace or view, or the
    interception is out of reach. The recipe redraws; a user spec is rejected."""


class ShardError(DyanaError):
    """A shard or manifest is missing, truncated, corrupt or does not match its hash."""


class PolicyError(DyanaError):
    """A policy returned an invalid action, raised, timed out or disconnected."""


class ReplayMismatch(DyanaError):
    """Re-executing a recording did not reproduce it byte for byte."""

"""The one exception hierarchy every Dyana package raises from.

CLIs catch :class:`DyanaError`, print its one-line message and exit with a code from
:data:`schemas.cli.EXIT_CODES`: 1 for :class:`ReplayMismatch` (a replay or verify whose
bytes differ), 3 for :class:`AllEpisodesFailed` (an eval whose every episode failed; the run
is written), 2 for every other DyanaError (bad input, an unusable file or object store).
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


class OutputError(DyanaError):
    """A user-named output path that cannot be written as asked: a folder, socket or block
    device, or a file inside a folder being read."""


class StorageError(DyanaError):
    """An object store (``s3://...``) that cannot be used: unreachable, no credentials, a
    missing bucket, a refused request. The message names the URL and the cause."""


class PolicyError(DyanaError):
    """A policy returned an invalid action, raised, timed out or disconnected."""


class AllEpisodesFailed(DyanaError):
    """An evaluation wrote its run, but every episode failed (a policy or transport error)."""


class ReplayMismatch(DyanaError):
    """Re-executing a recording did not reproduce it byte for byte."""


class ShardMissing(ShardError):
    """A file the manifest lists is not on disk."""

    def __init__(self, path: object) -> None:
        self.path = str(path)
        super().__init__(f"{self.path}: file is missing")


class ShardSizeMismatch(ShardError):
    """A file's size differs from the manifest's (truncated or appended to)."""

    def __init__(self, path: object, expected: int, actual: int) -> None:
        self.path, self.expected, self.actual = str(path), expected, actual
        state = "truncated" if actual < expected else "longer than recorded"
        super().__init__(f"{self.path}: {state}: {actual} bytes, catalog.json says {expected}")


class ShardHashMismatch(ShardError):
    """A file's sha256 differs from the manifest's (its content changed)."""

    def __init__(self, path: object, expected: str, actual: str) -> None:
        self.path, self.expected, self.actual = str(path), expected, actual
        super().__init__(f"{self.path}: content changed: sha256 {actual}, catalog.json says {expected}")


class ShardContentError(ShardError):
    """A shard's rows contradict the manifest or the contract (counts, ranges, numbering)."""

    def __init__(self, path: object, detail: str) -> None:
        self.path, self.detail = str(path), detail
        super().__init__(f"{self.path}: {detail}")


class DuplicateEpisode(ShardContentError):
    """An episode index appears twice where each must appear once."""

    def __init__(self, path: object, episode: int) -> None:
        self.episode = episode
        super().__init__(path, f"episode_index {episode} is listed twice (a duplicate)")


class FrameNumberingError(ShardContentError):
    """An episode's frames are not numbered 0..n-1 in order."""


class SettingsMismatch(ShardError):
    """A folder's settings or dataset version are not what the reader supports or asked for."""

    def __init__(self, path: object, key: str, expected: object, actual: object) -> None:
        self.path, self.key, self.expected, self.actual = str(path), key, expected, actual
        super().__init__(f"{self.path}: settings {key} is {actual!r}, expected {expected!r}")

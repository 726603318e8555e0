"""Where every kind of policy reference is resolved: one registration per kind.

A ``--policy`` reference is matched against the registered kinds in order; the first
whose ``matches`` accepts it makes the policy. Built in:

=============  ==================  ===========================================================
kind           reference           makes
=============  ==================  ===========================================================
``vlm``        ``vlm:URL``         :class:`pipeline.policies.vlm.VLMPolicy` (an OpenAI-compatible
                                   endpoint; its configuration comes from ``--model`` and the
                                   ``--vlm-*`` flags, its exchanges are kept as an audit trail)
``lerobot``    ``lerobot:PATH``    :class:`pipeline.policies.lerobot_checkpoint.CheckpointPolicy` (a
                                   LeRobot checkpoint folder, loaded with the installed lerobot on
                                   ``--policy-device``; its features are checked up front)
``openpi``     ``openpi:ws://...`` :class:`pipeline.remote.openpi_client.OpenpiPolicy` (an openpi
                                   policy server; key names in the URL's query)
``remote``     ``ws://HOST:PORT``  :class:`pipeline.remote.client.RemotePolicy` (``pipeline serve``)
``module``     ``module:callable`` a user's policy, in a child process unless ``isolate`` is off
                                   (:class:`pipeline.remote.isolated.IsolatedPolicy`)
``builtin``    a name              :func:`pipeline.policies.base.make_policy` (``still``,
                                   ``oracle``, ``chase``, ``predictive``, ...)
=============  ==================  ===========================================================

A new kind (a LeRobot checkpoint, an openpi server) is one :func:`register` call with a
:class:`PolicyKind`; the job layer (:mod:`pipeline.jobs.evaluate`, :mod:`pipeline.jobs.replay`)
only talks to kinds. Optional abilities of a made policy are protocols, checked with
``isinstance``: :class:`Closable`, :class:`Timed` (remote round trips), :class:`Audited`
(an audit trail, e.g. a VLM's exchanges).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable
from urllib.parse import urlsplit, urlunsplit

from catalog.hashing import sha256_file
from pipeline.loop.rollout import WATCHDOG_S
from pipeline.policies.base import Policy, make_policy, module_file
from schemas.errors import PolicyError, SpecError
from schemas.names import shorten

#: Extra seconds a remote policy's socket waits beyond the deadline or watchdog (the
#: rollout's fires first and names the fault).
REMOTE_SLACK_S = 5.0

#: A kind's configuration (e.g. a VLM's), JSON-ready: recorded in the run's manifest.
Config = dict[str, Any]


@dataclass(frozen=True)
class OpenOptions:
    """How to make a policy: the per-call timeout it may wait (a socket's), whether a
    user's code runs in a child process, and the kind's configuration (None: none)."""

    timeout_s: float = WATCHDOG_S
    isolate: bool = True
    config: Config | None = None


@runtime_checkable
class Closable(Protocol):
    def close(self) -> None: ...


@runtime_checkable
class Timed(Protocol):
    """A policy across a socket: its round-trip timing (``calls``, ``round_trip_ms``,
    ``server_ms``, ``max_round_trip_ms``)."""

    def timing(self) -> dict[str, float]: ...


@runtime_checkable
class Audited(Protocol):
    """A policy that keeps a record of its exchanges (JSON objects; the job adds each
    record's ``episode_id``, which the policy is never told)."""

    def take_audit(self) -> list[dict[str, Any]]: ...


def no_config(ref: str, config: Config | None) -> Config | None:
    """The configuration step of kinds that take none: refuse one."""
    if config is not None:
        raise SpecError(f"--model and the --vlm-* flags are for vlm:URL policies, not {shorten(repr(ref))}")
    return None


@dataclass(frozen=True)
class PolicyKind:
    """One kind of policy reference.

    ``matches(ref)`` says whether a reference is of this kind; ``make(ref, options)``
    makes a fresh policy; ``configure(ref, config)`` checks and completes the kind's
    configuration in the driver (default: none allowed); ``manifest_key`` names the
    configuration's key in the run's manifest (its URL without credentials); an
    ``audit_dir`` keeps the policies' :class:`Audited` records beside the shards, and
    ``replay(config, records)`` makes the policy that re-runs an episode from them
    (``summarize_audit(records)``: the run summary's line about them).
    ``names_ref`` prefixes the reference to the errors of describing the policy.
    ``check(config)`` makes sure, in the driver before the first episode, that what every
    episode needs is there (a VLM's endpoint accepts a connection): PolicyError if not.
    """

    name: str
    matches: Callable[[str], bool]
    make: Callable[[str, OpenOptions], Policy]
    configure: Callable[[str, Config | None], Config | None] = no_config
    manifest_key: str | None = None
    audit_dir: str | None = None
    replay: Callable[[Config, list[dict[str, Any]]], Policy] | None = None
    summarize_audit: Callable[[list[dict[str, Any]]], str] | None = None
    names_ref: bool = False
    check: Callable[[Config | None], None] | None = None

    def manifest(self, config: Config | None) -> dict[str, Any]:
        """The run manifest's keys for this configuration."""
        if self.manifest_key is None or config is None:
            return {}
        public = {k: v for k, v in config.items() if k != "url"}
        if "url" in config:
            public["url"] = public_url(config["url"])
        return {self.manifest_key: public}


KINDS: list[PolicyKind] = []


def register(kind: PolicyKind, first: bool = True) -> PolicyKind:
    """Add a kind (replacing one of the same name); ``first`` puts it before the others
    (so a specific prefix wins over the built-in fallbacks)."""
    if not isinstance(kind, PolicyKind):
        raise SpecError(f"register() takes a PolicyKind, got {type(kind).__name__}")
    KINDS[:] = [k for k in KINDS if k.name != kind.name]
    if first:
        KINDS.insert(0, kind)
    else:
        KINDS.append(kind)
    return kind


def kind_of(ref: str) -> PolicyKind:
    """The kind of ``ref``; SpecError when it is not a non-empty string."""
    if not isinstance(ref, str) or not ref:
        raise SpecError(f"--policy must be a name, module:callable or ws://HOST:PORT, got {shorten(repr(ref))}")
    for kind in KINDS:
        if kind.matches(ref):
            return kind
    raise SpecError(f"no policy kind accepts {shorten(repr(ref))}")  # unreachable while "builtin" accepts everything


def kind_named(name: str) -> PolicyKind:
    for kind in KINDS:
        if kind.name == name:
            return kind
    raise SpecError(f"unknown policy kind {name!r}: registered {[k.name for k in KINDS]}")


def open_policy(ref: str, options: OpenOptions | None = None) -> Policy:
    """A fresh policy for ``ref`` (its kind's ``make``)."""
    return kind_of(ref).make(ref, options or OpenOptions())


def close_policy(policy: object) -> None:
    """Close a policy that can be closed, ignoring what closing raises (it is being discarded)."""
    if isinstance(policy, Closable):
        try:
            policy.close()
        except Exception:
            pass


def describe_policy(ref: str, options: OpenOptions | None = None) -> tuple[str, bool]:
    """The policy's name and privileged flag, making it once in the driver so that a bad
    name, an unimportable callable or an unreachable server fails before any work starts."""
    kind = kind_of(ref)
    try:
        policy = kind.make(ref, options or OpenOptions())
    except PolicyError as exc:
        raise PolicyError(f"{ref}: {exc}" if kind.names_ref else str(exc)) from None
    try:
        name = getattr(policy, "name", None)
        if not isinstance(name, str) or not name:
            raise SpecError(f"policy {shorten(repr(ref))} has no name (a Policy needs a non-empty str attribute name)")
        privileged = getattr(policy, "privileged", False)
        if not isinstance(privileged, bool):
            raise SpecError(f"policy {shorten(repr(ref))}: privileged must be True or False, got {shorten(repr(privileged))}")
        return name, privileged
    finally:
        close_policy(policy)


def public_url(url: str) -> str:
    """A URL without user:password@ (credentials never reach a manifest)."""
    parts = urlsplit(url)
    host = parts.hostname or ""
    netloc = host + (f":{parts.port}" if parts.port else "")
    return urlunsplit((parts.scheme, netloc, parts.path, "", ""))


# the built-in kinds ----------------------------------------------------------------
# Each imports its implementation when first used: the VLM client, the WebSocket client
# and the child-process runner are not needed by the other kinds.

VLM_PREFIX = "vlm:"


def make_vlm(ref: str, options: OpenOptions) -> Policy:
    from pipeline.policies.vlm import VLMConfig, VLMPolicy  # lazy: the OpenAI client

    if options.config is None:
        raise SpecError(f"policy {shorten(repr(ref))} needs a VLM configuration (--model NAME and the --vlm-* flags)")
    return VLMPolicy(VLMConfig.from_dict(options.config))


def configure_vlm(ref: str, config: Config | None) -> Config:
    from pipeline.policies.vlm import VLMConfig

    if config is not None and not isinstance(config, dict):
        raise SpecError(f"config of {shorten(ref)} must be a dict of --vlm-* settings, got {shorten(repr(config))}")
    return VLMConfig.from_dict({"url": ref[len(VLM_PREFIX):], **(config or {})}).to_dict()


def replay_vlm(config: Config, records: list[dict[str, Any]]) -> Policy:
    from pipeline.policies.vlm import VLMConfig, VLMPolicy
    from pipeline.policies.vlm_transport import RecordedTransport

    return VLMPolicy(VLMConfig.from_dict(config), transport=RecordedTransport(records))


def check_vlm(config: Config | None) -> None:
    from pipeline.policies.vlm_http import check_reachable

    if config is not None:
        check_reachable(config["url"], float(config["timeout_s"]), VLM_PREFIX + public_url(config["url"]))


def summarize_vlm(records: list[dict[str, Any]]) -> str:
    from pipeline.policies.vlm import audit_summary

    return audit_summary(records)


def make_remote(ref: str, options: OpenOptions) -> Policy:
    from pipeline.remote.client import RemotePolicy  # lazy: websockets

    return RemotePolicy(ref, timeout_s=options.timeout_s + REMOTE_SLACK_S)


def make_module(ref: str, options: OpenOptions) -> Policy:
    if not options.isolate:
        return make_policy(ref)
    from pipeline.remote.isolated import IsolatedPolicy  # lazy: the child-process runner

    return IsolatedPolicy(ref, timeout_s=options.timeout_s + REMOTE_SLACK_S)


def make_builtin(ref: str, options: OpenOptions) -> Policy:
    return make_policy(ref)


register(PolicyKind("builtin", lambda ref: True, make_builtin))
def configure_module(ref: str, config: Config | None) -> Config | None:
    """The sha256 of the module's source file (None when it has none), recorded in the
    run's manifest: an edited policy file makes a re-run or a resume refuse the folder
    instead of calling it up to date or mixing episodes of two versions. Files the module
    imports or loads (weights) are not covered: ``--overwrite`` after changing them."""
    no_config(ref, config)
    path = module_file(ref)
    return {"source_sha256": None if path is None else sha256_file(path)}


register(PolicyKind("module", lambda ref: ":" in ref, make_module, configure=configure_module, manifest_key="module"))
register(PolicyKind("remote", lambda ref: ref.startswith(("ws://", "wss://")), make_remote, names_ref=True))
register(PolicyKind("vlm", lambda ref: ref.startswith(VLM_PREFIX), make_vlm, configure=configure_vlm,
                    manifest_key="vlm", audit_dir="vlm", replay=replay_vlm, summarize_audit=summarize_vlm,
                    check=check_vlm))


def make_lerobot(ref: str, options: OpenOptions) -> Policy:
    from pipeline.policies.lerobot_checkpoint import make  # lazy: torch and lerobot

    return make(ref, options.config)


def configure_lerobot(ref: str, config: Config | None) -> Config:
    from pipeline.policies.lerobot_checkpoint import configure

    return configure(ref, config)


register(PolicyKind("lerobot", lambda ref: ref.startswith("lerobot:"), make_lerobot, configure=configure_lerobot,
                    manifest_key="lerobot"))


# openpi policy servers: openpi:ws://HOST:PORT[?key=value...] ---------------------------------


def configure_openpi(ref: str, config: Config | None) -> Config:
    """The key mapping the ref's query sets (recorded in the manifest; the URL is not, so
    that a server restarted on another port resumes the same run)."""
    from pipeline.remote.openpi_client import split_ref

    no_config(ref, config)
    return split_ref(ref)[1].to_dict()


def make_openpi(ref: str, options: OpenOptions) -> Policy:
    from pipeline.remote.openpi_client import OpenpiPolicy, split_ref
    from pipeline.remote.openpi_keys import OpenpiConfig

    url, config = split_ref(ref)
    if options.config is not None:
        config = OpenpiConfig.from_dict(options.config)
    return OpenpiPolicy(url, config, timeout_s=options.timeout_s + REMOTE_SLACK_S)


register(PolicyKind("openpi", lambda ref: ref.startswith("openpi:"), make_openpi, configure=configure_openpi,
                    manifest_key="openpi", names_ref=True))

"""Where every kind of policy reference is resolved: one registration per kind.

Each kind claims its references by an explicit rule, never by registration order: a
kind with a ``claim`` prefix (``vlm:``) owns every reference that starts with it, and the
prefixes of two kinds may not overlap (:func:`register` refuses the second); a kind with a
``claim`` predicate (the fallbacks ``module`` and ``builtin``) is asked only about
references that no prefix owns, and two predicates accepting one reference is an error
naming both. So every reference has one kind or none (:func:`claimants`). Built in:

=============  ==================  ===========================================================
kind           reference           makes
=============  ==================  ===========================================================
``vlm``        ``vlm:URL``         :class:`pipeline.policies.vlm.VLMPolicy` (an OpenAI-compatible
                                   endpoint; its configuration comes from ``--model`` and the
                                   ``--vlm-*`` flags, its exchanges are kept as an audit trail)
``lerobot``    ``lerobot:PATH``    :class:`pipeline.policies.lerobot_checkpoint.CheckpointPolicy` (a
                                   LeRobot checkpoint folder, loaded with the installed lerobot on
                                   ``--policy-device``; its features are checked up front)
``sb3``        ``sb3:PATH``        :class:`pipeline.loop.sb3_policy.SB3Policy` (a saved Stable-Baselines3
                                   model's zip, on the CPU, with the view and action mapping its
                                   spaces say it was trained with)
``openpi``     ``openpi:ws://...`` :class:`pipeline.remote.openpi_client.OpenpiPolicy` (an openpi
                                   policy server; key names in the URL's query)
``remote``     ``ws://HOST:PORT``  :class:`pipeline.remote.client.RemotePolicy` (``pipeline serve``)
``module``     ``module:callable`` a user's policy, in a child process unless ``isolate`` is off
                                   (:class:`pipeline.remote.isolated.IsolatedPolicy`)
``builtin``    a name              :func:`pipeline.policies.base.make_policy` (``still``,
                                   ``oracle``, ``chase``, ``predictive``, ...)
=============  ==================  ===========================================================

A new kind (a LeRobot checkpoint, an openpi server) is one :func:`register` call with a
:class:`PolicyKind`, whose ``form``, ``flags`` and ``from_flags`` are all the command line
needs (``pipeline eval --policy``'s help, which flags it takes); the job layer (:mod:`pipeline.jobs.evaluate`, :mod:`pipeline.jobs.replay`)
only talks to kinds. Optional abilities of a made policy are protocols, checked with
``isinstance``: :class:`Closable`, :class:`Timed` (remote round trips), :class:`Audited`
(an audit trail, e.g. a VLM's exchanges).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Protocol, cast, runtime_checkable

from catalog.store.hashing import sha256_file
from pipeline.loop.deadlines import WATCHDOG_S
from pipeline.vlm_kind import (
    VLM_FLAGS,
    VLM_PREFIX,
    check_vlm,
    configure_vlm,
    make_vlm,
    public_url,
    replay_vlm,
    summarize_vlm,
    vlm_from_flags,
)
from schemas.errors import PolicyError, SpecError
from schemas.names import shorten

if TYPE_CHECKING:  # the command line reads the kinds to build its parser: the loop is imported when used
    import numpy as np

    from pipeline.policies.base import Observation, Policy, Task

#: Extra seconds a remote policy's socket waits beyond the deadline or watchdog (the
#: rollout's fires first and names the fault).
REMOTE_SLACK_S = 5.0

#: A kind's configuration (e.g. a VLM's), JSON-ready: recorded in the run's manifest.
Config = dict[str, Any]


@dataclass(frozen=True)
class OpenOptions:
    """How to make a policy: the per-call timeout it may wait (a socket's), whether a
    user's code runs in a child process, and the kind's configuration (None: none)."""

    #: The rollout's watchdog by default (:data:`pipeline.loop.deadlines.WATCHDOG_S`).
    timeout_s: float = WATCHDOG_S
    isolate: bool = True
    config: Config | None = None
    #: A held-out run's seal (:class:`pipeline.remote.sandbox.Seal`): a user's code runs sealed.
    seal: Any = None


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


#: A kind's claim: a prefix (or several) it owns, or a predicate over the references no prefix owns.
Claim = str | tuple[str, ...] | Callable[[str], bool]


@dataclass(frozen=True)
class PolicyKind:
    """One kind of policy reference.

    ``claim`` says which references are of this kind (see the module docstring): a prefix
    or a tuple of prefixes, or a predicate asked only about references no prefix owns.
    ``make(ref, options)`` makes a fresh policy; ``configure(ref, config)`` checks and
    completes the kind's configuration in the driver (default: none allowed);
    ``manifest_key`` names the configuration's key in the run's manifest (its URL without
    credentials); an ``audit_dir`` keeps the policies' :class:`Audited` records beside the
    shards, and ``replay(config, records)`` makes the policy that re-runs an episode from
    them (``summarize_audit(records)``: the run summary's line about them).
    ``names_ref`` prefixes the reference to the errors of describing the policy.
    ``check(config, resolution)`` makes sure, in the driver before the first episode, that what every
    episode needs is there (a VLM's endpoint accepts a connection): PolicyError if not.

    What the command line asks of a kind: ``form`` (how a reference is written, e.g.
    ``vlm:URL``) and ``about`` make ``--policy``'s help; ``flags`` are the command-line
    options (argparse names -> defaults) only this kind takes, ``from_flags(ref, values)``
    its configuration from their values; ``imports_module``: the reference names a module
    that the current folder may hold; ``servable``: ``pipeline serve`` can serve it.
    ``examples`` are references of this kind: :func:`register` refuses a kind that claims
    another's example or leaves one of its own to another kind. ``sealed_files`` marks a
    kind that runs a user's code: on a private split it is served sealed in a child.
    """

    name: str
    claim: Claim
    make: Callable[[str, OpenOptions], Policy]
    configure: Callable[[str, Config | None], Config | None] = no_config
    manifest_key: str | None = None
    audit_dir: str | None = None
    replay: Callable[[Config, list[dict[str, Any]]], Policy] | None = None
    summarize_audit: Callable[[list[dict[str, Any]]], str] | None = None
    names_ref: bool = False
    check: Callable[[Config | None, int], None] | None = None
    form: str = ""
    about: str = ""
    flags: Mapping[str, Any] = field(default_factory=dict)
    from_flags: Callable[[str, Mapping[str, Any]], Config | None] | None = None
    imports_module: bool = False
    servable: bool = False
    examples: tuple[str, ...] = ()
    #: A kind that runs a user's code (a module, a model that unpickles code when loaded):
    #: the files of a reference it must read; on a private split it runs sealed
    #: (:func:`pipeline.remote.sandbox.sealing`). None: it runs no user's code.
    sealed_files: Callable[[str], tuple[str, ...]] | None = None
    #: Its policies carry nothing from one episode to the next (``reset`` starts afresh), so an
    #: interrupted shard resumes between episodes with the same bytes (Dyana's built-ins); a
    #: user's policy, a server or a model may keep state, so its shard is run again whole.
    episodic: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise SpecError(f"a policy kind's name must be a non-empty str, got {shorten(repr(self.name))}")
        prefixes = (self.claim,) if isinstance(self.claim, str) else self.claim
        if isinstance(prefixes, tuple):
            if not prefixes or not all(isinstance(p, str) and p for p in prefixes):
                raise SpecError(f"policy kind {self.name!r}: claim must be a non-empty prefix, a tuple of them or a "
                                f"predicate, got {shorten(repr(self.claim))}")
        elif not callable(self.claim):
            raise SpecError(f"policy kind {self.name!r}: claim must be a prefix, a tuple of prefixes or a predicate, "
                            f"got {shorten(repr(self.claim))}")
        if not isinstance(self.examples, tuple) or not all(isinstance(e, str) and e for e in self.examples):
            raise SpecError(f"policy kind {self.name!r}: examples must be a tuple of references, "
                            f"got {shorten(repr(self.examples))}")
        object.__setattr__(self, "flags", MappingProxyType(dict(self.flags)))

    @property
    def prefixes(self) -> tuple[str, ...]:
        """The prefixes this kind owns (none for a predicate kind)."""
        return (self.claim,) if isinstance(self.claim, str) else self.claim if isinstance(self.claim, tuple) else ()

    @property
    def usage(self) -> str:
        """This kind in ``--policy``'s help: its form and what it is."""
        form = self.form or (self.prefixes[0] + "..." if self.prefixes else self.name)
        return f"{form} ({self.about})" if self.about else form

    def manifest(self, config: Config | None) -> dict[str, Any]:
        """The run manifest's keys for this configuration."""
        if self.manifest_key is None or config is None:
            return {}
        public = {k: v for k, v in config.items() if k != "url"}
        if "url" in config:
            public["url"] = public_url(config["url"])
        return {self.manifest_key: public}


#: The registered kinds, in the order ``--policy``'s help lists them (the order decides nothing else).
KINDS: list[PolicyKind] = []


def claimants(ref: str, kinds: list[PolicyKind] | None = None) -> list[PolicyKind]:
    """The kinds that claim ``ref``: those owning a prefix it starts with, else the predicate
    kinds accepting it. One in a sound registry; none for a reference no kind takes."""
    kinds = KINDS if kinds is None else kinds
    owners = [kind for kind in kinds if kind.prefixes and ref.startswith(kind.prefixes)]
    if owners:
        return owners
    return [kind for kind in kinds if not kind.prefixes and callable(kind.claim) and kind.claim(ref)]


def register(kind: PolicyKind) -> PolicyKind:
    """Add a kind, or replace the one of the same name in its place. SpecError, leaving the
    registry as it was, when a prefix overlaps another kind's (one starts with the other) or
    an example of any kind would then be claimed by another kind or by two."""
    if not isinstance(kind, PolicyKind):
        raise SpecError(f"register() takes a PolicyKind, got {type(kind).__name__}")
    for other in KINDS:
        clash = next(((mine, theirs) for mine in kind.prefixes for theirs in other.prefixes
                      if other.name != kind.name and (mine.startswith(theirs) or theirs.startswith(mine))), None)
        if clash is not None:
            raise SpecError(f"policy kind {kind.name!r}: prefix {clash[0]!r} overlaps {clash[1]!r} of kind "
                            f"{other.name!r}, so a reference could have two kinds")
    names = [k.name for k in KINDS]
    kinds = [kind if k.name == kind.name else k for k in KINDS] + ([] if kind.name in names else [kind])
    for owner in kinds:
        for example in owner.examples:
            found = [k.name for k in claimants(example, kinds)]
            if found != [owner.name]:
                raise SpecError(f"policy kind {kind.name!r}: example {shorten(repr(example))} of kind {owner.name!r} "
                                f"would be claimed by {found or 'no kind'}")
    KINDS[:] = kinds
    return kind


def kind_of(ref: str) -> PolicyKind:
    """The one kind that claims ``ref``; SpecError when it is not a non-empty string, when no
    kind claims it, or when two predicate kinds both do (a registry fault, named)."""
    forms = ", ".join(kind.form or kind.name for kind in KINDS)
    if not isinstance(ref, str) or not ref:
        raise SpecError(f"--policy must be one of the forms {forms}, got {shorten(repr(ref))}")
    found = claimants(ref)
    if len(found) == 1:
        return found[0]
    if not found:
        raise SpecError(f"no policy kind claims {shorten(repr(ref))}: expected one of the forms {forms}")
    raise SpecError(f"policy {shorten(repr(ref))} is claimed by kinds {[k.name for k in found]}: "
                    f"a registered claim overlaps another")


def kind_named(name: str) -> PolicyKind:
    for kind in KINDS:
        if kind.name == name:
            return kind
    raise SpecError(f"unknown policy kind {name!r}: registered {[k.name for k in KINDS]}")


def policy_help(servable: bool = False) -> str:
    """The registered kinds' usages (only those ``pipeline serve`` can serve, if asked), as
    ``--policy``'s help lists them."""
    usages = [kind.usage for kind in KINDS if kind.servable or not servable]
    return ", ".join(usages[:-1]) + " or " + usages[-1] if len(usages) > 1 else "".join(usages)


def flag_defaults() -> dict[str, Any]:
    """Every kind's command-line flags and their defaults (a parser's ``set_defaults``)."""
    return {dest: default for kind in KINDS for dest, default in kind.flags.items()}


def config_from_flags(ref: str, values: Mapping[str, Any]) -> Config | None:
    """The configuration ``ref``'s kind takes from the command line (``values``: argparse
    names -> values); SpecError naming a flag of another kind that is set."""
    kind = kind_of(ref)
    for other in KINDS:
        for dest, default in other.flags.items():
            if other is not kind and values.get(dest, default) != default:
                raise SpecError(f"--{dest.replace('_', '-')} is for --policy {other.form or other.name} only")
    if kind.from_flags is None:
        return None
    return kind.from_flags(ref, {dest: values.get(dest, default) for dest, default in kind.flags.items()})


def serving_factory(ref: str, values: Mapping[str, Any]) -> Callable[[], Policy]:
    """What ``pipeline serve`` serves for ``ref``: a maker of its policy in this process, with
    its kind's configuration from the command line's ``values``; SpecError for a kind it
    cannot serve (one that is itself a server, or a VLM)."""
    kind = kind_of(ref)
    if not kind.servable:
        raise SpecError(f"pipeline serve serves {policy_help(servable=True)}, not {shorten(repr(ref))}")
    options = OpenOptions(isolate=False, config=kind.configure(ref, config_from_flags(ref, values)))
    return lambda: kind.make(ref, options)


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


# the built-in kinds ----------------------------------------------------------------
# Each imports its implementation when first used: the VLM client, the WebSocket client
# and the child-process runner are not needed by the other kinds.

def make_remote(ref: str, options: OpenOptions) -> Policy:
    from pipeline.remote.client import RemotePolicy  # lazy: websockets

    return RemotePolicy(ref, timeout_s=options.timeout_s + REMOTE_SLACK_S)


def isolated(ref: str, options: OpenOptions) -> Policy:
    """``ref`` served by a child ``pipeline serve`` (sealed when ``options`` carry a seal)."""
    from pipeline.remote.isolated import IsolatedPolicy  # lazy: the child-process runner

    return IsolatedPolicy(ref, timeout_s=options.timeout_s + REMOTE_SLACK_S, seal=options.seal)


def make_module(ref: str, options: OpenOptions) -> Policy:
    from pipeline.policies.base import make_policy

    return isolated(ref, options) if options.isolate else make_policy(ref)


def make_builtin(ref: str, options: OpenOptions) -> Policy:
    from pipeline.policies.base import make_policy

    return make_policy(ref)


def configure_module(ref: str, config: Config | None) -> Config | None:
    """The sha256 of the module's source file (None when it has none), recorded in the
    run's manifest: an edited policy file makes a re-run or a resume refuse the folder
    instead of calling it up to date or mixing episodes of two versions. Files the module
    imports or loads (weights) are not covered: ``--overwrite`` after changing them."""
    from pipeline.policies.base import module_file

    no_config(ref, config)
    path = module_file(ref)
    return {"source_sha256": None if path is None else sha256_file(path)}


def make_lerobot(ref: str, options: OpenOptions) -> Policy:
    from pipeline.policies.lerobot_checkpoint import make  # lazy: torch and lerobot

    return make(ref, options.config)


def configure_lerobot(ref: str, config: Config | None) -> Config:
    from pipeline.policies.lerobot_checkpoint import configure

    return configure(ref, config)


def lerobot_from_flags(ref: str, values: Mapping[str, Any]) -> Config:
    return {"device": values["policy_device"] or "cpu"}


def make_sb3(ref: str, options: OpenOptions) -> Policy:
    """In this process; sealed in a child on a private split (SB3's ``load`` unpickles code)."""
    if options.seal is not None:
        return isolated(ref, options)
    from pipeline.loop.sb3_policy import make  # lazy: torch and stable_baselines3

    return cast("Policy", make(ref, options.config))  # a frozen dataclass: its members are read-only


def check_sb3(config: Config | None, resolution: int) -> None:
    """A model trained on images of another side than the run's: one line before the run."""
    trained = None if config is None else config.get("resolution")
    if trained is not None and trained != resolution:
        raise SpecError(f"--resolution {resolution}: the sb3 model {shorten(str(config and config.get('model')))} was "
                        f"trained on {trained} px images: pass --resolution {trained}")


def sb3_files(ref: str) -> tuple[str, ...]:
    from pipeline.loop.sb3_policy import split_ref

    return (os.path.abspath(os.path.expanduser(split_ref(ref)[1])),)


def configure_sb3(ref: str, config: Config | None) -> Config:
    from pipeline.loop.sb3_policy import configure

    return configure(ref, config)


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


# the two predicate kinds split what no prefix owns: a name, or module:callable (it has a colon)
register(PolicyKind("builtin", lambda ref: ":" not in ref, make_builtin, episodic=True, form="oracle, still, chase, predictive",
                    servable=True, examples=("still", "oracle", "blind-centre", "nosuch")))
register(PolicyKind("module", lambda ref: ":" in ref, make_module, configure=configure_module, manifest_key="module",
                    form="module:callable", imports_module=True, servable=True, sealed_files=lambda ref: (),
                    examples=("mypkg.policies:make", "vlm.x:make", "ws:x")))
register(PolicyKind("remote", ("ws://", "wss://"), make_remote, names_ref=True, form="ws://HOST:PORT",
                    about="a pipeline serve or other dyana/1 server", examples=("ws://127.0.0.1:8000", "wss://h/p")))
register(PolicyKind("vlm", VLM_PREFIX, make_vlm, configure=configure_vlm, manifest_key="vlm", audit_dir="vlm",
                    replay=replay_vlm, summarize_audit=summarize_vlm, check=check_vlm, form="vlm:URL",
                    about="an OpenAI-compatible endpoint, e.g. vlm:http://127.0.0.1:8000/v1", flags=VLM_FLAGS,
                    from_flags=vlm_from_flags, examples=("vlm:http://127.0.0.1:8000/v1",)))
register(PolicyKind("lerobot", "lerobot:", make_lerobot, configure=configure_lerobot, manifest_key="lerobot",
                    form="lerobot:PATH", about="a LeRobot checkpoint folder, run with the lerobot installed here",
                    flags={"policy_device": None}, from_flags=lerobot_from_flags, servable=True,
                    examples=("lerobot:outputs/train/pretrained_model", "lerobot:ckpt")))
register(PolicyKind("openpi", "openpi:", make_openpi, configure=configure_openpi, manifest_key="openpi",
                    names_ref=True, form="openpi:ws://HOST:PORT", about="an openpi policy server",
                    examples=("openpi:ws://127.0.0.1:8000?image=observation/image",)))
register(PolicyKind("sb3", "sb3:", make_sb3, configure=configure_sb3, manifest_key="sb3", form="sb3:MODEL.zip",
                    servable=True, sealed_files=sb3_files, check=check_sb3,
                    about="a saved Stable-Baselines3 model (sb3:ALGO:MODEL.zip names its algorithm)",
                    examples=("sb3:ppo_dyana.zip", "sb3:SAC:models/sac.zip")))


class Unavailable:
    """Stands in for a policy that could not be made: its episode records the reason."""

    action_horizon = 1
    privileged = False

    def __init__(self, name: str, reason: str) -> None:
        self.name, self.reason = name, reason

    def reset(self, task: Task) -> None:
        raise PolicyError(self.reason)

    def act(self, obs: Observation) -> np.ndarray:
        raise PolicyError(self.reason)

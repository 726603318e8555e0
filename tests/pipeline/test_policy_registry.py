"""The policy registry: every kind of ``--policy`` reference resolves through one table,
and a new kind is one registration that the job layer uses without a case of its own."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from pipeline import policy_registry
from pipeline.policies.base import Observation, Task
from pipeline.policies.chase import ChasePolicy
from pipeline.policy_registry import (
    OpenOptions,
    PolicyKind,
    claimants,
    config_from_flags,
    describe_policy,
    flag_defaults,
    kind_of,
    open_policy,
    policy_help,
    public_url,
    register,
)
from schemas.errors import PolicyError, SpecError


def test_each_reference_finds_its_kind():
    assert [kind_of(ref).name for ref in ("chase", "tests.x:make", "ws://127.0.0.1:1", "vlm:http://h/v1")] == [
        "builtin", "module", "remote", "vlm"]
    assert isinstance(open_policy("chase"), ChasePolicy)
    with pytest.raises(SpecError, match="--policy must be"):
        kind_of("")


def test_only_a_vlm_takes_a_vlm_configuration():
    with pytest.raises(SpecError, match="for vlm:URL policies, not 'chase'"):
        kind_of("chase").configure("chase", {"model": "m"})
    with pytest.raises(SpecError, match="--model"):
        kind_of("vlm:http://h/v1").configure("vlm:http://h/v1", {"model": ""})
    config = kind_of("vlm:http://u:p@h:8/v1").configure("vlm:http://u:p@h:8/v1", {"model": "m"})
    assert config is not None and config["url"] == "http://u:p@h:8/v1"
    assert kind_of("vlm:x").manifest(config)["vlm"]["url"] == "http://h:8/v1"  # no credentials in a manifest
    assert public_url("https://user:secret@example.org/v1?key=1") == "https://example.org/v1"


def test_an_unreachable_server_is_named_when_described():
    with pytest.raises(PolicyError, match=r"^ws://127\.0\.0\.1:9: "):
        describe_policy("ws://127.0.0.1:9", OpenOptions(timeout_s=1.0))


class Fixed:
    name, action_horizon, privileged = "fixed", 1, False

    def reset(self, task: Task) -> None:
        return None

    def act(self, obs: Observation) -> np.ndarray:
        return np.zeros(18, np.float32)


def test_a_new_kind_is_one_registration(monkeypatch):
    monkeypatch.setattr(policy_registry, "KINDS", list(policy_registry.KINDS))
    register(PolicyKind("fixed", "fixed:", lambda ref, options: Fixed(), form="fixed:ANY", examples=("fixed:a",)))
    assert kind_of("fixed:anything").name == "fixed" and kind_of("chase").name == "builtin"
    assert describe_policy("fixed:anything") == ("fixed", False)
    assert policy_help().endswith(" or fixed:ANY") and "fixed" not in policy_help(servable=True)
    with pytest.raises(SpecError, match="takes a PolicyKind"):
        register("fixed")  # type: ignore[arg-type]  # the mistake under test


#: References and the one kind each must have: every kind's own examples, plus edge cases
#: that a registration-order rule used to settle (a module named like a prefix, a colon).
SAMPLES = {
    "chase": "builtin", "blind-sweep": "builtin", "nosuch": "builtin",
    "tests.x:make": "module", "vlm.policies:make": "module", "lerobot_pkg:make": "module", "ws:x": "module",
    "ws://127.0.0.1:1": "remote", "wss://example.org/p": "remote",
    "vlm:http://h/v1": "vlm", "vlm:": "vlm", "lerobot:ckpt": "lerobot", "lerobot:/abs/path:with:colons": "lerobot",
    "openpi:ws://127.0.0.1:8000?image=observation/image": "openpi",
}


def test_every_reference_is_claimed_by_exactly_one_kind():
    table = dict(SAMPLES) | {example: kind.name for kind in policy_registry.KINDS for example in kind.examples}
    assert all(kind.examples for kind in policy_registry.KINDS)  # each built-in kind shows what it claims
    claimed = {ref: [kind.name for kind in claimants(ref)] for ref in table}
    assert claimed == {ref: [name] for ref, name in table.items()}


@pytest.mark.parametrize("order", ["reversed", "rotated", "shuffled"])
def test_which_kind_claims_a_reference_does_not_depend_on_registration_order(monkeypatch, order):
    kinds = list(policy_registry.KINDS)
    arranged = {"reversed": kinds[::-1], "rotated": kinds[3:] + kinds[:3],
                "shuffled": [kinds[i] for i in np.random.default_rng(7).permutation(len(kinds))]}[order]
    monkeypatch.setattr(policy_registry, "KINDS", [])
    for kind in arranged:
        register(kind)
    assert {ref: kind_of(ref).name for ref in SAMPLES} == SAMPLES


def test_a_kind_whose_claim_clashes_is_refused(monkeypatch):
    before = list(policy_registry.KINDS)
    monkeypatch.setattr(policy_registry, "KINDS", list(before))

    def make(ref, options):
        return Fixed()

    for prefix, other in (("vlm:h", "vlm"), ("v", "vlm"), ("ws://", "remote"), (("x:", "lerobot:ckpt"), "lerobot")):
        with pytest.raises(SpecError, match=f"of kind '{other}', so a reference could have two kinds"):
            register(PolicyKind("clash", prefix, make))
    with pytest.raises(SpecError, match=r"example 'still' of kind 'builtin' would be claimed by \['builtin', 'all'\]"):
        register(PolicyKind("all", lambda ref: True, make))  # a predicate that takes the built-in names too
    with pytest.raises(SpecError, match=r"example 'chase' of kind 'mine' would be claimed by \['builtin'\]"):
        register(PolicyKind("mine", "mine:", make, examples=("chase",)))  # an example it does not claim
    assert policy_registry.KINDS == before  # nothing was added
    replaced = register(PolicyKind("vlm", "vlm:", make))  # a kind replaces its namesake, in its place
    assert [k.name for k in policy_registry.KINDS] == [k.name for k in before] and kind_of("vlm:x") is replaced
    with pytest.raises(SpecError, match="claim must be a non-empty prefix"):
        PolicyKind("empty", "", make)


def test_two_kinds_claiming_one_reference_is_an_error_not_a_choice(monkeypatch):
    """Were a predicate kind added without the registration's checks, kind_of names the
    conflict instead of taking whichever comes first."""
    extra = PolicyKind("greedy", lambda ref: ref.startswith("mypkg"), lambda ref, options: Fixed())
    monkeypatch.setattr(policy_registry, "KINDS", list(policy_registry.KINDS) + [extra])
    assert kind_of("chase").name == "builtin"
    with pytest.raises(SpecError, match=r"claimed by kinds \['module', 'greedy'\]"):
        kind_of("mypkg.pol:hold")


def test_a_kinds_flags_are_its_own(monkeypatch):
    values = flag_defaults()
    assert config_from_flags("chase", values) is None
    assert config_from_flags("lerobot:ckpt", values) == {"device": "cpu"}
    assert config_from_flags("lerobot:ckpt", values | {"policy_device": "cuda"}) == {"device": "cuda"}
    assert config_from_flags("vlm:http://h/v1", values | {"model": "m"})["model"] == "m"
    with pytest.raises(SpecError, match="^--model is for --policy vlm:URL only$"):
        config_from_flags("lerobot:ckpt", values | {"model": "m"})
    with pytest.raises(SpecError, match="^--vlm-seed is for --policy vlm:URL only$"):
        config_from_flags("tests.x:make", values | {"vlm_seed": 3})
    with pytest.raises(SpecError, match="^--policy-device is for --policy lerobot:PATH only$"):
        config_from_flags("vlm:http://h/v1", values | {"model": "m", "policy_device": "cuda"})
    monkeypatch.setattr(policy_registry, "KINDS", list(policy_registry.KINDS))
    register(PolicyKind("fixed", "fixed:", lambda ref, options: Fixed(), form="fixed:ANY", flags={"fixed_gain": 1},
                        from_flags=lambda ref, flags: {"gain": flags["fixed_gain"]}))
    assert config_from_flags("fixed:a", {"fixed_gain": 4}) == {"gain": 4}
    with pytest.raises(SpecError, match="^--fixed-gain is for --policy fixed:ANY only$"):
        config_from_flags("chase", {"fixed_gain": 4})


def test_a_module_policy_records_its_source_file_without_running_it(tmp_path, monkeypatch):
    """The module kind's configuration is the sha256 of the file that defines the module,
    found without importing it (a package's __init__ that would fail is never run): an
    edited file is another configuration, so another job for the same folder."""
    package = tmp_path / "mypkg"
    package.mkdir()
    (package / "__init__.py").write_text("raise RuntimeError('imported')\n")
    policy_file = package / "pol.py"
    policy_file.write_text("def hold(obs):\n    return obs\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    kind = kind_of("mypkg.pol:hold")
    config = kind.configure("mypkg.pol:hold", None)
    assert config == {"source_sha256": hashlib.sha256(policy_file.read_bytes()).hexdigest()}
    assert kind.manifest(config) == {"module": config}
    policy_file.write_text("def hold(obs):\n    return obs  # edited\n")
    assert kind.configure("mypkg.pol:hold", None) != config
    assert kind.configure("nosuchmodule_xyz:make", None) == {"source_sha256": None}  # describing it then fails
    with pytest.raises(SpecError, match="for vlm:URL policies"):
        kind.configure("mypkg.pol:hold", {"model": "m"})

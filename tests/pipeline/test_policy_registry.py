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
    describe_policy,
    kind_of,
    open_policy,
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
    register(PolicyKind("fixed", lambda ref: ref.startswith("fixed:"), lambda ref, options: Fixed()))
    assert kind_of("fixed:anything").name == "fixed" and kind_of("chase").name == "builtin"
    assert describe_policy("fixed:anything") == ("fixed", False)
    with pytest.raises(SpecError, match="takes a PolicyKind"):
        register("fixed")  # type: ignore[arg-type]  # the mistake under test


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

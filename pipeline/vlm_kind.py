"""The ``vlm`` policy kind's steps (:mod:`pipeline.policy_registry` registers them): an
OpenAI-compatible endpoint, configured from ``--model`` and the ``--vlm-*`` flags, its
exchanges kept as an audit trail and replayed from it. Each step imports the VLM client
when first used."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any
from urllib.parse import urlsplit, urlunsplit

from schemas.errors import SpecError
from schemas.names import shorten

if TYPE_CHECKING:
    from pipeline.policies.base import Policy

#: A kind's configuration, JSON-ready (:data:`pipeline.policy_registry.Config`).
Config = dict[str, Any]


def public_url(url: str) -> str:
    """A URL without user:password@ (credentials never reach a manifest)."""
    parts = urlsplit(url)
    host = parts.hostname or ""
    netloc = host + (f":{parts.port}" if parts.port else "")
    return urlunsplit((parts.scheme, netloc, parts.path, "", ""))


VLM_PREFIX = "vlm:"


def make_vlm(ref: str, options: Any) -> Policy:
    """``options``: the registry's OpenOptions (its ``config``)."""
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


def check_vlm(config: Config | None, resolution: int) -> None:
    from pipeline.policies.vlm_http import check_reachable

    if config is not None:
        check_reachable(config["url"], float(config["timeout_s"]), VLM_PREFIX + public_url(config["url"]))


def summarize_vlm(records: list[dict[str, Any]]) -> str:
    from pipeline.policies.vlm import audit_summary

    return audit_summary(records)


#: The --model and --vlm-* flags (argparse names) and their defaults: the parser's and the
#: check that no other kind is given them.
VLM_FLAGS = {"model": None, "vlm_every": 5, "vlm_latency_frames": 0, "vlm_observe_images": 2, "vlm_on_fault": "error",
             "vlm_timeout": 60.0, "vlm_template": "v1", "vlm_api_key_env": "OPENAI_API_KEY",
             "vlm_no_json_schema": False, "vlm_temperature": 0.0, "vlm_seed": 0}


def vlm_from_flags(ref: str, values: Mapping[str, Any]) -> Config:
    if not values["model"]:
        raise SpecError("--policy vlm:URL needs --model NAME (the model the endpoint serves)")
    return {
        "model": values["model"], "every": values["vlm_every"], "latency_frames": values["vlm_latency_frames"],
        "observe_images": values["vlm_observe_images"], "on_fault": values["vlm_on_fault"],
        "timeout_s": values["vlm_timeout"], "template": values["vlm_template"],
        "api_key_env": values["vlm_api_key_env"], "json_schema": not values["vlm_no_json_schema"],
        "temperature": values["vlm_temperature"], "seed": values["vlm_seed"],
    }

"""The byte settings are one dataclass (schemas.settings.BuildSettings): each of its fields
has a CLI flag (or says how it is derived), a row on the settings reference page, a place
on `catalog info`'s settings line, and round-trips through a manifest."""

from __future__ import annotations

import argparse
import json
import re
from dataclasses import fields
from pathlib import Path

import pytest

from catalog.store.manifest import CodeInfo, Manifest, write_manifest
from pipeline import cli as pipeline_cli
from pipeline.cli_catalog import main as catalog_main
from schemas.errors import SpecError
from schemas.renderers import REBUILDABLE_DATASET_VERSIONS
from schemas.settings import BuildSettings, setting_docs, setting_flags, setting_names

DOCS_PAGE = Path(__file__).resolve().parents[2] / "docs" / "reference" / "settings.md"

#: A value other than the default for every field (a new field needs one here), but the
#: dataset version while this code writes one only (5.0.0: ``--renderer full`` is retired).
CHANGED = {
    "resolution": 32,
    "jpeg_quality": 75,
    "fps": 10,
    "image_format": "png",
    "dataset_version": REBUILDABLE_DATASET_VERSIONS[0],
    "obstacle_clearance": True,
    "protocol": {"latency_frames": 2, "realtime": False},
    "hand_model": "body-1",
    "formats": ("parquet",),
}


def command_flags(name: str) -> set[str]:
    """The long options of one `pipeline` command, as its usage line lists them."""
    command = next(c for c in pipeline_cli.COMMANDS if c.name == name)
    parser = argparse.ArgumentParser(prog=name)
    command.add_arguments(parser)
    return set(re.findall(r"--[a-z][a-z0-9-]*", parser.format_usage()))


def test_every_field_is_documented_with_its_flags_or_derivation():
    assert set(setting_docs()) == set(setting_names())
    build, run = command_flags("build"), command_flags("eval")
    for name, doc in setting_docs().items():
        assert doc.doc, name
        for flag in doc.flags:
            assert flag in build | run, f"{name}: {flag} is on neither pipeline build nor pipeline eval"
        if name != "protocol":  # the protocol is a run's only
            assert set(doc.flags) <= build, name
    assert setting_flags()["--renderer"] == "dataset_version"


def test_every_field_has_a_row_on_the_settings_page():
    rows = [line for line in DOCS_PAGE.read_text().splitlines() if line.startswith("| `")]
    documented = [row.split("`")[1] for row in rows]
    assert documented == list(setting_names())
    for row, doc in zip(rows, setting_docs().values()):
        assert all(f"`{flag}`" in row for flag in doc.flags), row


def test_every_field_round_trips_through_a_manifest():
    assert set(CHANGED) == set(setting_names()), "give the new field a non-default value in CHANGED"
    settings = BuildSettings(**CHANGED)
    for f in fields(BuildSettings):
        if f.name == "dataset_version" and len(REBUILDABLE_DATASET_VERSIONS) == 1:
            continue
        assert getattr(settings, f.name) != f.default, f.name
    manifest = Manifest.create("linear-fast", 7, settings.to_dict(), [], code=CodeInfo("0.1.0", None))
    again = Manifest.from_dict(json.loads(json.dumps(manifest.to_dict())))
    assert BuildSettings.from_dict(again.settings) == settings


def test_the_defaults_keep_the_settings_a_build_always_wrote():
    assert BuildSettings().to_dict() == {"resolution": 224, "jpeg_quality": 90, "fps": 20, "image_format": "jpeg",
                                         "dataset_version": "5.0.0", "formats": ["parquet", "mcap"]}


def test_every_field_is_on_catalog_info(tmp_path, capsys):
    settings = BuildSettings(**CHANGED)
    write_manifest(tmp_path, Manifest.create("linear-fast", 7, settings.to_dict(), [], code=CodeInfo("0.1.0", None)))
    assert catalog_main(["info", str(tmp_path)]) == 0
    rows = dict(line.split(None, 1) for line in capsys.readouterr().out.splitlines())
    for name in setting_names():
        if name == "dataset_version":
            assert rows["dataset"].startswith(f"{CHANGED['dataset_version']} "), rows["dataset"]
        else:
            assert f"{name}=" in rows["settings"], name
    assert "protocol={\"latency_frames\":2,\"realtime\":false}" in rows["settings"]


def test_from_dict_names_an_unknown_or_missing_key():
    with pytest.raises(SpecError, match=r"unknown settings \['hdr'\]"):
        BuildSettings.from_dict({**BuildSettings().to_dict(), "hdr": True})
    with pytest.raises(SpecError, match="settings lack 'resolution'"):
        BuildSettings.from_dict({"jpeg_quality": 90, "dataset_version": "5.0.0"})
    with pytest.raises(SpecError, match="resolution must be an integer in"):
        BuildSettings.from_dict({**BuildSettings().to_dict(), "resolution": True})

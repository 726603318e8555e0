"""``--version`` of the three programs names the code version and the dataset version it writes."""

from __future__ import annotations

import pytest

from pipeline.cli import main as pipeline_main
from pipeline.cli_catalog import main as catalog_main
from schemas.versions import CODE_VERSION, DATASET_VERSION
from scoring.cli import main as scoring_main


@pytest.mark.parametrize(
    "main, argv, prog",
    [
        (pipeline_main, ["--version"], "pipeline"),
        (pipeline_main, ["build", "--version"], "pipeline build"),
        (catalog_main, ["--version"], "catalog"),
        (catalog_main, ["info", "--version"], "catalog info"),
        (scoring_main, ["--version"], "scoring"),
    ],
)
def test_version_names_code_and_dataset(main, argv, prog, capsys):
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 0
    assert capsys.readouterr().out == f"{prog} (dyana {CODE_VERSION}, writes dataset {DATASET_VERSION})\n"

"""MkDocs hook: adds the generated pages to the site at build time (nothing is committed).

- ``reference/cli.md`` from the console scripts' argparse parsers (cli_reference.py);
- ``results/*.md`` and ``benchmarks.md`` from ``benchmarks/results/`` (results_pages.py),
  with the raw result files published under ``results/files/``;
- ``changelog.md`` from ``CHANGELOG.md``.

Registered in mkdocs.yml under ``hooks:``. The list of generated pages is site_pages.py
(which tests/docs imports without needing MkDocs).
"""

from __future__ import annotations

import results_pages
from mkdocs.config.defaults import MkDocsConfig
from mkdocs.structure.files import File, Files
from site_pages import GENERATED, ROOT


def on_files(files: Files, config: MkDocsConfig) -> Files:
    for uri, render in GENERATED.items():
        if files.get_file_from_path(uri) is not None:
            raise ValueError(f"docs/{uri} is generated at build time: delete the committed copy")
        files.append(File.generated(config, uri, content=render(ROOT)))
    for uri, path in results_pages.published_files(ROOT).items():
        files.append(File.generated(config, uri, abs_src_path=str(path)))
    return files

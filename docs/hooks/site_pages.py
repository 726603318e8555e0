"""The pages that exist only in the built site, and their renderers (no MkDocs needed).

generated_pages.py (the MkDocs hook) adds them at build time; tests/docs reads
:data:`GENERATED` to check links to them and that each renders.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cli_reference
import results_pages

ROOT = Path(__file__).resolve().parents[2]


def changelog_page(root: Path) -> str:
    return (root / "CHANGELOG.md").read_text(encoding="utf-8")


#: Page path relative to docs/ -> renderer(repository root) -> Markdown.
GENERATED: dict[str, Callable[[Path], str]] = {
    "reference/cli.md": cli_reference.render,
    **results_pages.PAGES,
    "changelog.md": changelog_page,
}

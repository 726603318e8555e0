"""The manual's tests: every ```bash and ```python block of README.md and docs/**/*.md runs.

How a page is run (what a page author relies on):

- Pages: README.md, then docs/**/*.md; pages generated at build time (docs/hooks/) are not
  run. One test per page, each page in a fresh temporary folder, in a process of its own;
  three pages run at a time. The pages' tests are marked ``manual``: ``.ci/run`` runs them
  in a step of their own (``python -m pytest -n 0 -m 'manual and not slow' tests/docs``),
  not in the default run.
- Blocks run in page order. ```bash blocks: ``bash -euo pipefail``, the venv's ``bin/``
  first on PATH (``pipeline``, ``catalog``, ``scoring``, ``python`` are Dyana's); exported
  variables and the folder a block ends in carry over to the next block. ```python blocks:
  one namespace per page, the same folder and environment. ```text (and any other) blocks
  are output and are not run.
- A failure names the page and the line of the block's opening fence, with the output.
- Markers, an HTML comment on the line right before the fence:
  ``<!-- docs-test: slow -->`` (runs only under ``pytest -m slow``, in a second test of the
  page that runs every block), ``<!-- docs-test: needs MODULE -->`` (skipped when MODULE is
  not importable), ``<!-- docs-test: skip REASON -->`` (never run; each is a skipped test
  in every run's summary, with its reason). Any other marker, or one not right before a
  bash/python fence, fails test_markers_are_well_formed.
- ``<!-- docs-setup: COMMAND -->`` anywhere on a page: a bash command run before the
  page's blocks. Processes a block or setup command leaves in the background are ended
  with the page.
- ``pipeline build --slice ...`` with the same flags as an earlier one in the session
  (``--out`` and ``--quiet`` aside) copies that build's folder instead of building again
  (build_cache.py): prefer README command 1's build when a page needs a slice.
"""

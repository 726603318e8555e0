"""The paper's published online-evaluation rows (Table 3: policy models; Table 4: VLMs),
for ``scoring eval --paper``: shown beside a run's rows, never mixed into its numbers.

Values are transcribed from the paper's tables (test-1k on the authors' Unity suite);
S_hold and S_grasp_contact are Dyana's own metrics, so the paper has no value for them.
"""

from __future__ import annotations

from dataclasses import dataclass

from scoring.registry import metric_names, registered


def table_metrics() -> tuple[str, ...]:
    """The paper's Table 3 columns: the registered metrics marked ``in_paper``, in order."""
    return tuple(m.name for m in registered() if m.in_paper)


@dataclass(frozen=True)
class PaperRow:
    """One published row: its label, the table it comes from and its metrics."""

    label: str
    table: int
    values: tuple[float, ...]

    def __post_init__(self) -> None:
        if len(self.values) != len(table_metrics()):
            raise ValueError(f"paper row {self.label!r} needs {len(table_metrics())} values, got {len(self.values)}")

    @property
    def metrics(self) -> dict[str, float | None]:
        """The row in the tables' metric order; metrics the paper does not report are None."""
        given = dict(zip(table_metrics(), self.values))
        return {name: given.get(name) for name in metric_names()}


PAPER_ROWS = (
    PaperRow("GT", 3, (100.00, 0.16, 100.00, 0.09, 0.81, 0.96, 0.16)),
    PaperRow("OpenVLA (7B)", 3, (9.25, 3.26, 37.20, 2.85, 0.54, 0.71, 0.04)),
    PaperRow("UP-VLA (1.6B)", 3, (22.60, 0.84, 41.60, 0.75, 0.47, 0.38, 0.13)),
    PaperRow("GR00T-N1.5 (2.7B)", 3, (22.04, 0.91, 79.00, 0.68, 0.28, 0.26, 0.09)),
    PaperRow("SmolVLA (500M)", 3, (8.30, 2.14, 47.00, 1.72, 0.54, 0.11, 0.05)),
    PaperRow("Qwen-VL-Max", 4, (15.00, 0.91, 80.00, 0.80, 0.38, 0.35, 0.01)),
    PaperRow("Qwen3-VL (235B)", 4, (30.00, 0.96, 16.00, 0.79, 0.78, 0.85, 0.05)),
    PaperRow("Seed-1.6", 4, (23.00, 0.66, 81.00, 0.55, 0.32, 0.31, 0.02)),
    PaperRow("GPT-4o", 4, (32.00, 0.85, 53.00, 0.72, 0.28, 0.40, 0.05)),
)


def paper_label(row: PaperRow) -> str:
    return f"paper T{row.table}: {row.label}"

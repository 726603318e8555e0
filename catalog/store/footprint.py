"""Expected disk size of a slice: its frame and episode counts times the bytes per frame (and per
episode) measured on a sample of it (``catalog/store/footprint.json``, written by
``benchmarks/footprint.py``). An estimate: JPEG sizes vary with what each frame shows."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

FOOTPRINT_PATH = Path(__file__).with_name("footprint.json")


@dataclass(frozen=True)
class Footprint:
    """Expected bytes of a slice's tables (``parquet`` = frames + episodes) and of its MCAP."""

    parquet: int
    mcap: int

    @property
    def total(self) -> int:
        return self.parquet + self.mcap


def _measured() -> dict[str, dict[str, float]]:
    return json.loads(FOOTPRINT_PATH.read_text())["slices"]


def expected_footprint(parts: dict[str, tuple[int, int]]) -> Footprint | None:
    """The footprint of the slices ``{name: (episodes, frames)}`` together (a union's parts);
    None when one of them was not measured (a slice added since the file was written)."""
    measured = _measured()
    if not set(parts) <= set(measured):
        return None
    parquet = mcap = 0.0
    for name, (episodes, frames) in parts.items():
        row = measured[name]
        parquet += frames * row["frames_bytes_per_frame"] + episodes * row["episodes_bytes_per_episode"]
        mcap += frames * row["mcap_bytes_per_frame"]
    return Footprint(round(parquet), round(mcap))



def footprint_at(name: str, episodes: int, frames: int, resolution: int) -> Footprint | None:
    """:func:`expected_footprint` of one slice's ``episodes`` and ``frames`` built at
    ``resolution``; None at another resolution than the one measured (JPEG sizes do not
    scale simply) or for a slice not measured."""
    if resolution != json.loads(FOOTPRINT_PATH.read_text())["resolution"]:
        return None
    return expected_footprint({name: (episodes, frames)})

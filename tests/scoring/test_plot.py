"""The radar's families: many runs drawn as a few series readable at a column's width."""

from __future__ import annotations

from scoring.cli import main
from scoring.plot import envelope
from tests.scoring.rollouts import Ep, png_size, write_run
from tests.scoring.test_cli import GOOD, MISS


def test_a_familys_envelope_is_its_best_and_worst_member_per_axis_outward_better():
    best, worst = envelope([{"S_loc": 90.0, "E_loc": 0.5, "R_time": None}, {"S_loc": 10.0, "E_loc": 0.1, "R_time": None}])
    assert (best["S_loc"], worst["S_loc"]) == (90.0, 10.0)
    assert (best["E_loc"], worst["E_loc"]) == (0.1, 0.5), "an error is better when lower"
    assert best["R_time"] is None and worst["R_time"] is None, "no member has it: a gap, not a 0"


def test_families_shorten_the_legend_and_bad_ones_are_refused_in_one_line(tmp_path, capsys):
    runs = [write_run(tmp_path / name, [Ep(**GOOD), Ep(**MISS)], policy=name) for name in ("chase", "still", "predictive")]
    plain, grouped = tmp_path / "plain.png", tmp_path / "grouped.png"
    assert main(["eval", *map(str, runs), "--plot", str(plain)]) == 0
    assert main(["eval", *map(str, runs), "--plot", str(grouped), "--family", "scripted", str(runs[0]), str(runs[1])]) == 0
    capsys.readouterr()
    assert all(900 <= png_size(path)[0] <= 1200 for path in (plain, grouped)), "3.5 in at 300 dpi"
    assert grouped.read_bytes() != plain.read_bytes()

    bad = [
        (["--family", "scripted", str(tmp_path / "other")], "is not one of the runs scored"),
        (["--family", "a", str(runs[0]), "--family", "b", str(runs[0])], "is already in family a"),
        (["--family", "lonely"], "name the runs it holds"),
    ]
    for extra, message in bad:
        out_png = tmp_path / "x.png"
        assert main(["eval", *map(str, runs), "--plot", str(out_png), *extra]) == 2
        out, err = capsys.readouterr()
        assert message in err and err.count("\n") == 1 and out == ""
        assert not out_png.exists(), "refused before any output"
    assert main(["eval", str(runs[0]), "--family", "x", str(runs[0])]) == 2
    assert "give --plot" in capsys.readouterr().err

"""``tpnet sim run|show`` (tpnet_ref.cli.sim): files written exactly where asked, one-line errors."""
from __future__ import annotations

import numpy as np
import pytest

from tpnet_ref.cli import main


def test_cli_run_and_show(tmp_path):
    out = tmp_path / "t.npy"
    assert main(["sim", "run", "--steps", "20", "-o", str(out)]) == 0
    assert np.load(out).shape == (20, 30, 2)
    pytest.importorskip("matplotlib")
    png = tmp_path / "t.png"
    assert main(["sim", "show", "--steps", "40", "-o", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["sim", "run", "--steps", "0", "-o", str(out)]) == 2


def test_run_refuses_another_suffix_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "x.txt"
    assert main(["sim", "run", "--steps", "5", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and ".npy" in err and "--output" in err
    assert list(tmp_path.iterdir()) == []


def test_run_missing_directory_is_one_line_naming_it(tmp_path, capsys):
    missing = tmp_path / "nonexistent" / "dir"
    assert main(["sim", "run", "--steps", "5", "-o", str(missing / "x.npy")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(missing) in err


def test_run_reports_the_path_it_wrote(tmp_path, capsys):
    out = tmp_path / "T.NPY"
    assert main(["sim", "run", "--steps", "3", "-o", str(out)]) == 0
    assert str(out) in capsys.readouterr().out
    assert [p.name for p in tmp_path.iterdir()] == ["T.NPY"]
    assert np.load(out).shape == (3, 30, 2)


def test_impulse_point_flag_selects_the_convention(tmp_path):
    from tpnet_ref.sim import simulate
    out = tmp_path / "c.npy"
    args = ["sim", "run", "--steps", "200", "--x", "39.5", "--y", "29.5", "-o", str(out)]
    assert main(args + ["--impulse-point", "particle_centre"]) == 0
    np.testing.assert_array_equal(
        np.load(out), simulate(1.3, 225.0, 39.5, 29.5, 200, impulse_point="particle_centre"))
    assert main(args) == 0
    np.testing.assert_array_equal(np.load(out), simulate(1.3, 225.0, 39.5, 29.5, 200))

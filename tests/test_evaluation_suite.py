"""tpnet eval (tpnet_ref.evaluation.suite and tpnet_ref.cli.evaluation) end to end on small inputs.
"""
from __future__ import annotations

import argparse

import numpy as np
import pytest

pytest.importorskip("h5py")

from tpnet_ref import evaluation as E  # noqa: E402
from tpnet_ref.cli import main  # noqa: E402
from evaluation_helpers import HAS_MPL, small_model, weights_file  # noqa: E402,F401


def test_eval_cli_small(weights_file, tmp_path, capsys):
    out = tmp_path / "docs"
    args = ["eval", "--weights", weights_file, "--cases", "2", "--horizon", "3", "--out", str(out),
            "--no-timing", "--quiet"]
    if not HAS_MPL:
        args.append("--no-plots")
    assert main(args) == 0
    text = (out / "results.md").read_text()
    assert "TP-Net small_m4.h5" in text and "E_p @3" in text and "descending_y" in text
    assert f"`tpnet eval --weights {weights_file} --cases 2 --horizon 3 --out {out}`" in text
    assert "No weights given" not in text
    printed = capsys.readouterr().out
    assert printed.startswith("## The paper's table, side by side")     # no stray fragment
    assert "## Which reading the paper's table is" in printed and f"wrote {out}" in printed
    if HAS_MPL:
        assert {p.name for p in out.glob("*.png")} == {"eval_error_vs_frame.png",
                                                       "eval_gallery.png", "eval_spread.png"}
    assert (out / "eval_cases.csv").is_file() and " med " in text     # every cell's spread


def test_eval_cli_needs_weights_or_baselines_only(tmp_path, capsys):
    assert main(["eval", "--out", str(tmp_path)]) == 2
    assert "--baselines-only" in capsys.readouterr().err
    assert main(["eval", "--weights", str(tmp_path / "nope.h5"), "--out", str(tmp_path)]) == 2


def test_eval_baselines_only_with_timing(tmp_path):
    pytest.importorskip("matplotlib")
    ns = argparse.Namespace(weights=[], baselines_only=True, m=None, data=None, cases=2,
                            horizon=2, orderings=list(E.ORDERINGS), no_timing=False,
                            no_peers=True, repeats=1, generalisation=True, gen_cases=1,
                            workers=1, seed=0, out=str(tmp_path), no_plots=False, quiet=True)
    path = E.run_eval(ns, command="tpnet eval --baselines-only")
    text = path.read_text()
    assert "No weights given" in text and "pymunk simulator dt x8" in text
    assert "### start near other walls" in text
    assert (tmp_path / "eval_error_vs_time.png").is_file()
    assert (tmp_path / "eval_generalisation.png").is_file()


def test_eval_from_dataset_file(tmp_path):
    from tpnet_ref.sim.dataset import generate, train_grid
    path = str(tmp_path / "d.h5")
    generate(path, train_grid(positions=1)[:1], np.asarray(E.TEST_CASES[:2]), steps=49,
             progress=False)
    base = dict(weights=[], baselines_only=True, m=[4], cases=None, horizon=3,
                orderings=["given"], no_timing=True, no_peers=True, repeats=1,
                generalisation=False, gen_cases=1, workers=1, seed=0, no_plots=True, quiet=True)
    a = E.run_eval(argparse.Namespace(data=path, out=str(tmp_path / "a"), **base), command="x")
    b = E.run_eval(argparse.Namespace(data=None, out=str(tmp_path / "b"), **dict(base, cases=2)),
                   command="x")
    ta, tb = a.read_text(), b.read_text()
    assert "test split of" in ta and "2 cases" in ta
    # the same numbers from the file (float32 positions) as simulated on the fly: E_p equal to
    # the printed digits (E_s of the baselines is ~0 and only shows the float32 rounding)
    def ep_cells(text):
        rows = text.split("## The paper's table")[1].split("## Which reading")[0].splitlines()
        return [r.split("|")[:4] for r in rows if r.startswith("| 4 |")]
    assert ep_cells(ta) == ep_cells(tb) and len(ep_cells(ta)) == 2


def test_eval_writes_a_new_directory_by_default(weights_file, tmp_path, monkeypatch, capsys):
    """Without --out, tpnet eval writes into a new ./tpnet-eval-<timestamp>/, never docs/."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "docs").mkdir()
    assert main(["eval", "--weights", weights_file, "--cases", "1", "--horizon", "2",
                 "--no-timing", "--no-plots", "--quiet", "--orderings", "given"]) == 0
    made = [p for p in tmp_path.iterdir() if p.name.startswith("tpnet-eval-")]
    assert len(made) == 1 and (made[0] / "results.md").is_file()
    assert not list((tmp_path / "docs").iterdir())


def test_eval_gallery_and_timing_use_the_m4_model(tmp_path):
    """With m = 3 given first, the gallery and the timing rows are the m = 4 model's."""
    a, b = tmp_path / "m3.h5", tmp_path / "m4.h5"
    small_model(3, seed=1, dtype="float32").save(str(a))
    small_model(4, seed=2, dtype="float32").save(str(b))
    ns = argparse.Namespace(weights=[str(a), str(b)], baselines_only=False, m=None, data=None,
                            cases=1, horizon=2, orderings=["given"], no_timing=False,
                            no_peers=True, repeats=1, generalisation=False, gen_cases=1,
                            workers=1, seed=0, out=str(tmp_path / "o"), no_plots=True,
                            quiet=True, calibration_trajectories=1)
    text = E.run_eval(ns, command="x").read_text()
    assert "| TP-Net m4.h5 NumPy float32 |" in text and "m3.h5 NumPy" not in text
    assert "m = 4, ordering `given`" in text
    # the scene-specialised row is on by default (ns has no no_specialized), calibrated as asked
    assert "| TP-Net m4.h5 NumPy float32, scene-specialised |" in text
    assert "windows of 1 simulated training-grid trajectories" in text


def test_eval_cli_no_specialized_and_calibration_flags(weights_file, tmp_path, capsys,
                                                       monkeypatch):
    from tpnet_ref.cli import evaluation as cli_eval
    from tpnet_ref.evaluation.timing import CALIBRATION_TRAJECTORIES
    assert cli_eval._CALIBRATION_TRAJECTORIES == CALIBRATION_TRAJECTORIES   # --help's default
    base = ["eval", "--weights", weights_file, "--cases", "1", "--horizon", "2", "--no-peers",
            "--repeats", "1", "--no-plots", "--quiet", "--orderings", "given"]
    assert main(base + ["--out", str(tmp_path / "a"), "--no-specialized"]) == 0
    text = (tmp_path / "a" / "results.md").read_text()
    assert "| TP-Net small_m4.h5 NumPy float32 |" in text and "scene-specialised" not in text
    assert main(base + ["--out", str(tmp_path / "b"), "--calibration-trajectories", "0"]) == 2
    assert "--calibration-trajectories: must be >= 1" in capsys.readouterr().err
    ns = argparse.Namespace(weights=["w.h5"], baselines_only=False, data=None, cases=None,
                            horizon=None, generalisation=False, no_specialized=True,
                            calibration_trajectories=3, out="o", m=None)
    monkeypatch.setattr("sys.argv", ["pytest"])                    # rebuilt from ns
    assert E.command_line(ns).endswith("--no-specialized --calibration-trajectories 3 --out o")

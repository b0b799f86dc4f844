"""Model selection without the test cases: baselines, rollout scores and spacing on validation
data; the train CLI."""
from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import tpnet_ref  # noqa: E402
from tpnet_ref import cli  # noqa: E402
from tpnet_ref.training import loop as L  # noqa: E402
from tpnet_ref.training import native_export as NE  # noqa: E402
from tpnet_ref.training import recipe as R  # noqa: E402
from tpnet_ref.training import score as S  # noqa: E402
from training_helpers import dataset, tiny_recipe  # noqa: E402,F401


def test_baselines_and_cli(dataset, tmp_path, capsys):
    data = R.WindowData(dataset, 0.2, 0)
    b = S.baselines(data)
    assert set(b) == {"copy_last", "const_velocity"}
    assert all(np.isfinite(v["val_loss"]) and v["val_loss"] > 0 for v in b.values())
    run = str(tmp_path / "run")
    out = str(tmp_path / "w.h5")
    assert cli.main(["train", "run", dataset, "-o", run, "--size", "tiny", "--epochs", "1",
                     "--batch", "32", "--threads", "1", "--quiet", "--export", out]) == 0
    assert tpnet_ref.load(out).config == R.size_config("tiny")
    assert cli.main(["train", "run", dataset, "-o", run, "--resume", "--epochs", "2",
                     "--quiet"]) == 0
    assert cli.main(["train", "export", run, str(tmp_path / "w2.h5")]) == 0
    assert "(done)" in capsys.readouterr().out
    args = cli.build_parser().parse_args(["train", "bench", "--size", "tiny", "--rollouts", "1"])
    assert callable(args.func) and (args.size, args.rollouts, args.batch) == ("tiny", [1], 128)
    assert cli.main(["train", "export", str(tmp_path / "missing"), out]) == 2


def test_score_rollouts_on_validation_trajectories(dataset, tmp_path, capsys):
    """`tpnet train score`: the test protocol on the validation trajectories (never the test
    cases), for weights files and both baselines; copy last scored as computed directly."""
    from tpnet_ref.evaluation import copy_last
    from tpnet_ref.metrics import position_error

    L.train(dataset, tmp_path / "run", tiny_recipe(epochs=1), threads=1, progress=False)
    NE.export(tmp_path / "run", tmp_path / "w.h5")
    data = R.WindowData(dataset, 0.2, 0)
    res = S.score_rollouts(data, [tmp_path / "w.h5"], horizon=10, at=(1, 10))
    assert set(res) == {"copy last", "constant velocity", str(tmp_path / "w.h5")}
    f = data.frames[data.val_traj].astype(np.float64)
    want = position_error(f[:, 4 + 9], copy_last(f[:, :4], 10)[:, 9], variant="released").mean()
    assert res["copy last"]["Ep@10"] == pytest.approx(want, rel=1e-12)
    assert all(np.isfinite(v) for row in res.values() for v in row.values())
    both = S.score_rollouts(data, [tmp_path / "w.h5"], horizon=10, at=(10,),
                            readings=("released", "squared"))
    want_sq = position_error(f[:, 4 + 9], copy_last(f[:, :4], 10)[:, 9], variant="squared").mean()
    assert both["copy last"]["Ep@10 squared"] == pytest.approx(want_sq, rel=1e-12)
    assert both["copy last"]["Ep@10"] == res["copy last"]["Ep@10"]
    with pytest.raises(ValueError, match="readings"):
        S.score_rollouts(data, [], horizon=10, at=(10,), readings=("cubed",))
    assert cli.main(["train", "score", dataset, str(tmp_path / "w.h5"), "--horizon", "10",
                     "--val-fraction", "0.2", "--reading", "squared"]) == 0
    assert f"{want_sq:9.3f}" in capsys.readouterr().out
    assert cli.main(["train", "score", dataset, str(tmp_path / "w.h5"), "--horizon", "10",
                     "--val-fraction", "0.2"]) == 0
    out = capsys.readouterr().out
    assert "Es@10" in out and "copy last" in out and "Ep@40" not in out
    sp = S.spacing_report(data, [tmp_path / "w.h5"], every=1)
    assert set(sp) == {"truth", str(tmp_path / "w.h5")}
    assert sp["truth"]["nn_mean"] == pytest.approx(0.418, abs=0.02)   # a ring, barely deformed
    assert cli.main(["train", "score", dataset, str(tmp_path / "w.h5"), "--horizon", "10",
                     "--val-fraction", "0.2", "--spacing"]) == 0
    assert "nn_min" in capsys.readouterr().out


def test_spacing_stats_of_the_rest_ring_and_of_a_clump():
    from tpnet_ref.evaluation import spacing_stats
    from tpnet_ref.config import NORM_HI, NORM_LO

    a = 2 * np.pi * np.arange(30) / 30
    r = 2.0 / (NORM_HI - NORM_LO)
    ring = np.stack([0.5 + r * np.sin(a), 0.5 + r * np.cos(a)], axis=-1)
    st = spacing_stats(ring[None])
    spacing = 2 * 2.0 * np.sin(np.pi / 30)                              # chord, world units
    assert st["nn_mean"] == pytest.approx(spacing, rel=1e-12)
    assert st["nn_min"] == pytest.approx(spacing, rel=1e-12)
    assert st["radius_std"] == pytest.approx(0.0, abs=1e-12)
    clumped = ring.copy()
    clumped[1] = clumped[0]                                             # two on one particle
    st = spacing_stats(np.stack([ring, clumped]))
    assert st["nn_min"] == pytest.approx(spacing / 2, rel=1e-12)        # mean of 0.418 and 0
    with pytest.raises(ValueError, match="sets"):
        spacing_stats(ring)


def test_recipe_curves_summary_gives_each_runs_mean_and_range():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "tools" / "recipe_curves.py"
    spec = importlib.util.spec_from_file_location("recipe_curves", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    rows = [{"run": "a", "step": s, "Ep@40 squared": e40, "Ep@80 squared": e80,
             "Es@80 squared": 0.01, "val_cd8": None if s == 3 else 2.0}
            for s, e40, e80 in ((1, 4.0, 10.0), (2, 8.0, 20.0), (3, 6.0, 3.0))]
    rows.append({"run": "b", "step": 7, "Ep@40 squared": 1.0, "Ep@80 squared": 2.0,
                 "Es@80 squared": 0.5, "val_cd8": 1.5})
    lines = mod.summary(rows, "squared").splitlines()
    assert lines[0].startswith("| run | snapshots (steps) | Ep@40 squared")
    assert lines[2] == "| a | 3 (1-3) | 6 [4, 8] | 11 [3, 20] | 0.01 [0.01, 0.01] | 2 [2, 2] |"
    assert lines[3] == "| b | 1 (7-7) | 1 [1, 1] | 2 [2, 2] | 0.5 [0.5, 0.5] | 1.5 [1.5, 1.5] |"


def test_recipe_curves_fit_finds_the_power_law_and_where_it_meets_a_target():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "tools" / "recipe_curves.py"
    spec = importlib.util.spec_from_file_location("recipe_curves", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    # E = 100 * w^-0.5: 1.0 at 10^4 windows; the first snapshot is left out by first_step
    rows = [{"run": "a", "step": i, "windows_seen": w, "Ep@80 squared": 100 * w ** -0.5}
            for i, w in enumerate((10.0, 100.0, 1e3, 1e4 / 4, 1e4 / 2))]
    rows[0]["Ep@80 squared"] = 1e9
    out = mod.fit(rows, "a", "squared", {"Ep@80": 1.0}, {"cpu": 10.0}, first_step=1)
    assert "windows^-0.50" in out and "1.0 at 0.0 M windows" in out
    assert "0.3 h at cpu" in out                     # 10^4 windows at 10 windows/s: 1,000 s
    flat = [{**r, "Ep@80 squared": 5.0 + r["step"]} for r in rows]
    assert "not falling" in mod.fit(flat, "a", "squared", {"Ep@80": 1.0}, {}, 1)
    assert "too few" in mod.fit(rows[:2], "a", "squared", {"Ep@80": 1.0}, {}, 1)

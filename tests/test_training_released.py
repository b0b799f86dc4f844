"""The authors' recipe as released: the released preprocessing's windows, Keras
initialisation, the ``--preset released`` options, and the dead units logged with validation."""
from __future__ import annotations

import argparse
import json
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tpnet_ref.sim import dataset as D  # noqa: E402
from tpnet_ref.config import NORM_HI, NORM_LO  # noqa: E402
from tpnet_ref.training import recipe as R  # noqa: E402


@pytest.fixture(scope="module")
def released(tmp_path_factory):
    """6 short trajectories (160 rows) with every row kept and the released windows; 1 whole."""
    path = tmp_path_factory.mktemp("data") / "released.h5"
    grid = D.train_grid([1.3], [200.0, 245.0], positions=3)
    D.generate(str(path), grid, None, m=4, steps=160, seed=0, whole=1, progress=False,
               windows="released")
    return str(path)


def _rows(n_rows=200, near=()):
    """``(n_rows, 30, 2)`` normalised rows in the middle of the box; rows in ``near`` put one
    particle 0.1 world units from the left wall's particle-centre bound."""
    rows = np.full((n_rows, 30, 2), 0.5)
    for r in near:
        rows[r, 7, 0] = 0.1 / (NORM_HI - NORM_LO)
    return rows


def test_released_windows_start_at_any_row_and_judge_collision_by_the_first_frame():
    rows = _rows(200, near=range(40, 60))
    w = D.released_windows(rows, np.random.default_rng(0), m=4)
    n_starts = 200 - 11 * 4
    starts, kinds = w[:, 0], w[:, 1]
    assert (starts >= 0).all() and (starts < n_starts).all()
    assert (kinds == D.KIND_NORMAL).sum() == 5
    coll = starts[kinds == D.KIND_COLLISION]
    # collision windows: exactly the starts whose FIRST frame is near a wall, none also normal
    assert len(coll) >= 10 and set(coll) <= set(range(40, 60))
    assert not set(coll) & set(starts[kinds == D.KIND_NORMAL])
    # rows near the wall only after the first frame do not make a collision window
    late = _rows(200, near=[4])         # row 4 is the 2nd frame of the window starting at row 0
    w = D.released_windows(late, np.random.default_rng(0), m=4)
    assert 0 not in w[w[:, 1] == D.KIND_COLLISION, 0]
    # 0.2 world units is the bound: 0.25 is not near
    far = _rows(200)
    far[10:20, 3, 1] = 1 - 0.25 / (NORM_HI - NORM_LO)
    assert (D.released_windows(far, np.random.default_rng(0), m=4)[:, 1] != D.KIND_COLLISION).all()
    whole = D.released_windows(rows, np.random.default_rng(0), m=4, whole=True)
    assert np.array_equal(whole[:, 0], np.arange(n_starts))
    assert (whole[:, 1] == D.KIND_WHOLE).all()
    with pytest.raises(ValueError, match="shorter than a window"):
        D.released_windows(_rows(44), np.random.default_rng(0), m=4)


def test_a_released_file_keeps_every_row_and_the_same_model_frames(released):
    import h5py

    with h5py.File(released, "r") as h:
        g = h["train"]
        assert h.attrs["windows"] == "released"
        rows, frames = g["rows"][...], g["normalized"][...]
        assert rows.shape[:2] == (6, 160)
        assert np.array_equal(rows[:, ::4], frames)
        win, model_win = g["windows_released"][...], g["windows"][...]
    whole_traj = np.unique(model_win[model_win[:, 2] == D.KIND_WHOLE, 0])
    assert np.array_equal(np.unique(win[win[:, 2] == D.KIND_WHOLE, 0]), whole_traj)
    # a whole trajectory gives every row start and nothing else
    t = whole_traj[0]
    assert np.array_equal(win[win[:, 0] == t, 1], np.arange(160 - 44))
    assert set(np.unique(win[:, 0])) == set(range(6))
    # a file made with the other window mode is not resumed into this one
    with pytest.raises(ValueError, match="windows"):
        D.generate(released, D.train_grid([1.3], [200.0, 245.0], positions=3), None, m=4,
                   steps=160, seed=0, whole=1, progress=False)


def test_released_windows_gather_rows_four_apart_and_validate_on_the_model_windows(released):
    rel = R.WindowData(released, 0.2, 0, windows="released")
    mod = R.WindowData(released, 0.2, 0)
    assert np.array_equal(rel.val_traj, mod.val_traj)
    assert not np.isin(rel.train_win[:, 0], rel.val_traj).any()
    # the validation windows are the model-frame windows of the same trajectories
    xr, yr = rel.gather(rel.val_win)
    xm, ym = mod.gather(mod.val_win)
    assert np.array_equal(xr, xm) and np.array_equal(yr, ym)
    w = rel.train_win[rel.train_win[:, 1] % 4 != 0][:3]
    assert len(w)
    x, y = rel.gather(w)
    for i, (t, s, _) in enumerate(w):
        assert np.array_equal(x[i], rel.rows[t, s:s + 16:4])
        assert np.array_equal(y[i], rel.rows[t, s + 16:s + 48:4])
    with pytest.raises(ValueError, match="--windows released"):
        from training_helpers import dataset  # noqa: F401 (the fixture's file has no rows)
        R.WindowData(_model_only(released), 0.2, 0, windows="released")


def _model_only(path):
    import shutil
    import tempfile

    import h5py

    out = tempfile.mktemp(suffix=".h5")
    shutil.copy(path, out)
    with h5py.File(out, "r+") as h:
        del h["train/rows"], h["train/windows_released"]
    return out


def test_keras_initialisation_is_the_released_codes():
    from tpnet_ref.training.torch_model import BiLSTM, TorchTPNet, init_keras

    torch.manual_seed(0)
    net = TorchTPNet(R.size_config("quarter"))
    init_keras(net)
    # glorot-uniform: bound sqrt(6 / (fan_in + fan_out)); the first per-point layer is a
    # (1, 2) Conv2D, so its fan_out is 16 * 2
    # (a uniform sample's largest |w| is above 3/4 of the bound but for a chance of 0.75^n)
    def bound(w, fi, fo):
        a = math.sqrt(6 / (fi + fo))
        top = float(w.detach().abs().max())
        return 0.75 * a < top <= a

    first = net.mlp1[0]
    assert bound(first.weight, 2, 16 * 2)   # a Dense's fans (2, 16) would draw up to 0.58
    for lin in [*net.mlp1[1:], *net.mlp2, net.global_fc, net.head]:
        assert bound(lin.weight, lin.in_features, lin.out_features)
        assert float(lin.bias.detach().abs().max()) == 0.0
    for mod in net.modules():
        if isinstance(mod, BiLSTM):
            u = mod.units
            for sfx in ("_l0", "_l0_reverse"):
                w_hh = getattr(mod, "weight_hh" + sfx).detach()
                # the whole (u, 4u) Keras matrix has orthonormal rows
                assert torch.allclose(w_hh.T @ w_hh, torch.eye(u), atol=1e-5)
                b = getattr(mod, "bias_ih" + sfx).detach()
                assert (b[u:2 * u] == 1).all() and (b[:u] == 0).all() and (b[2 * u:] == 0).all()
                assert (getattr(mod, "bias_hh" + sfx) == 0).all()
                w_ih = getattr(mod, "weight_ih" + sfx)
                assert bound(w_ih, w_ih.shape[1], 4 * u)


def test_the_released_preset_fills_the_options_left_at_their_defaults():
    from tpnet_ref.cli import build_parser

    def parse(*extra):
        args = build_parser().parse_args(["train", "run", "d.h5", "-o", "r", *extra])
        from tpnet_ref.cli.train import apply_preset
        apply_preset(args)
        return args

    a = parse("--preset", "released")
    assert (a.recipe, a.init, a.windows, a.schedule, a.clip, a.warmup_steps, a.match_weight,
            a.lr, a.batch) == ("paper", "keras", "released", "constant", 0.0, 0, 0.0, 1e-3, 128)
    b = parse("--preset", "released", "--lr", "5e-4", "--clip", "3")
    assert (b.lr, b.clip, b.init) == (5e-4, 3.0, "keras")
    c = parse()
    assert (c.init, c.windows, c.schedule) == ("torch", "model", "cosine")
    # a value given explicitly wins also when it equals the parser's default (200, 10, 'cosine')
    d = parse("--preset", "released", "--warmup-steps", "200", "--clip", "10",
              "--schedule", "cosine", "--init", "torch")
    assert (d.warmup_steps, d.clip, d.schedule, d.init, d.lr) == (200, 10.0, "cosine", "torch",
                                                                  1e-3)
    assert isinstance(a, argparse.Namespace)


@pytest.fixture(scope="module")
def long_grid(tmp_path_factory):
    """4 trajectories of 344 rows (86 frames: the protocol's 4 + 80 fit) to score snapshots on."""
    path = tmp_path_factory.mktemp("data") / "long.h5"
    D.generate(str(path), D.train_grid([1.3], [200.0, 245.0], positions=2), None, m=4,
               steps=344, seed=1, whole=1, progress=False)
    return str(path)


def test_a_released_run_trains_and_logs_dead_units(released, long_grid, tmp_path):
    from tpnet_ref import cli

    run = tmp_path / "run"
    assert cli.main(["train", "run", released, "-o", str(run), "--preset", "released",
                     "--size", "tiny", "--epochs", "1", "--batch", "16", "--val-fraction", "0.2", "--threads",
                     "1", "--val-every", "2", "--snapshots", "--quiet"]) == 0
    st = json.loads((run / "checkpoint.json").read_text())
    assert st["recipe"]["init"] == "keras" and st["recipe"]["windows"] == "released"
    vals = [json.loads(s) for s in (run / "log.jsonl").read_text().splitlines()]
    vals = [v for v in vals if v["kind"] == "val"]
    assert len(vals) >= 2
    dead = vals[-1]["dead"]
    for layer in ("mlp1.0", "mlp1.1", "mlp2.2", "global", "lstm1", "lstm3"):
        assert 0 <= dead[layer] <= dead[layer + "/of"]
    assert dead["global/of"] == 8 and dead["lstm1/of"] == 16
    snaps = sorted(p.name for p in (run / "snapshots").iterdir())
    assert snaps and snaps[0] == "step-0000002.h5"
    from tpnet_ref import load
    assert load(run / "snapshots" / snaps[-1]).config.lstm_units == (8, 8, 8)
    # --best: the snapshot of the lowest validation loss, as the released train.py ships
    by_step = {v["step"]: v["val_loss"] for v in vals}
    best = min((s for s in snaps), key=lambda s: by_step[int(s[5:12])])
    assert cli.main(["train", "export", str(run), str(tmp_path / "best.h5"), "--best"]) == 0
    assert (tmp_path / "best.h5").read_bytes() == (run / "snapshots" / best).read_bytes()
    # --monitor ep80: the snapshot of the lowest validation E_p@80 (squared), scores cached
    from tpnet_ref.training.recipe import WindowData
    from tpnet_ref.training.score import score_rollouts
    direct = score_rollouts(WindowData(long_grid, 0.05, 0),
                            [run / "snapshots" / s for s in snaps], readings=("squared",))
    ep80 = min(snaps, key=lambda s: (direct[str(run / "snapshots" / s)]["Ep@80 squared"], s))
    assert cli.main(["train", "export", str(run), str(tmp_path / "e.h5"), "--best", "--monitor",
                     "ep80", "--data", long_grid]) == 0
    assert (tmp_path / "e.h5").read_bytes() == (run / "snapshots" / ep80).read_bytes()
    cache = json.loads((run / "snapshots" / "scores.json").read_text())
    assert set(snaps) | {"copy last"} == set(cache)
    assert cli.main(["train", "export", str(run), str(tmp_path / "e2.h5"), "--best", "--monitor",
                     "ep80"]) == 2                       # a rollout score needs --data
    (run / "log.jsonl").write_text("")
    assert cli.main(["train", "export", str(run), str(tmp_path / "b2.h5"), "--best"]) == 2


def test_dead_units_counts_a_layer_that_is_off_everywhere():
    from tpnet_ref.training.torch_model import TorchTPNet
    from tpnet_ref.training.loop import dead_units

    torch.manual_seed(0)
    net = TorchTPNet(R.size_config("tiny"))
    x = torch.rand(5, 4, 30, 2)
    before = dead_units(net, x)
    with torch.no_grad():
        net.global_fc.bias.fill_(-1e3)          # every global unit off for every frame
        net.mlp2[0].bias[:3] = -1e3             # three per-point units off at every point
    after = dead_units(net, x)
    assert after["global"] == after["global/of"] == 8
    assert after["mlp2.0"] >= 3 and after["mlp2.0"] >= before["mlp2.0"]


def test_a_run_that_ends_between_validations_is_validated_and_snapshotted_at_its_end(released,
                                                                                      tmp_path):
    from tpnet_ref import cli

    run = tmp_path / "run"
    assert cli.main(["train", "run", released, "-o", str(run), "--preset", "released",
                     "--size", "tiny", "--epochs", "0.55", "--batch", "16", "--val-fraction",
                     "0.2", "--threads", "1", "--val-every", "4", "--snapshots", "--quiet"]) == 0
    st = json.loads((run / "checkpoint.json").read_text())
    last, spe = st["step"], st["steps_per_epoch"]
    assert st["stopped"] == "done" and last % 4 and last % spe     # ends between validations
    vals = [json.loads(s) for s in (run / "log.jsonl").read_text().splitlines()]
    steps = [v["step"] for v in vals if v["kind"] == "val"]
    assert steps[-1] == last and steps.count(last) == 1
    assert (run / "snapshots" / f"step-{last:07d}.h5").is_file()
    # resuming a finished run adds nothing
    assert cli.main(["train", "run", released, "-o", str(run), "--resume", "--quiet"]) == 0
    assert len((run / "log.jsonl").read_text().splitlines()) == len(vals)

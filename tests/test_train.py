"""Training (tpnet_ref.train): loss goes down, resume == uninterrupted run, export, CLI."""
from __future__ import annotations

import dataclasses
import json

import h5py
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tpnet_ref import cli  # noqa: E402
from tpnet_ref import data as D  # noqa: E402
from tpnet_ref import train as T  # noqa: E402
from tpnet_ref.training.torch_model import TorchTPNet  # noqa: E402
from tpnet_ref.weights import load_native  # noqa: E402


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """6 short trajectories (120 rows = 30 frames), 20 windows each, no test cases."""
    path = tmp_path_factory.mktemp("data") / "tiny.h5"
    grid = D.train_grid([1.3], [200.0, 245.0], positions=3)
    D.generate(str(path), grid, None, m=4, steps=120, seed=0, progress=False)
    return str(path)


def _recipe(**kw):
    base = dict(recipe="paper", epochs=2, batch=16, lr=3e-3, warmup_steps=2, clip=10.0,
                val_fraction=0.2, seed=3, config=T.size_config("tiny").to_dict())
    return T.Recipe(**{**base, **kw})


def _params(run_dir):
    payload, _ = T.load_checkpoint(run_dir)
    return {k: v for k, v in payload["model"].items() if k != "_extra_state"}


def test_loss_decreases_on_fixed_batch(dataset, tmp_path):
    r = _recipe(epochs=4, schedule="constant")
    data = T.WindowData(dataset, r.val_fraction, r.split_seed)
    x, y = (torch.from_numpy(a) for a in data.gather(data.train_win[:32]))
    torch.manual_seed(r.seed)
    net = TorchTPNet(r.tpnet_config)            # what train() starts from (same seed)
    with torch.no_grad():
        before = float(T.loss_fn(net, x, y, 8, 9.0))
    st = T.train(dataset, tmp_path / "run", r, threads=1, progress=False)
    assert st["stopped"] == "done" and st["step"] == st["total_steps"] == 4 * st["steps_per_epoch"]
    net.load_state_dict(T.load_checkpoint(tmp_path / "run")[0]["model"])
    with torch.no_grad():
        after = float(T.loss_fn(net, x, y, 8, 9.0))
    assert after < 0.9 * before, (before, after)
    log = [json.loads(s) for s in (tmp_path / "run" / T.LOG_NAME).read_text().splitlines()]
    val = [rec for rec in log if rec["kind"] == "val"]
    assert val[0]["step"] == 0 and len(val) == 5
    assert val[-1]["val_loss"] < val[0]["val_loss"]


def test_resume_gives_the_uninterrupted_run(dataset, tmp_path):
    """Stop mid-epoch, resume in a fresh call: parameters bit-identical to one straight run
    (curriculum rollout lengths, cosine schedule and input noise all exercised)."""
    r = _recipe(recipe="curriculum", epochs=3, pretrain_epochs=0.5, ramp_epochs=1.5,
                noise=0.01, schedule="cosine")
    a = T.train(dataset, tmp_path / "a", r, threads=1, progress=False, val_every=4)
    b1 = T.train(dataset, tmp_path / "b", r, threads=1, progress=False, max_steps=7, val_every=4)
    assert b1["stopped"] == "max_steps" and b1["step"] == 7
    with pytest.raises(ValueError, match="already holds a run"):
        T.train(dataset, tmp_path / "b", r, threads=1, progress=False)
    with open(tmp_path / "b" / T.LOG_NAME, "a") as f:     # a record written after the checkpoint
        f.write(json.dumps({"kind": "train", "step": 9, "loss": 1.0}) + "\n")
    b2 = T.train(dataset, tmp_path / "b", resume=True, threads=1, progress=False)
    assert b2["step"] == a["step"] and b2["windows_seen"] == a["windows_seen"]

    def log(run):
        return [(d["kind"], d["step"]) for d in map(json.loads, (run / T.LOG_NAME).open())]
    # stale record dropped on resume; the resumed run keeps validating every 4 steps
    assert log(tmp_path / "b") == log(tmp_path / "a")
    assert ("val", 12) in log(tmp_path / "b")
    pa, pb = _params(tmp_path / "a"), _params(tmp_path / "b")
    assert pa.keys() == pb.keys()
    for k in pa:
        assert torch.equal(pa[k], pb[k]), k
    oa = T.load_checkpoint(tmp_path / "a")[0]["optimizer"]["state"]
    ob = T.load_checkpoint(tmp_path / "b")[0]["optimizer"]["state"]
    for k in oa:
        assert torch.equal(oa[k]["exp_avg_sq"], ob[k]["exp_avg_sq"])


def test_export_roundtrip(dataset, tmp_path):
    r = _recipe(epochs=1)
    T.train(dataset, tmp_path / "run", r, threads=1, progress=False)
    out = tmp_path / "w.h5"
    T.export(tmp_path / "run", out)
    model = load_native(out)
    net = TorchTPNet(model.config)
    net.load_state_dict(T.load_checkpoint(tmp_path / "run")[0]["model"])
    data = T.WindowData(dataset, r.val_fraction, r.split_seed)
    x, _ = data.gather(data.val_win[:8])
    with torch.no_grad():
        yt = net(torch.from_numpy(x)).numpy()
        rt = net.rollout(torch.from_numpy(x[:1]), 8).numpy()[0]
    assert np.abs(model.predict_batch(x, normalized=True) - yt).max() <= 1e-5
    assert np.abs(model.rollout(x[0], 8, normalized=True) - rt).max() <= 1e-5
    with h5py.File(out, "r") as f:
        a = f.attrs
        assert json.loads(a["recipe"])["recipe"] == "paper"
        assert int(a["windows_seen"]) == int(a["training_steps"]) * 16 > 0
        assert float(a["epochs"]) == 1.0 and "cpu" in str(a["hardware"])
        assert float(a["export_max_abs_diff"]) <= 1e-5


def test_recipe_schedules():
    r = T.Recipe(recipe="curriculum", pretrain_epochs=2, ramp_epochs=4, warmup_steps=10,
                 lr=1e-3, lr_min=1e-5)
    ks = [r.steps_at(e / 4) for e in range(0, 32)]
    assert ks[:8] == [1] * 8 and ks[-1] == 8 and ks == sorted(ks) and set(ks) == set(range(1, 9))
    assert T.Recipe(recipe="paper").steps_at(0.0) == 8
    assert r.lr_at(0, 1000) == pytest.approx(1e-4)
    assert r.lr_at(10, 1000) == pytest.approx(1e-3, rel=1e-3)
    assert r.lr_at(999, 1000) == pytest.approx(1e-5)
    with pytest.raises(ValueError):
        T.Recipe(recipe="nope")
    assert T.Recipe.from_dict(json.loads(json.dumps(dataclasses.asdict(r)))) == r


def test_baselines_and_cli(dataset, tmp_path, capsys):
    data = T.WindowData(dataset, 0.2, 0)
    b = T.baselines(data)
    assert set(b) == {"copy_last", "const_velocity"}
    assert all(np.isfinite(v["val_loss"]) and v["val_loss"] > 0 for v in b.values())
    run = str(tmp_path / "run")
    out = str(tmp_path / "w.h5")
    assert cli.main(["train", "run", dataset, "-o", run, "--size", "tiny", "--epochs", "1",
                     "--batch", "32", "--threads", "1", "--quiet", "--export", out]) == 0
    assert load_native(out).config == T.size_config("tiny")
    assert cli.main(["train", "run", dataset, "-o", run, "--resume", "--epochs", "2",
                     "--quiet"]) == 0
    assert cli.main(["train", "export", run, str(tmp_path / "w2.h5")]) == 0
    assert "(done)" in capsys.readouterr().out
    args = cli.build_parser().parse_args(["train", "bench", "--size", "tiny", "--rollouts", "1"])
    assert args.func is T._cli_bench and args.batch == 128
    assert cli.main(["train", "export", str(tmp_path / "missing"), out]) == 2


def test_sigterm_stops_with_a_checkpoint(dataset, tmp_path):
    """SIGTERM (what `timeout` sends) ends the run after the current step, resumable."""
    import os
    import signal
    import threading

    r = _recipe(epochs=10_000)
    before = signal.getsignal(signal.SIGTERM)
    timer = threading.Timer(1.0, os.kill, (os.getpid(), signal.SIGTERM))
    timer.start()
    try:
        st = T.train(dataset, tmp_path / "run", r, threads=1, progress=False)
    finally:
        timer.cancel()
    assert st["stopped"] == "interrupted" and 0 < st["step"] < st["total_steps"]
    assert signal.getsignal(signal.SIGTERM) is before       # handlers restored
    st2 = T.train(dataset, tmp_path / "run", resume=True, threads=1, progress=False,
                  max_steps=st["step"] + 2)
    assert st2["step"] == st["step"] + 2 and st2["stopped"] == "max_steps"


def test_template_head_init_outputs_a_ring_of_the_body_size(dataset):
    """--head-init template: before any step the network's output is (close to) a ring of the
    rest radius around the data's mean position, whatever the input."""
    r = _recipe(head_init="template")
    data = T.WindowData(dataset, r.val_fraction, r.split_seed)
    torch.manual_seed(0)
    net = TorchTPNet(r.tpnet_config)
    T.init_head_template(net, data)
    x, _ = data.gather(data.train_win[:8])
    with torch.no_grad():
        y = net(torch.from_numpy(x)).numpy().astype(np.float64)        # (8, 30, 2)
    f0 = data.frames[:, 0].astype(np.float64)
    radius = np.linalg.norm(f0 - f0.mean(1, keepdims=True), axis=-1).mean()
    c = y.mean(1, keepdims=True)
    r_out = np.linalg.norm(y - c, axis=-1)
    assert abs(r_out.mean() - radius) < 0.25 * radius                   # a ring of the body's size
    assert np.median(np.abs(r_out / radius - 1)) < 0.5                  # ... not a few stray points
    mean_pos = data.frames.reshape(-1, 2).mean(0)
    assert np.abs(c[:, 0] - mean_pos).max() < 0.05                        # near the data's middle
    # the default initialisation gives no such ring
    torch.manual_seed(0)
    plain = TorchTPNet(r.tpnet_config)
    with torch.no_grad():
        yp = plain(torch.from_numpy(x)).numpy()
    rp = np.linalg.norm(yp - yp.mean(1, keepdims=True), axis=-1)
    assert abs(rp.mean() - radius) > 0.5 * radius


def test_fractional_epochs_rollout_and_validation_subset(dataset, tmp_path, capsys):
    """--epochs may be fractional (total = round(epochs * steps/epoch)), --rollout caps the
    recursive loss, --val-windows validates on an evenly spaced subset; all kept on resume."""
    run = tmp_path / "run"
    args = ["train", "run", dataset, "-o", str(run), "--size", "tiny", "--batch", "16",
            "--epochs", "1.5", "--pretrain-epochs", "0.5", "--ramp-epochs", "0.5",
            "--rollout", "3", "--val-windows", "5", "--head-init", "template", "--threads", "1",
            "--quiet", "--val-fraction", "0.2"]
    assert cli.main(args) == 0
    st = json.loads((run / T.SIDECAR_NAME).read_text())
    spe = st["steps_per_epoch"]
    assert st["total_steps"] == round(1.5 * spe) and st["step"] == st["total_steps"]
    assert st["recipe"]["rollout"] == 3 and st["recipe"]["head_init"] == "template"
    assert st["val_windows_used"] == 5
    log = [json.loads(s) for s in (run / T.LOG_NAME).read_text().splitlines()]
    assert max(rec.get("rollout", 0) for rec in log) == 3
    assert "val_cd3" in log[0]
    r = T.Recipe.from_dict(st["recipe"])
    assert [r.steps_at(e) for e in (0.0, 0.49, 0.5, 0.7, 0.9, 1.2)] == [1, 1, 1, 2, 3, 3]
    with pytest.raises(ValueError, match="head_init"):
        _recipe(head_init="zeros")
    with pytest.raises(ValueError, match="epochs"):
        _recipe(epochs=0)


def test_init_from_fine_tunes_a_run_and_carries_its_provenance(dataset, tmp_path):
    """--init-from starts a new run (own recipe, fresh Adam) from another run's weights; the
    exported file counts the training of the whole chain; a different network is refused."""
    parent = tmp_path / "parent"
    T.train(dataset, parent, _recipe(epochs=1), threads=1, progress=False)
    child = tmp_path / "child"
    args = ["train", "run", dataset, "-o", str(child), "--init-from", str(parent),
            "--recipe", "paper", "--rollout", "2", "--batch", "16", "--epochs", "1",
            "--lr", "1e-9", "--schedule", "constant", "--warmup-steps", "0", "--threads", "1",
            "--quiet",
            "--val-fraction", "0.2"]
    assert cli.main(args) == 0                  # --size is not given: the parent's network is used
    pa, ch = _params(parent), _params(child)
    assert pa.keys() == ch.keys()
    for k in pa:                                # lr 1e-9: the child's weights are the parent's
        np.testing.assert_allclose(ch[k].numpy(), pa[k].numpy(), atol=1e-6, err_msg=k)
    pst = json.loads((parent / T.SIDECAR_NAME).read_text())
    cst = json.loads((child / T.SIDECAR_NAME).read_text())
    assert cst["inherited"]["windows_seen"] == pst["windows_seen"]
    assert cst["recipe"]["init_from"] == str(parent) and cst["recipe"]["rollout"] == 2
    T.export(child, tmp_path / "w.h5")
    model = load_native(tmp_path / "w.h5")
    assert model.meta["windows_seen"] == pst["windows_seen"] + cst["windows_seen"]
    assert model.meta["training_steps"] == pst["step"] + cst["step"]
    assert json.loads(model.meta["parent_runs"])[0]["run"] == str(parent)
    with pytest.raises(ValueError, match="differs"):
        T.train(dataset, tmp_path / "bad", _recipe(init_from=str(parent),
                                                   config=T.size_config("small").to_dict()),
                threads=1, progress=False)


def test_init_from_a_native_weights_file_carries_its_provenance(dataset, tmp_path):
    """--init-from also takes a native weights file (the shipped model is fine-tuned this way):
    the run starts from exactly its parameters and the export adds the file's training counts."""
    parent = tmp_path / "parent"
    T.train(dataset, parent, _recipe(epochs=1), threads=1, progress=False)
    T.export(parent, tmp_path / "parent.h5")
    pmeta = load_native(tmp_path / "parent.h5").meta
    child = tmp_path / "child"
    r = _recipe(epochs=1, init_from=str(tmp_path / "parent.h5"), lr=1e-12, schedule="constant",
                warmup_steps=0)
    T.train(dataset, child, r, threads=1, progress=False)
    # the same function (the native format holds one LSTM bias, so torch's two are re-split)
    nets = []
    for run in (parent, child):
        net = TorchTPNet(r.tpnet_config)
        net.load_state_dict(T.load_checkpoint(run)[0]["model"])
        nets.append(net.eval())
    data = T.WindowData(dataset, r.val_fraction, r.split_seed)
    x = torch.from_numpy(data.gather(data.train_win[:8])[0])
    with torch.no_grad():
        np.testing.assert_allclose(nets[1](x).numpy(), nets[0](x).numpy(), atol=1e-6)
    cst = json.loads((child / T.SIDECAR_NAME).read_text())
    T.export(child, tmp_path / "child.h5")
    meta = load_native(tmp_path / "child.h5").meta
    assert meta["windows_seen"] == pmeta["windows_seen"] + cst["windows_seen"]
    assert meta["training_steps"] == pmeta["training_steps"] + cst["step"]
    assert meta["epochs"] == pytest.approx(pmeta["epochs"] + 1.0)
    chain = json.loads(meta["parent_runs"])
    assert chain[0]["recipe"]["weights_file"] == str(tmp_path / "parent.h5")
    with pytest.raises(ValueError, match="differs"):
        T.train(dataset, tmp_path / "bad", _recipe(init_from=str(tmp_path / "parent.h5"),
                                                   config=T.size_config("small").to_dict()),
                threads=1, progress=False)


def test_init_from_a_model_of_another_window_length(dataset, tmp_path):
    """The m = 3 and m = 5 models start from the m = 4 weights: no weight depends on m, so
    --init-from accepts a parent of another window length and the child's network takes the
    dataset's m (the same parameters, run over 3 frames)."""
    parent = tmp_path / "parent"
    T.train(dataset, parent, _recipe(epochs=1), threads=1, progress=False)
    T.export(parent, tmp_path / "parent.h5")
    data3 = tmp_path / "m3.h5"
    D.generate(str(data3), D.train_grid([1.3], [200.0, 245.0], positions=3), None, m=3,
               steps=120, seed=0, progress=False)
    child = tmp_path / "child"
    args = ["train", "run", str(data3), "-o", str(child), "--init-from", str(tmp_path / "parent.h5"),
            "--rollout", "2", "--batch", "16", "--epochs", "1", "--lr", "1e-12",
            "--schedule", "constant", "--warmup-steps", "0", "--threads", "1", "--quiet",
            "--val-fraction", "0.2"]
    assert cli.main(args) == 0
    cst = json.loads((child / T.SIDECAR_NAME).read_text())
    assert cst["recipe"]["config"]["m"] == 3
    T.export(child, tmp_path / "child.h5")
    m3, m4 = load_native(tmp_path / "child.h5"), load_native(tmp_path / "parent.h5")
    assert (m3.config.m, m4.config.m) == (3, 4)
    assert m3.params.keys() == m4.params.keys()
    for k in m4.params:                          # lr 1e-12: the parent's parameters
        np.testing.assert_allclose(m3.params[k], m4.params[k], atol=1e-6, err_msg=k)
    w = np.random.default_rng(0).uniform(0.3, 0.7, (4, 30, 2))
    assert m3.predict(w[1:]).shape == (30, 2)
    with pytest.raises(ValueError):              # the child's network wants 3 frames
        m3.predict(w)
    other = T.size_config("small", m=3).to_dict()
    with pytest.raises(ValueError, match="differs"):   # another size is still refused
        T.train(str(data3), tmp_path / "bad", _recipe(init_from=str(tmp_path / "parent.h5"),
                                                      config=other), threads=1, progress=False)


def test_shape_term_is_the_released_shape_error_and_is_optimised(dataset, tmp_path):
    """--shape-weight λ adds λ·Σ w_i·E_s (released shape error of the centred sets): the torch
    term equals tpnet_ref.metrics.shape_error, is invariant to translating either set, and the
    run logs val_es1 / val_esK."""
    from tpnet_ref.metrics import shape_error
    from tpnet_ref.training.torch_model import chamfer_shape

    rng = np.random.default_rng(0)
    p, q = rng.uniform(0, 1, (5, 3, 30, 2)), rng.uniform(0, 1, (5, 3, 27, 2))
    ours = chamfer_shape(torch.from_numpy(p), torch.from_numpy(q)).numpy()
    ref = np.asarray(shape_error(q, p, variant="released")).mean(0)
    np.testing.assert_allclose(ours, ref, rtol=1e-10)
    shifted = chamfer_shape(torch.from_numpy(p + 0.3), torch.from_numpy(q - 0.1)).numpy()
    np.testing.assert_allclose(shifted, ours, rtol=1e-10)

    r = _recipe(epochs=1, shape_weight=2.0, rollout=3)
    data = T.WindowData(dataset, r.val_fraction, r.split_seed)
    x, y = (torch.from_numpy(a) for a in data.gather(data.train_win[:8]))
    net = TorchTPNet(r.tpnet_config)
    with torch.no_grad():
        plain = float(T.loss_fn(net, x, y, 3, 9.0))
        both = float(T.loss_fn(net, x, y, 3, 9.0, 2.0))
        es = chamfer_shape(net.rollout(x, 3), y[:, :3]).numpy()
    assert both == pytest.approx(plain + 2.0 * float(es @ np.array([9.0, 1.0, 1.0])), rel=1e-5)
    T.train(dataset, tmp_path / "run", r, threads=1, progress=False)
    log = [json.loads(s) for s in (tmp_path / "run" / T.LOG_NAME).read_text().splitlines()]
    assert {"val_es1", "val_es3", "val_cd1", "val_cd3"} <= set(log[0])
    with pytest.raises(ValueError, match="shape_weight"):
        _recipe(shape_weight=-1.0)


def test_score_rollouts_on_validation_trajectories(dataset, tmp_path, capsys):
    """`tpnet train score`: the test protocol on the validation trajectories (never the test
    cases), for weights files and both baselines; copy last scored as computed directly."""
    from tpnet_ref.evaluation import copy_last
    from tpnet_ref.metrics import position_error

    T.train(dataset, tmp_path / "run", _recipe(epochs=1), threads=1, progress=False)
    T.export(tmp_path / "run", tmp_path / "w.h5")
    data = T.WindowData(dataset, 0.2, 0)
    res = T.score_rollouts(data, [tmp_path / "w.h5"], horizon=10, at=(1, 10))
    assert set(res) == {"copy last", "constant velocity", str(tmp_path / "w.h5")}
    f = data.frames[data.val_traj].astype(np.float64)
    want = position_error(f[:, 4 + 9], copy_last(f[:, :4], 10)[:, 9], variant="released").mean()
    assert res["copy last"]["Ep@10"] == pytest.approx(want, rel=1e-12)
    assert all(np.isfinite(v) for row in res.values() for v in row.values())
    assert cli.main(["train", "score", dataset, str(tmp_path / "w.h5"), "--horizon", "10",
                     "--val-fraction", "0.2"]) == 0
    out = capsys.readouterr().out
    assert "Es@10" in out and "copy last" in out and "Ep@40" not in out
    sp = T.spacing_report(data, [tmp_path / "w.h5"], every=1)
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


def test_budget_minutes_sets_the_run_length_from_measured_throughput(dataset, tmp_path,
                                                                    monkeypatch):
    calls = []

    def fake_bench(cfg, *, batch, rollouts, **kw):       # 100 windows/s, whatever the machine
        calls.append((batch, rollouts))
        return {rollouts[0]: 100.0}

    monkeypatch.setattr(T, "bench", fake_bench)
    r = _recipe(epochs=50, rollout=3)
    st = T.train(dataset, tmp_path / "run", r, threads=1, progress=False, budget_minutes=0.05)
    assert calls == [(16, (3,))]                         # the recipe's batch and longest loss
    spe = st["steps_per_epoch"]
    want = 0.9 * 0.05 * 60 * 100.0 / (spe * 16)          # 90 % of the budget at that rate
    assert st["budget"] == {"minutes": 0.05, "bench_windows_per_s": 100.0, "epochs": want}
    assert st["recipe"]["epochs"] == want and st["total_steps"] == round(want * spe)
    assert st["stopped"] == "done" and st["step"] == st["total_steps"]
    with pytest.raises(ValueError, match="budget_minutes"):
        T.train(dataset, tmp_path / "run2", _recipe(), threads=1, progress=False,
                budget_minutes=0)


def test_matched_distance_is_the_optimal_bijection_and_penalises_clumping():
    import itertools

    from tpnet_ref.training.torch_model import chamfer_released, matched_distance

    g = torch.Generator().manual_seed(0)
    p = torch.rand(4, 2, 6, 2, generator=g, dtype=torch.float64)
    q = torch.rand(4, 2, 6, 2, generator=g, dtype=torch.float64)
    got = matched_distance(p, q)
    assert got.shape == (2,)
    for s in range(2):
        brute = [2 * min(sum(float(torch.linalg.norm(p[b, s, k] - q[b, s, perm[k]]))
                             for k in range(6)) for perm in itertools.permutations(range(6)))
                 for b in range(4)]
        assert float(got[s]) == pytest.approx(np.mean(brute), rel=1e-12)
    assert (got >= chamfer_released(p, q) - 1e-12).all()       # Chamfer pairs need not be 1:1
    # two predictions on one target, one target uncovered: Chamfer sees half of the gap,
    # the matched distance all of it; the gradient moves a duplicate towards the free target
    ring = torch.tensor([[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]], dtype=torch.float64)
    clump = torch.tensor([[[0.0, 0.0], [1.0, 0.0], [1.0, 0.0]]], dtype=torch.float64,
                         requires_grad=True)
    assert float(chamfer_released(clump.detach(), ring)) == pytest.approx(1.0)
    em = matched_distance(clump, ring)
    assert float(em.detach()) == pytest.approx(2.0)
    em.backward()
    assert float(clump.grad[0, 1:, 0].min()) < 0                # one duplicate pushed to x = 2
    with pytest.raises(ValueError, match="equal shape"):
        matched_distance(p[:, :, :5], q)


def test_match_term_trains_and_is_stored_in_the_recipe(dataset, tmp_path):
    st = T.train(dataset, tmp_path / "run", _recipe(epochs=1, match_weight=2.0, rollout=2),
                 threads=1, progress=False)
    assert st["stopped"] == "done" and st["recipe"]["match_weight"] == 2.0
    with pytest.raises(ValueError, match="match_weight"):
        _recipe(match_weight=-1.0)

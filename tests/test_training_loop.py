"""The training loop: the loss goes down, export round trip, fractional epochs, budgets, the match
term."""
from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

torch = pytest.importorskip("torch")

import tpnet_ref  # noqa: E402
from tpnet_ref import cli  # noqa: E402
from tpnet_ref.training import checkpoint as C  # noqa: E402
from tpnet_ref.training import loop as L  # noqa: E402
from tpnet_ref.training import native_export as NE  # noqa: E402
from tpnet_ref.training import step as ST  # noqa: E402
from tpnet_ref.training import recipe as R  # noqa: E402
from tpnet_ref.training.torch_model import TorchTPNet  # noqa: E402
from training_helpers import dataset, tiny_recipe  # noqa: E402,F401


def test_loss_decreases_on_fixed_batch(dataset, tmp_path):
    r = tiny_recipe(epochs=4, schedule="constant")
    data = R.WindowData(dataset, r.val_fraction, r.split_seed)
    x, y = (torch.from_numpy(a) for a in data.gather(data.train_win[:32]))
    torch.manual_seed(r.seed)
    net = TorchTPNet(r.tpnet_config)            # what train() starts from (same seed)
    with torch.no_grad():
        before = float(ST.loss_fn(net, x, y, 8, 9.0))
    st = L.train(dataset, tmp_path / "run", r, threads=1, progress=False)
    assert st["stopped"] == "done" and st["step"] == st["total_steps"] == 4 * st["steps_per_epoch"]
    net.load_state_dict(C.load_checkpoint(tmp_path / "run")[0]["model"])
    with torch.no_grad():
        after = float(ST.loss_fn(net, x, y, 8, 9.0))
    assert after < 0.9 * before, (before, after)
    log = [json.loads(s) for s in (tmp_path / "run" / L.LOG_NAME).read_text().splitlines()]
    val = [rec for rec in log if rec["kind"] == "val"]
    assert val[0]["step"] == 0 and len(val) == 5
    assert val[-1]["val_loss"] < val[0]["val_loss"]


def test_export_roundtrip(dataset, tmp_path):
    r = tiny_recipe(epochs=1)
    L.train(dataset, tmp_path / "run", r, threads=1, progress=False)
    out = tmp_path / "w.h5"
    NE.export(tmp_path / "run", out)
    model = tpnet_ref.load(out)
    net = TorchTPNet(model.config)
    net.load_state_dict(C.load_checkpoint(tmp_path / "run")[0]["model"])
    data = R.WindowData(dataset, r.val_fraction, r.split_seed)
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


def test_fractional_epochs_rollout_and_validation_subset(dataset, tmp_path, capsys):
    """--epochs may be fractional (total = round(epochs * steps/epoch)), --rollout caps the
    recursive loss, --val-windows validates on an evenly spaced subset; all kept on resume."""
    run = tmp_path / "run"
    args = ["train", "run", dataset, "-o", str(run), "--size", "tiny", "--batch", "16",
            "--epochs", "1.5", "--pretrain-epochs", "0.5", "--ramp-epochs", "0.5",
            "--rollout", "3", "--val-windows", "5", "--head-init", "template", "--threads", "1",
            "--quiet", "--val-fraction", "0.2"]
    assert cli.main(args) == 0
    st = json.loads((run / C.SIDECAR_NAME).read_text())
    spe = st["steps_per_epoch"]
    assert st["total_steps"] == round(1.5 * spe) and st["step"] == st["total_steps"]
    assert st["recipe"]["rollout"] == 3 and st["recipe"]["head_init"] == "template"
    assert st["val_windows_used"] == 5
    log = [json.loads(s) for s in (run / L.LOG_NAME).read_text().splitlines()]
    assert max(rec.get("rollout", 0) for rec in log) == 3
    assert "val_cd3" in log[0]
    r = R.Recipe.from_dict(st["recipe"])
    assert [r.steps_at(e) for e in (0.0, 0.49, 0.5, 0.7, 0.9, 1.2)] == [1, 1, 1, 2, 3, 3]
    with pytest.raises(ValueError, match="head_init"):
        tiny_recipe(head_init="zeros")
    with pytest.raises(ValueError, match="epochs"):
        tiny_recipe(epochs=0)


def test_budget_minutes_sets_the_run_length_from_measured_throughput(dataset, tmp_path,
                                                                    monkeypatch):
    calls = []

    def fake_bench(cfg, *, batch, rollouts, **kw):       # 100 windows/s, whatever the machine
        calls.append((batch, rollouts))
        return {rollouts[0]: 100.0}

    monkeypatch.setattr(L, "bench", fake_bench)         # what the loop times the budget with
    r = tiny_recipe(epochs=50, rollout=3)
    st = L.train(dataset, tmp_path / "run", r, threads=1, progress=False, budget_minutes=0.05)
    assert calls == [(16, (3,))]                         # the recipe's batch and longest loss
    spe = st["steps_per_epoch"]
    want = 0.9 * 0.05 * 60 * 100.0 / (spe * 16)          # 90 % of the budget at that rate
    assert st["budget"] == {"minutes": 0.05, "bench_windows_per_s": 100.0, "epochs": want}
    assert st["recipe"]["epochs"] == want and st["total_steps"] == round(want * spe)
    assert st["stopped"] == "done" and st["step"] == st["total_steps"]
    with pytest.raises(ValueError, match="budget_minutes"):
        L.train(dataset, tmp_path / "run2", tiny_recipe(), threads=1, progress=False,
                budget_minutes=0)


def test_match_term_trains_and_is_stored_in_thetiny_recipe(dataset, tmp_path):
    st = L.train(dataset, tmp_path / "run", tiny_recipe(epochs=1, match_weight=2.0, rollout=2),
                 threads=1, progress=False)
    assert st["stopped"] == "done" and st["recipe"]["match_weight"] == 2.0
    with pytest.raises(ValueError, match="match_weight"):
        tiny_recipe(match_weight=-1.0)


def test_settings_record_and_keywords_are_the_same_call(dataset, tmp_path):
    """train(..., TrainSettings(...)) and train(..., keyword=...) run the same; a keyword that
    is no setting is refused before any work."""
    s = L.TrainSettings(threads=1, progress=False, max_steps=3, log_every=1)
    a = L.train(dataset, tmp_path / "a", tiny_recipe(), s)
    b = L.train(dataset, tmp_path / "b", tiny_recipe(), threads=1, progress=False, max_steps=3,
                log_every=1)
    assert a["step"] == b["step"] == 3 and a["stopped"] == b["stopped"] == "max_steps"
    wa, wb = (C.load_checkpoint(tmp_path / n)[0]["model"] for n in "ab")
    assert all(torch.equal(wa[k], wb[k]) for k in wa if torch.is_tensor(wa[k]))
    assert s.max_steps == 3 and s.resume is False          # the caller's record is not changed
    c = L.train(dataset, tmp_path / "a", settings=s, resume=True, max_steps=4)
    assert c["step"] == 4
    with pytest.raises(TypeError, match="max_step"):
        L.train(dataset, tmp_path / "c", tiny_recipe(), s, max_step=5)
    assert not (tmp_path / "c").exists()

"""Mixed-precision training (``precision="bf16"``): what runs in bfloat16 and what stays float32,
the per-machine choice of ``auto``, the record a run keeps, and ``tpnet train bench``'s lines.
Parity of the validation loss at small scale is a measurement, not a test: docs/history.md."""
from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tpnet_ref.cli import main  # noqa: E402
from tpnet_ref.training.torch_model import TorchTPNet  # noqa: E402
from tpnet_ref.training import checkpoint as C  # noqa: E402
from tpnet_ref.training import loop as L  # noqa: E402
from tpnet_ref.training import native_export as NE  # noqa: E402
from tpnet_ref.training import precision as PR  # noqa: E402
from tpnet_ref.training import throughput as TH  # noqa: E402
from tpnet_ref.training import recipe as R  # noqa: E402
from training_helpers import dataset, tiny_recipe  # noqa: E402,F401


def _batch(cfg, b=8, k=3, seed=0):
    rng = np.random.default_rng(seed)
    x = torch.from_numpy(rng.uniform(0.2, 0.8, (b, cfg.m, cfg.n_out, cfg.dim)).astype(np.float32))
    y = torch.from_numpy(rng.uniform(0.2, 0.8, (b, k, cfg.n_out, cfg.dim)).astype(np.float32))
    return x, y


def test_bf16_step_keeps_coordinates_loss_and_gradients_in_float32():
    cfg = R.size_config("small")
    torch.manual_seed(0)
    net = TorchTPNet(cfg)
    x, y = _batch(cfg)
    with PR.autocast("bf16", "cpu"):
        pred = net.rollout(x, 3)
        feats = net.frame_features(x.reshape(-1, cfg.n_out, cfg.dim))
    assert pred.dtype == torch.float32          # the head writes coordinates in float32
    assert feats.dtype == torch.bfloat16        # ... while the products run in bfloat16
    f32 = PR.step_loss(net, "off", "float32")(x, y, 3, 9.0, 4.0, 0.0)
    bf = PR.step_loss(net, "off", "bf16")(x, y, 3, 9.0, 4.0, 0.0)
    assert bf.dtype == torch.float32 and torch.isfinite(bf)
    lb, lf = float(bf.detach()), float(f32.detach())
    assert abs(lb - lf) <= 0.02 * abs(lf), (lb, lf)
    assert lb != lf                             # bf16 did run: the products were rounded
    bf.backward()
    assert all(p.grad.dtype == torch.float32 for p in net.parameters() if p.grad is not None)


def test_bf16_gradient_points_where_float32_does():
    cfg = R.size_config("small")
    torch.manual_seed(1)
    net = TorchTPNet(cfg)
    x, y = _batch(cfg, seed=1)
    grads = {}
    for p in ("float32", "bf16"):
        net.zero_grad(set_to_none=True)
        PR.step_loss(net, "off", p)(x, y, 3, 9.0, 0.0, 0.0).backward()
        grads[p] = torch.cat([q.grad.flatten() for q in net.parameters() if q.grad is not None])
    cos = torch.nn.functional.cosine_similarity(grads["float32"], grads["bf16"], dim=0)
    assert float(cos) > 0.98, float(cos)


def test_auto_takes_bf16_only_when_it_is_clearly_faster(monkeypatch):
    rates = {}

    def fake_bench(cfg, *, batch, rollouts, precision, **kw):
        return {rollouts[0]: rates[precision]}

    monkeypatch.setattr(TH, "bench", fake_bench)
    cfg = R.size_config("tiny")
    for f32, bf, want in ((100.0, 180.0, "bf16"), (100.0, 110.0, "float32"),
                          (100.0, 60.0, "float32"), (100.0, 115.0, "bf16")):
        rates.update(float32=f32, bf16=bf)
        got, timing = TH.choose_precision("auto", "cpu", cfg, 16, 8, 1)
        assert got == want and timing == {"float32": f32, "bf16": bf}
    assert TH.choose_precision("bf16", "cpu", cfg, 16, 8, 1) == ("bf16", {})
    assert TH.choose_precision("float32", "cpu", cfg, 16, 8, 1) == ("float32", {})
    with pytest.raises(ValueError, match="precision must be one of"):
        TH.choose_precision("fp8", "cpu", cfg, 16, 8, 1)


def test_a_bf16_run_records_its_precision_and_exports_it(dataset, tmp_path, monkeypatch):
    r = tiny_recipe(epochs=1)
    st = L.train(dataset, tmp_path / "run", r, threads=1, progress=False, precision="bf16")
    assert st["precision"] == [{"step": 0, "mode": "bf16", "timing_windows_per_s": {}}]
    log = [json.loads(s) for s in (tmp_path / "run" / L.LOG_NAME).read_text().splitlines()]
    assert all(np.isfinite(rec["loss"]) for rec in log if rec["kind"] == "train")
    # resumed in float32: both calls are on record, and in the exported file
    L.train(dataset, tmp_path / "run", None, resume=True, epochs=2, threads=1, progress=False,
            precision="float32")
    _, st2 = C.load_checkpoint(tmp_path / "run")
    assert [c["mode"] for c in st2["precision"]] == ["bf16", "float32"]
    NE.export(tmp_path / "run", tmp_path / "w.h5")
    with h5py.File(tmp_path / "w.h5", "r") as f:
        assert [c["mode"] for c in json.loads(f.attrs["precision"])] == ["bf16", "float32"]


def test_bench_prints_a_line_per_precision_and_marks_the_default(capsys):
    assert main(["train", "bench", "--size", "tiny", "--batch", "4", "--rollouts", "1", "2",
                 "--iters", "1", "--threads", "1", "--device", "cpu"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].startswith("train step throughput, size tiny, batch 4")
    body = [ln.split(":")[0].strip() for ln in lines[1:]]
    assert body == ["1-step loss, float32", "1-step loss, bf16",
                    "2-step loss, float32", "2-step loss, bf16"]
    marked = [ln for ln in lines[1:] if "(default)" in ln]
    assert len(marked) == 1 and marked[0].strip().startswith("2-step loss, float32")
    auto = [ln for ln in lines[1:] if ln.endswith("(auto)")]
    assert len(auto) == 1 and auto[0].strip().startswith("2-step loss")
    f32, bf = (float(ln.split(":")[1].split()[0]) for ln in lines[3:5])
    assert ("bf16" in auto[0]) == (bf >= PR.BF16_MIN_GAIN * f32)
    assert "x float32" in lines[4]

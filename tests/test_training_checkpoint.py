"""Checkpoints: resume equals the uninterrupted run, in one file or in parts; stop on SIGTERM;
fine-tuning provenance."""
from __future__ import annotations

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import tpnet_ref  # noqa: E402
from tpnet_ref import cli  # noqa: E402
from tpnet_ref.sim import dataset as D  # noqa: E402
from tpnet_ref.training import checkpoint as C  # noqa: E402
from tpnet_ref.training import loop as L  # noqa: E402
from tpnet_ref.training import native_export as NE  # noqa: E402
from tpnet_ref.training import recipe as R  # noqa: E402
from tpnet_ref.training.torch_model import TorchTPNet  # noqa: E402
from tpnet_ref.weights.provenance import absolute_paths, file_sha256, portable_path  # noqa: E402
from training_helpers import dataset, tiny_recipe  # noqa: E402,F401


def _params(run_dir):
    payload, _ = C.load_checkpoint(run_dir)
    return {k: v for k, v in payload["model"].items() if k != "_extra_state"}


def test_resume_gives_the_uninterrupted_run(dataset, tmp_path):
    """Stop mid-epoch, resume in a fresh call: parameters bit-identical to one straight run
    (curriculum rollout lengths, cosine schedule and input noise all exercised)."""
    r = tiny_recipe(recipe="curriculum", epochs=3, pretrain_epochs=0.5, ramp_epochs=1.5,
                noise=0.01, schedule="cosine")
    a = L.train(dataset, tmp_path / "a", r, threads=1, progress=False, val_every=4)
    b1 = L.train(dataset, tmp_path / "b", r, threads=1, progress=False, max_steps=7, val_every=4)
    assert b1["stopped"] == "max_steps" and b1["step"] == 7
    with pytest.raises(ValueError, match="already holds a run"):
        L.train(dataset, tmp_path / "b", r, threads=1, progress=False)
    with open(tmp_path / "b" / L.LOG_NAME, "a") as f:     # a record written after the checkpoint
        f.write(json.dumps({"kind": "train", "step": 9, "loss": 1.0}) + "\n")
    b2 = L.train(dataset, tmp_path / "b", resume=True, threads=1, progress=False)
    assert b2["step"] == a["step"] and b2["windows_seen"] == a["windows_seen"]

    def log(run):
        return [(d["kind"], d["step"]) for d in map(json.loads, (run / L.LOG_NAME).open())]
    # stale record dropped on resume; the resumed run keeps validating every 4 steps
    assert log(tmp_path / "b") == log(tmp_path / "a")
    assert ("val", 12) in log(tmp_path / "b")
    pa, pb = _params(tmp_path / "a"), _params(tmp_path / "b")
    assert pa.keys() == pb.keys()
    for k in pa:
        assert torch.equal(pa[k], pb[k]), k
    oa = C.load_checkpoint(tmp_path / "a")[0]["optimizer"]["state"]
    ob = C.load_checkpoint(tmp_path / "b")[0]["optimizer"]["state"]
    for k in oa:
        assert torch.equal(oa[k]["exp_avg_sq"], ob[k]["exp_avg_sq"])


def test_sigterm_stops_with_a_checkpoint(dataset, tmp_path):
    """SIGTERM (what `timeout` sends) ends the run after the current step, resumable."""
    import os
    import signal
    import threading

    r = tiny_recipe(epochs=10_000)
    before = signal.getsignal(signal.SIGTERM)
    timer = threading.Timer(1.0, os.kill, (os.getpid(), signal.SIGTERM))
    timer.start()
    try:
        st = L.train(dataset, tmp_path / "run", r, threads=1, progress=False)
    finally:
        timer.cancel()
    assert st["stopped"] == "interrupted" and 0 < st["step"] < st["total_steps"]
    assert signal.getsignal(signal.SIGTERM) is before       # handlers restored
    st2 = L.train(dataset, tmp_path / "run", resume=True, threads=1, progress=False,
                  max_steps=st["step"] + 2)
    assert st2["step"] == st["step"] + 2 and st2["stopped"] == "max_steps"


def test_init_from_fine_tunes_a_run_and_carries_its_provenance(dataset, tmp_path):
    """--init-from starts a new run (own recipe, fresh Adam) from another run's weights; the
    exported file counts the training of the whole chain; a different network is refused."""
    parent = tmp_path / "parent"
    L.train(dataset, parent, tiny_recipe(epochs=1), threads=1, progress=False)
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
    pst = json.loads((parent / C.SIDECAR_NAME).read_text())
    cst = json.loads((child / C.SIDECAR_NAME).read_text())
    assert cst["inherited"]["windows_seen"] == pst["windows_seen"]
    assert cst["recipe"]["init_from"] == str(parent) and cst["recipe"]["rollout"] == 2
    NE.export(child, tmp_path / "w.h5")
    model = tpnet_ref.load(tmp_path / "w.h5")
    assert model.meta["windows_seen"] == pst["windows_seen"] + cst["windows_seen"]
    assert model.meta["training_steps"] == pst["step"] + cst["step"]
    assert json.loads(model.meta["parent_runs"])[0]["run"] == portable_path(parent) == parent.name
    assert not [v for k, v in model.meta.items()       # "path": where it was read from now
                if k != "path" and isinstance(v, str) and absolute_paths(v)]
    assert model.meta["data_sha256"] == file_sha256(dataset)
    with pytest.raises(ValueError, match="differs"):
        L.train(dataset, tmp_path / "bad", tiny_recipe(init_from=str(parent),
                                                   config=R.size_config("small").to_dict()),
                threads=1, progress=False)


def test_init_from_a_native_weights_file_carries_its_provenance(dataset, tmp_path):
    """--init-from also takes a native weights file (the shipped model is fine-tuned this way):
    the run starts from exactly its parameters and the export adds the file's training counts."""
    parent = tmp_path / "parent"
    L.train(dataset, parent, tiny_recipe(epochs=1), threads=1, progress=False)
    NE.export(parent, tmp_path / "parent.h5")
    pmeta = tpnet_ref.load(tmp_path / "parent.h5").meta
    child = tmp_path / "child"
    r = tiny_recipe(epochs=1, init_from=str(tmp_path / "parent.h5"), lr=1e-12, schedule="constant",
                warmup_steps=0)
    L.train(dataset, child, r, threads=1, progress=False)
    # the same function (the native format holds one LSTM bias, so torch's two are re-split)
    nets = []
    for run in (parent, child):
        net = TorchTPNet(r.tpnet_config)
        net.load_state_dict(C.load_checkpoint(run)[0]["model"])
        nets.append(net.eval())
    data = R.WindowData(dataset, r.val_fraction, r.split_seed)
    x = torch.from_numpy(data.gather(data.train_win[:8])[0])
    with torch.no_grad():
        np.testing.assert_allclose(nets[1](x).numpy(), nets[0](x).numpy(), atol=1e-6)
    cst = json.loads((child / C.SIDECAR_NAME).read_text())
    NE.export(child, tmp_path / "child.h5")
    meta = tpnet_ref.load(tmp_path / "child.h5").meta
    assert meta["windows_seen"] == pmeta["windows_seen"] + cst["windows_seen"]
    assert meta["training_steps"] == pmeta["training_steps"] + cst["step"]
    assert meta["epochs"] == pytest.approx(pmeta["epochs"] + 1.0)
    chain = json.loads(meta["parent_runs"])
    assert chain[0]["recipe"]["weights_file"] == "parent.h5"        # by name: /tmp is no repo
    with pytest.raises(ValueError, match="differs"):
        L.train(dataset, tmp_path / "bad", tiny_recipe(init_from=str(tmp_path / "parent.h5"),
                                                   config=R.size_config("small").to_dict()),
                threads=1, progress=False)


def test_init_from_a_model_of_another_window_length(dataset, tmp_path):
    """The m = 3 and m = 5 models start from the m = 4 weights: no weight depends on m, so
    --init-from accepts a parent of another window length and the child's network takes the
    dataset's m (the same parameters, run over 3 frames)."""
    parent = tmp_path / "parent"
    L.train(dataset, parent, tiny_recipe(epochs=1), threads=1, progress=False)
    NE.export(parent, tmp_path / "parent.h5")
    data3 = tmp_path / "m3.h5"
    D.generate(str(data3), D.train_grid([1.3], [200.0, 245.0], positions=3), None, m=3,
               steps=120, seed=0, progress=False)
    child = tmp_path / "child"
    args = ["train", "run", str(data3), "-o", str(child), "--init-from", str(tmp_path / "parent.h5"),
            "--rollout", "2", "--batch", "16", "--epochs", "1", "--lr", "1e-12",
            "--schedule", "constant", "--warmup-steps", "0", "--threads", "1", "--quiet",
            "--val-fraction", "0.2"]
    assert cli.main(args) == 0
    cst = json.loads((child / C.SIDECAR_NAME).read_text())
    assert cst["recipe"]["config"]["m"] == 3
    NE.export(child, tmp_path / "child.h5")
    m3, m4 = tpnet_ref.load(tmp_path / "child.h5"), tpnet_ref.load(tmp_path / "parent.h5")
    assert (m3.config.m, m4.config.m) == (3, 4)
    assert m3.params.keys() == m4.params.keys()
    for k in m4.params:                          # lr 1e-12: the parent's parameters
        np.testing.assert_allclose(m3.params[k], m4.params[k], atol=1e-6, err_msg=k)
    w = np.random.default_rng(0).uniform(0.3, 0.7, (4, 30, 2))
    assert m3.predict(w[1:]).shape == (30, 2)
    with pytest.raises(ValueError):              # the child's network wants 3 frames
        m3.predict(w)
    other = R.size_config("small", m=3).to_dict()
    with pytest.raises(ValueError, match="differs"):   # another size is still refused
        L.train(str(data3), tmp_path / "bad", tiny_recipe(init_from=str(tmp_path / "parent.h5"),
                                                      config=other), threads=1, progress=False)


def test_checkpoint_in_parts_resumes_to_the_uninterrupted_run(dataset, tmp_path):
    """A run checkpointed as parts of at most 4 KiB, stopped and resumed, ends with exactly the
    parameters of the uninterrupted run; a missing or damaged part is refused by name."""
    r = tiny_recipe(epochs=2)
    L.train(dataset, tmp_path / "a", r, threads=1, progress=False)
    L.train(dataset, tmp_path / "b", r, threads=1, progress=False, max_steps=5,
            checkpoint_part_mib=4 / 1024)
    run = tmp_path / "b"
    parts = sorted(run.glob("checkpoint.pt.*"))
    assert len(parts) > 3 and not (run / "checkpoint.pt").exists()
    assert max(p.stat().st_size for p in parts) <= 4096
    st = json.loads((run / C.SIDECAR_NAME).read_text())
    assert st["checkpoint_files"]["files"] == [p.name for p in parts]
    L.train(dataset, run, resume=True, threads=1, progress=False)   # keeps writing parts
    assert not (run / "checkpoint.pt").exists()
    pa, pb = _params(tmp_path / "a"), _params(run)
    assert all(torch.equal(pa[k], pb[k]) for k in pa)
    # a run directory copied without one of its parts, or with a damaged one
    last = sorted(run.glob("checkpoint.pt.*"))[-1]
    data = last.read_bytes()
    last.write_bytes(data[:-1] + bytes([data[-1] ^ 1]))
    with pytest.raises(ValueError, match="do not match checkpoint.json"):
        C.load_checkpoint(run)
    last.unlink()
    with pytest.raises(FileNotFoundError, match="checkpoint part not found"):
        C.load_checkpoint(run)


def test_checkpoint_optimizer_modes_trade_size_for_exactness(dataset, tmp_path):
    """bf16 keeps Adam's moments in bfloat16, none keeps the model only: smaller files; a run
    resumed without optimizer state records the fresh Adam and still trains."""
    r = tiny_recipe(epochs=1)
    sizes = {}
    for mode in C.OPTIMIZER_MODES:
        run = tmp_path / mode
        L.train(dataset, run, r, threads=1, progress=False, max_steps=3, checkpoint_optimizer=mode)
        sizes[mode] = json.loads((run / C.SIDECAR_NAME).read_text())["checkpoint_files"]["bytes"]
        payload, _ = C.load_checkpoint(run)
        assert ("optimizer" in payload) == (mode != "none")
    assert sizes["none"] < sizes["bf16"] < sizes["full"]
    st = L.train(dataset, tmp_path / "none", resume=True, threads=1, progress=False)
    assert st["optimizer_resets"] == [3] and st["stopped"] == "done"
    st = L.train(dataset, tmp_path / "bf16", resume=True, threads=1, progress=False)
    assert st["stopped"] == "done" and "optimizer_resets" not in st


def test_cli_writes_parts_and_exports_from_them(dataset, tmp_path, capsys):
    run, out = str(tmp_path / "run"), str(tmp_path / "w.h5")
    assert cli.main(["train", "run", dataset, "-o", run, "--size", "tiny", "--epochs", "1",
                     "--batch", "32", "--threads", "1", "--quiet", "--max-steps", "2",
                     "--checkpoint-part-mib", "0.01", "--checkpoint-optimizer", "bf16"]) == 0
    assert len(list((tmp_path / "run").glob("checkpoint.pt.*"))) > 1
    assert cli.main(["train", "run", dataset, "-o", run, "--resume", "--quiet"]) == 0
    assert "(done)" in capsys.readouterr().out
    assert cli.main(["train", "export", run, out]) == 0
    assert tpnet_ref.load(out).config == R.size_config("tiny")


def test_pack_keeps_a_run_resumable_in_a_smaller_tarball(dataset, tmp_path, capsys):
    """`tpnet train pack`: the run's checkpoint with Adam's moments in bfloat16, its log and
    snapshot scores in one .tar.gz that unpacks into a run the loop resumes with Adam's state
    (no fresh Adam); a run that kept no Adam state cannot be packed with one."""
    import tarfile

    import torch

    run = tmp_path / "run"
    L.train(dataset, run, tiny_recipe(epochs=1), threads=1, progress=False, max_steps=3,
            checkpoint_optimizer="full")
    (run / "snapshots").mkdir()
    (run / "snapshots" / "scores.json").write_text("{}")
    out = tmp_path / "run.tar.gz"
    assert cli.main(["train", "pack", str(run), str(out)]) == 0
    assert "restore: mkdir -p DIR && tar xzf" in capsys.readouterr().out
    with tarfile.open(out) as tar:
        names = set(tar.getnames())
        tar.extractall(tmp_path / "moved", filter="data")
    assert {"run/checkpoint.json", "run/log.jsonl", "run/snapshots/scores.json"} <= names
    moved = tmp_path / "moved" / "run"
    payload, state = C.load_checkpoint(moved)
    full, _ = C.load_checkpoint(run)
    moments = [v for s in payload["optimizer"]["state"].values() for v in s.values()
               if torch.is_tensor(v) and v.dim() > 0]
    assert moments and all(v.dtype == torch.bfloat16 for v in moments)
    assert all(torch.equal(v, payload["model"][k]) if torch.is_tensor(v) else v == payload["model"][k]
               for k, v in full["model"].items())
    assert state["checkpoint_files"]["optimizer"] == "bf16"
    assert state["checkpoint_files"]["bytes"] < json.loads(
        (run / C.SIDECAR_NAME).read_text())["checkpoint_files"]["bytes"]
    st = L.train(dataset, moved, resume=True, threads=1, progress=False)
    assert st["stopped"] == "done" and "optimizer_resets" not in st

    bare = tmp_path / "bare"
    L.train(dataset, bare, tiny_recipe(epochs=1), threads=1, progress=False, max_steps=2,
            checkpoint_optimizer="none")
    with pytest.raises(ValueError, match="keeps no Adam state"):
        C.repack_checkpoint(bare, tmp_path / "x", optimizer="bf16")

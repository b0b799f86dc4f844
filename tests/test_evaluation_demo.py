"""tpnet demo (tpnet_ref.evaluation.demo): errors beside the baselines in two readings, the PNG.
"""
from __future__ import annotations


import numpy as np
import pytest

pytest.importorskip("h5py")

from tpnet_ref import evaluation as E  # noqa: E402
from tpnet_ref.cli import main  # noqa: E402
from evaluation_helpers import HAS_MPL, weights_file  # noqa: E402,F401


def test_demo_without_shipped_weights_exits_2(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("TPNET_WEIGHTS_DIR", str(tmp_path))
    monkeypatch.chdir(tmp_path)
    assert main(["demo"]) == 2
    err = capsys.readouterr().err
    assert "tpnet demo: error: no shipped weights" in err
    assert not list(tmp_path.iterdir())                   # nothing faked, nothing written


def test_demo_with_weights_prints_errors(weights_file, tmp_path, capsys):
    png = tmp_path / "demo.png"
    args = ["demo", "--weights", weights_file, "--steps", "12", "--horizons", "1", "10", "40",
            "-o", str(png)]
    if not HAS_MPL:
        args.append("--no-png")
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "shuffled" in out and "ms/frame" in out and "BLAS:" in out and "threads" in out
    for reading in ("squared", "released"):                 # both readings, in this order
        assert f'reading "{reading}"' in out
    assert out.index('reading "squared"') < out.index('reading "released"')
    assert out.count("TP-Net  copy last  const vel") == 4     # E_p and E_s, both readings
    lines = [ln.split() for ln in out.splitlines() if ln.strip()[:1].isdigit()]
    # step h -> frame m-1+h, once per reading; 3 methods x (E_p, E_s) per row
    assert [ln[:2] for ln in lines] == [["1", "4"], ["10", "13"]] * 2
    assert all(len(ln) == 8 and np.isfinite([float(x) for x in ln[2:]]).all() for ln in lines)
    if HAS_MPL:
        assert f"wrote {png}" in out
        from matplotlib.image import imread
        assert imread(png).shape[1] >= 1200                 # wide enough to read


def test_demo_returns_numbers(weights_file, tmp_path):
    import io
    text = io.StringIO()
    r = E.demo(weights_file, steps=3, horizons=(1, 3), png=None, out=text)
    assert r["m"] == 4 and r["steps"] == 3 and set(r["errors"]) == {1, 3}
    assert set(r["errors"][1]) == {"TP-Net", "copy last", "const. velocity"}
    assert r["errors"][1]["TP-Net"]["Ep_released"] > 0
    assert r["errors"][1]["TP-Net"]["Ep_squared"] > 0
    # the baselines are what tpnet_ref.sim.protocol computes on the same case
    frames = E.normalize(E.simulate_cases([E.DEMO_CASE], 4 * 7 + 1, workers=1))
    inputs, truth = E.split_protocol(frames, 4, 3)
    want = E.errors(truth, E.copy_last(inputs, 3))["Ep_squared"][0, 2]
    assert r["errors"][3]["copy last"]["Ep_squared"] == pytest.approx(want, rel=1e-9)
    assert "threads" in r["blas"] or "threadpoolctl" in r["blas"]
    # the threads the prediction ran on (the Numba engine, the default where numba is installed,
    # may run its two LSTM directions on two), and a one-thread BLAS (not the process's setting)
    said = "1 thread" if r["threads"] == 1 else "2 threads (the Numba engine's two LSTM directions)"
    assert r["threads"] in (1, 2) and f"the prediction ran on {said}" in text.getvalue()
    assert "threads 2" not in r["blas"]

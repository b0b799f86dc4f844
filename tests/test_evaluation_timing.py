"""tpnet_ref.evaluation.timing: coarse-step simulator rows and the error-against-run-time table.
"""
from __future__ import annotations


import numpy as np
import pytest

pytest.importorskip("h5py")

from tpnet_ref import evaluation as E  # noqa: E402
from evaluation_helpers import fake_curves, frames3, small_model  # noqa: E402,F401


def test_sim_coarse_indexing():
    from tpnet_ref.sim import simulate
    case = E.TEST_CASES[0]
    np.testing.assert_array_equal(E.sim_coarse(case, 1, 6), simulate(*case, 21)[::4])
    np.testing.assert_array_equal(E.sim_coarse(case, 2, 6), simulate(*case, 11, dt=2 / 45)[::2])
    rows8 = simulate(*case, 4, dt=8 / 45)
    got = E.sim_coarse(case, 8, 6)                       # a state every 2 frames
    np.testing.assert_array_equal(got[::2], rows8[:3])
    np.testing.assert_allclose(got[1], 0.5 * (rows8[0] + rows8[1]))


def test_timing_table_rows(frames3):
    model = small_model(4, dtype="float32")
    rows = E.timing_table(frames3, np.asarray(E.TEST_CASES[:3]), [E.ModelSpec("net", model)],
                          m=4, horizon=3, repeats=1, peers=True)
    names = [r.name for r in rows]
    assert names[:2] == ["net NumPy float64", "net NumPy float32"]
    assert "copy last input frame" in names and "constant velocity" in names
    assert [n for n in names if n.startswith("pymunk")] == [
        f"pymunk simulator dt x{k}" for k in (1, 2, 4, 8)]
    t = {r.name: r for r in rows}
    assert t["pymunk simulator dt x1"].err["Ep_released"].max() == 0.0   # it is the reference
    f64 = t["net NumPy float64"].err["Ep_released"]
    np.testing.assert_allclose(t["net NumPy float32"].err["Ep_released"], f64, rtol=1e-3, atol=1e-4)
    for peer in ("net PyTorch", "net onnxruntime"):
        if t[peer].err:                                   # installed: same network, same errors
            np.testing.assert_allclose(t[peer].err["Ep_released"], f64, rtol=1e-3, atol=1e-4)
            assert t[peer].ms_batch > 0
    md = E.timing_md(rows, 3)
    assert "ms/frame (batch of 3)" in md and "E_p @3" in md
    rep = E.Report(command="x", n_cases=3, horizon=3, source="s", curves=fake_curves(H=3),
                   timing=rows, models=["w.h5"])
    text = E.render_markdown(rep)
    assert "## Error against run time" in text and "Fastest here for one rollout: net" in text


def test_timing_table_scene_specialised_row(frames3):
    """The float32 network specialised on training-grid trajectories: its own row, the float32
    row's errors, a note that names the calibration and the fallbacks; off by default."""
    from tpnet_ref.evaluation.timing import CALIBRATION_ROLLOUT
    from tpnet_ref.sim.dataset import calibration_windows
    model = small_model(4, dtype="float32")
    cases = np.asarray(E.TEST_CASES[:3])
    kw = dict(m=4, horizon=3, repeats=1, peers=False, dt_factors=())
    rows = E.timing_table(frames3, cases, [E.ModelSpec("net", model)], specialized=True,
                          calibration_trajectories=2, **kw)
    t = {r.name: r for r in rows}
    names = [r.name for r in rows]
    assert names[:3] == ["net NumPy float64", "net NumPy float32",
                         "net NumPy float32, scene-specialised"]
    sp, f32 = t["net NumPy float32, scene-specialised"], t["net NumPy float32"]
    assert sp.kind == "model" and sp.ms_batch > 0 and sp.ms_single > 0
    for key, e in f32.err.items():
        np.testing.assert_allclose(sp.err[key], e, rtol=1e-4, atol=1e-6)
    n_windows = len(calibration_windows(model, 2, rollout=CALIBRATION_ROLLOUT))
    assert f"on {n_windows:,} windows of 2 simulated training-grid trajectories" in sp.note
    assert "timed windows fell back to the full network" in sp.note
    assert "max abs difference from the float32 row's predictions" in sp.note
    assert "scene-specialised" in E.timing_md(rows, 3)
    plain = E.timing_table(frames3, cases, [E.ModelSpec("net", model)], **kw)
    assert not [r for r in plain if "specialised" in r.name]


def test_eval_names_the_rows_an_extra_would_add(monkeypatch):
    """``tpnet eval`` says at its start which rows a missing extra leaves out."""
    import importlib.util

    from tpnet_ref.evaluation import timing
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name in ("torch", "onnxruntime") else real(name, *a))
    lines = timing.missing_peers()
    assert len(lines) == 2
    assert lines[0].startswith("the PyTorch rows") and "tpnet-ref[crosscheck]" in lines[0]
    assert "onnxruntime" in lines[1] and "left out of the figure" in lines[1]
    monkeypatch.setattr(importlib.util, "find_spec", real)
    assert timing.missing_peers() == [] or all("crosscheck" in ln for ln in timing.missing_peers())

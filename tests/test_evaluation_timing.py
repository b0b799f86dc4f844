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

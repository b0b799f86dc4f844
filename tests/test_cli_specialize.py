"""``tpnet specialize`` and ``tpnet sort-units`` (tpnet_ref.cli.specialize): the files they write,
where their windows come from, and one-line errors for bad paths (checked before any work)."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("h5py")

import tpnet_ref  # noqa: E402
from tpnet_ref.engines import unit_order as U  # noqa: E402
from tpnet_ref.cli import main  # noqa: E402
from tpnet_ref.model import init_random  # noqa: E402
from ring_helpers import SMALL, rings  # noqa: E402


def _rings(rng, n, m=4):
    return rings(rng, n, m, wobble=0.05)


@pytest.fixture
def small_weights(tmp_path):
    p = tmp_path / "w.h5"
    init_random(SMALL, seed=4).save(p)
    return p


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_cli_writes_a_specialised_file_and_names_bad_paths_in_one_line(tmp_path, capsys):
    src = tmp_path / "w.npy"
    np.save(src, _rings(np.random.default_rng(5), 16))
    out = tmp_path / "s.h5"
    assert main(["specialize", str(src), "-o", str(out)]) == 0
    assert tpnet_ref.load(out).specialization is not None
    capsys.readouterr()
    for argv, msg in ((["specialize", str(tmp_path / "none.npy"), "-o", str(out)], "not found"),
                      (["specialize", str(src), "-o", str(tmp_path / "no" / "s.h5")],
                       "does not exist")):
        assert main(argv) == 2
        assert msg in _one_error_line(capsys)


def test_specialize_uses_at_most_max_windows_and_says_what_it_read(tmp_path, capsys,
                                                                  small_weights):
    src = tmp_path / "w.npy"
    np.save(src, _rings(np.random.default_rng(1), 30))
    out = tmp_path / "s.h5"
    assert main(["specialize", str(src), "--weights", str(small_weights), "-o", str(out),
                 "--max-windows", "7"]) == 0
    text = capsys.readouterr().out
    assert text.startswith(f"wrote {out}: calibrated on 7 windows; units used:")
    back = tpnet_ref.load(out)
    assert back.specialization is not None
    assert int(back.meta["calibration_windows"]) == 7
    assert back.meta["specialized_from"] == small_weights.name       # no machine's path
    w = _rings(np.random.default_rng(2), 5)                # exact on any input, seen or not
    np.testing.assert_allclose(back.predict_batch(w),
                               tpnet_ref.load(small_weights).predict_batch(w), atol=1e-4)


def test_a_pickled_or_non_array_source_is_refused_in_one_line(tmp_path, capsys, small_weights):
    bad = tmp_path / "w.npy"
    np.save(bad, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    assert main(["specialize", str(bad), "--weights", str(small_weights),
                 "-o", str(tmp_path / "s.h5")]) == 2
    assert "never unpickled" in _one_error_line(capsys)
    assert not (tmp_path / "s.h5").exists()


def test_cli_sort_units_writes_the_same_network_ordered(tmp_path, capsys, small_weights):
    src, out = tmp_path / "win.npy", tmp_path / "sorted.h5"
    model = tpnet_ref.load(small_weights, dtype="float64")
    np.save(src, _rings(np.random.default_rng(6), 12))
    assert main(["sort-units", str(src), "--weights", str(small_weights), "-o", str(out)]) == 0
    assert "units sorted by use on 12 windows" in capsys.readouterr().out
    back = tpnet_ref.load(out, dtype="float64")
    assert set(back.unit_order) == set(U.sizes(SMALL))
    assert "12 windows" in back.meta["units_sorted_on"]
    for k in model.params:
        np.testing.assert_array_equal(back.params[k], model.params[k])
    w = _rings(np.random.default_rng(7), 4)
    np.testing.assert_allclose(back.predict_batch(w), model.predict_batch(w), rtol=0, atol=1e-3)
    assert main(["sort-units", str(tmp_path / "none.npy"), "-o", str(out)]) == 2
    assert "not found" in _one_error_line(capsys)


def test_sort_units_without_a_source_simulates_training_grid_windows(tmp_path, capsys,
                                                                     small_weights, monkeypatch):
    """No source: --trajectories training-grid trajectories (tpnet_ref.sim.dataset.calibration_windows,
    never the test cases); replaced here by a recording stand-in to stay fast."""
    from tpnet_ref.sim import dataset as D
    calls = []

    def fake(model, n, **kw):
        calls.append(n)
        return _rings(np.random.default_rng(3), 9)
    monkeypatch.setattr(D, "calibration_windows", fake)
    out = tmp_path / "sorted.h5"
    assert main(["sort-units", "--weights", str(small_weights), "-o", str(out),
                 "--trajectories", "3"]) == 0
    assert calls == [3]
    assert "9 windows (3 training-grid trajectories + rollouts)" in capsys.readouterr().out

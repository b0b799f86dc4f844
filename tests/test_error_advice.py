"""Every error a user can trigger through ``load``, ``predict``, ``predict_batch``, ``rollout`` and
the ``tpnet`` command that gives advice is one line, and the advice works when followed: each test
triggers the message, then does what it says."""
from __future__ import annotations

import shutil
import traceback
import warnings
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("h5py")

import tpnet_ref  # noqa: E402
from tpnet_ref.checks import (NonFiniteResultError, NotOneBodyWarning,  # noqa: E402
                              OutsideTrainingRangeWarning)
from tpnet_ref.cli import main  # noqa: E402
from tpnet_ref.weights.shipped import default_weights_path  # noqa: E402

FIX = Path(__file__).parent / "fixtures"


@pytest.fixture(scope="module")
def model():
    return tpnet_ref.load(engine="numpy")


def _window() -> np.ndarray:
    return tpnet_ref.example_window().astype(np.float64)


def _one_line(exc: BaseException) -> str:
    text = str(exc)
    assert "\n" not in text and text.strip() == text and text
    return text


def _quiet(fn, *args, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutsideTrainingRangeWarning)
        return fn(*args, **kw)


def test_float32_overflow_names_float64_and_each_form_of_its_advice_works(model):
    """A window scaled by 1e30: the float32 network overflows; every form the message names
    (predict's dtype=, load(dtype=), model.astype) computes it, and the traceback is short."""
    w = _window() * 1e30
    with pytest.raises(NonFiniteResultError) as err, warnings.catch_warnings():
        warnings.simplefilter("ignore", OutsideTrainingRangeWarning)
        tpnet_ref.predict(w, model=model)
    text = _one_line(err.value)
    for form in ("tpnet_ref.predict(window, dtype='float64')", "tpnet_ref.load(dtype='float64')",
                 "model.astype('float64')", "tpnet predict --dtype float64"):
        assert form in text
    # the user's call, tpnet_ref.predict, TPNet.predict, TPNet._split: not seven frames deep
    assert len(traceback.extract_tb(err.value.__traceback__)) <= 4
    for call in (lambda **kw: tpnet_ref.predict(w, model=model, **kw),
                 lambda **kw: tpnet_ref.predict_batch(w[None], model=model, **kw)[0],
                 lambda **kw: tpnet_ref.rollout(w, 1, model=model, **kw)[0]):
        with pytest.raises(NonFiniteResultError):
            _quiet(call)
        out = _quiet(call, dtype="float64")                         # the advice, as written
        assert out.dtype == np.float64 and np.isfinite(out).all()
    m64 = model.astype("float64")
    assert np.isfinite(_quiet(m64.predict, w)).all()
    assert np.isfinite(_quiet(tpnet_ref.load(dtype="float64", engine="numpy").predict, w)).all()


def test_float32_overflow_on_the_command_line_and_its_dtype_flag(tmp_path, capsys):
    path = tmp_path / "huge.npy"
    np.save(path, _window() * 1e30)
    assert main(["predict", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "tpnet predict --dtype float64" in err
    assert main(["predict", str(path), "--dtype", "float64"]) == 0


def test_values_beyond_float32_name_float64_and_it_works(model):
    w = _window() * 1e39                                   # finite in float64, beyond float32
    with pytest.raises(ValueError) as err:
        tpnet_ref.predict(w, model=model)
    assert "dtype='float64'" in _one_line(err.value)
    assert len(traceback.extract_tb(err.value.__traceback__)) <= 4
    assert np.isfinite(_quiet(tpnet_ref.predict, w, model=model, dtype="float64")).all()


def test_a_path_instead_of_points_says_load_it_and_both_ways_work(model, tmp_path, capsys):
    path = tmp_path / "w.npy"
    np.save(path, _window())
    with pytest.raises(TypeError) as err:
        tpnet_ref.predict(str(path), model=model)
    assert "np.load(path)" in _one_line(err.value) and "tpnet predict PATH" in str(err.value)
    assert tpnet_ref.predict(np.load(path), model=model).shape == (30, 2)
    assert main(["predict", str(path)]) == 0


def test_load_with_a_path_and_a_shipped_size_says_give_one(tmp_path):
    with pytest.raises(ValueError) as err:
        tpnet_ref.load(default_weights_path(), m=3)
    assert "give either a path or m= / size=" in _one_line(err.value)
    assert tpnet_ref.load(default_weights_path(), engine="numpy").config.m == 4
    assert tpnet_ref.load(m=4, size="quarter", engine="numpy").config.m == 4


def test_missing_shipped_weights_say_pass_a_path_or_set_the_folder(tmp_path, monkeypatch):
    monkeypatch.setenv("TPNET_WEIGHTS_DIR", str(tmp_path))
    with pytest.raises(FileNotFoundError) as err:
        tpnet_ref.load(size="quarter")
    text = _one_line(err.value)
    assert "pass the path of a weights file" in text and "TPNET_WEIGHTS_DIR" in text
    monkeypatch.delenv("TPNET_WEIGHTS_DIR")
    src = tpnet_ref.weights.shipped.shipped_weights_path(4, "quarter")
    assert tpnet_ref.load(src, engine="numpy").config.m == 4             # a path
    shutil.copy(src, tmp_path / src.name)
    monkeypatch.setenv("TPNET_WEIGHTS_DIR", str(tmp_path))               # the folder
    assert tpnet_ref.load(size="quarter", engine="numpy").config.m == 4


def test_a_framework_checkpoint_says_tpnet_import_and_that_works(tmp_path, capsys):
    src = FIX / "tf2_released_weights.h5"
    with pytest.raises(ValueError) as err:
        tpnet_ref.load(src)
    assert "`tpnet import SRC DST`" in _one_line(err.value)
    assert main(["import", str(src), str(tmp_path / "n.h5")]) == 0
    assert tpnet_ref.load(tmp_path / "n.h5", engine="numpy").config.m == 4


def test_model_coordinates_given_as_world_units_say_pass_normalized(model):
    w = model.normalize(_window())
    with pytest.warns(OutsideTrainingRangeWarning, match="pass normalized=True") as rec:
        tpnet_ref.predict(w, model=model)
    _one_line(rec[0].message)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tpnet_ref.predict(w, model=model, normalized=True)


def test_world_units_given_as_normalized_say_so(model):
    w = _window()
    with pytest.warns(OutsideTrainingRangeWarning, match="world units passed as normalized=True"):
        tpnet_ref.predict(w, model=model, normalized=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tpnet_ref.predict(w, model=model)


def test_stray_points_say_drop_outliers_and_that_cleans_them(model):
    pytest.importorskip("tpnet_ref.observe")
    from tpnet_ref.observe import drop_outliers
    w = [f for f in _window()]
    w[2] = np.concatenate([w[2], w[2].mean(axis=0, keepdims=True) + [[6.0, 0.0]]])   # a speck
    with pytest.warns(NotOneBodyWarning, match="tpnet_ref.observe.drop_outliers") as rec:
        tpnet_ref.predict(w, model=model)
    _one_line(rec[0].message)
    clean = [drop_outliers(f) for f in w]
    assert [len(f) for f in clean] == [30, 30, 30, 30]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tpnet_ref.predict(clean, model=model)


def test_an_output_without_its_suffix_says_which_and_that_works(tmp_path, capsys):
    pytest.importorskip("pymunk")
    assert main(["sim", "run", "--steps", "8", "-o", str(tmp_path / "traj.txt")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "must end in .npy" in err
    assert main(["sim", "run", "--steps", "8", "-o", str(tmp_path / "traj.npy")]) == 0
    assert np.load(tmp_path / "traj.npy").shape == (8, 30, 2)


def test_a_usage_error_points_at_help_and_help_works(capsys):
    with pytest.raises(SystemExit) as ex:
        main(["predict", "w.npy", "--dtype", "float16"])
    assert ex.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "(see tpnet predict --help)" in err
    with pytest.raises(SystemExit) as ex:
        main(["predict", "--help"])
    assert ex.value.code == 0 and "--dtype" in capsys.readouterr().out


def test_dtype_must_be_float32_or_float64(model):
    with pytest.raises(ValueError, match="'float32' or 'float64'"):
        tpnet_ref.predict(_window(), model=model, dtype="float16")


def test_frames_without_a_frame_rate_say_pass_fps_and_that_works(tmp_path, capsys):
    pytest.importorskip("pymunk")
    pytest.importorskip("cv2")
    frames = tmp_path / "frames"
    assert main(["sim", "render", "--steps", "20", "--size", "320", "-o", str(frames)]) == 0
    capsys.readouterr()
    camera = "7.111,312.9,312.9"                  # given by hand: no calibration file, no fps
    out = str(tmp_path / "w.npy")
    assert main(["observe", str(frames), "--camera", camera, "-o", out]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.endswith("frame rate unknown; pass --fps")
    assert main(["observe", str(frames), "--camera", camera, "--fps", "45", "-o", out]) == 0
    assert np.load(out).shape == (4, 30, 2)


def test_a_file_without_a_digest_says_scrub_provenance_and_that_adds_one(tmp_path, capsys):
    import h5py
    from tpnet_ref.weights.native import DIGEST_ATTR, UnverifiedFileWarning
    src, dst = tmp_path / "old.h5", tmp_path / "new.h5"
    shutil.copy(tpnet_ref.weights.shipped.shipped_weights_path(4, "quarter"), src)
    with h5py.File(src, "r+") as f:                   # as written before digests existed
        del f.attrs[DIGEST_ATTR]
    with pytest.warns(UnverifiedFileWarning, match="`tpnet scrub-provenance SRC DST`") as rec:
        tpnet_ref.load(src, engine="numpy")
    _one_line(rec[0].message)
    assert main(["scrub-provenance", str(src), str(dst)]) == 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tpnet_ref.load(dst, engine="numpy")

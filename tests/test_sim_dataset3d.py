"""The 3-D dataset (tpnet_ref.sim.dataset with dim = 3, ``tpnet data generate --dim 3``): the layout,
released windows, the validation split, resuming, and readers of either dimension refusing the
other's file in one line."""
from __future__ import annotations

import importlib.util

import numpy as np
import pytest

h5py = pytest.importorskip("h5py")

from tpnet_ref.sim import dataset as D  # noqa: E402
from tpnet_ref.cli import main  # noqa: E402
from tpnet_ref.config import normalize  # noqa: E402
from tpnet_ref.sim.cases3d import TEST_CASES3D, TRAIN_POSITIONS3D  # noqa: E402
from tpnet_ref.sim.scene import SceneParams  # noqa: E402
from tpnet_ref.sim.scene3d import SceneParams3D, simulate3d  # noqa: E402

pytestmark = pytest.mark.lane("3-D")   # in a second test process (tests/lane.py)

needs_mujoco = pytest.mark.skipif(importlib.util.find_spec("mujoco") is None,
                                  reason="the 3-D scene needs mujoco: pip install "
                                         "'tpnet-ref[sim3d]'")
STEPS = 81            # 21 model frames: a window of m = 4 and 8 targets, 37 released starts


@pytest.fixture(scope="module")
def file3d(tmp_path_factory):
    """A 3-D dataset made by the command: 3 throws of the grid, released windows."""
    if importlib.util.find_spec("mujoco") is None:
        pytest.skip("the 3-D scene needs mujoco: pip install 'tpnet-ref[sim3d]'")
    out = tmp_path_factory.mktemp("d3") / "grid3d.h5"
    rc = main(["data", "generate", "--dim", "3", "-o", str(out), "--forces", "1.3", "1.6",
               "--azimuths", "200", "230", "260", "--elevations", "-30", "--steps", str(STEPS),
               "--no-test", "--quiet", "--whole", "1"])
    assert rc == 0
    return out


@pytest.fixture(scope="module")
def file2d(tmp_path_factory):
    out = tmp_path_factory.mktemp("d2") / "grid2d.h5"
    D.generate(str(out), D.train_grid([1.3], [225.0], 2), m=4, steps=STEPS, progress=False)
    return out


@needs_mujoco
def test_the_command_writes_the_3d_layout(file3d):
    with h5py.File(file3d, "r") as h:
        assert D.file_dim(h) == 3 and int(h.attrs["dim"]) == 3
        assert h.attrs["windows"] == "released" and int(h.attrs["whole"]) == 1
        assert "impulse_point" not in h.attrs and "test" not in h
        g = h["train"]
        params = g["params"][...]
        np.testing.assert_array_equal(params, D.train_grid3d([1.3, 1.6], [200.0, 230.0, 260.0],
                                                             [-30.0]))
        assert g["positions"].shape == (3, 21, 42, 3) and g["normalized"].shape == (3, 21, 42, 3)
        assert g["contact"].shape == (3, 21, 6) and g["rows"].shape == (3, STEPS, 42, 3)
        assert g["done"][...].all()
        rows = simulate3d(*params[1], STEPS)
        np.testing.assert_array_equal(g["positions"][1], rows[::4].astype(np.float32))
        np.testing.assert_array_equal(g["rows"][1], normalize(rows).astype(np.float32))
        np.testing.assert_array_equal(g["contact"][1], D.wall_contact(rows[::4], SceneParams3D()))
        win = g["windows"][...]
        rel = g["windows_released"][...]
        # the whole trajectory gives every start and no sampled window, in both kinds
        whole = np.unique(rel[rel[:, 2] == D.KIND_WHOLE, 0])
        assert len(whole) == 1 and (rel[rel[:, 0] == whole[0], 2] == D.KIND_WHOLE).all()
        assert (rel[:, 1] + (4 + 8 - 1) * 4 < STEPS).all()
        assert set(np.unique(win[:, 0])) == {0, 1, 2}
        # a released collision window's first frame has a coordinate within 0.2 of the wall
        bound = D.RELEASED_COLLISION_RANGE / (43.8562 - 1.1438)
        for t, s, _ in rel[rel[:, 2] == D.KIND_COLLISION]:
            first = g["rows"][t, s]
            assert first.min() <= bound or first.max() >= 1 - bound


@needs_mujoco
def test_3d_readers_and_the_validation_split(file3d):
    x, y = D.load_windows(str(file3d), dim=3)
    assert x.shape[1:] == (4, 42, 3) and y.shape[1:] == (8, 42, 3) and len(x) == len(y)
    same, _ = D.load_windows(str(file3d), scene=SceneParams3D())     # a 3-D scene asks dim 3
    np.testing.assert_array_equal(same, x)
    frames, params = D.load_trajectories(str(file3d), "train", dim=3)
    assert frames.shape == (3, 21, 42, 3) and params.shape == (3, 6)
    from tpnet_ref.training.recipe import WindowData
    wd = WindowData(file3d, 0.34, 0, windows="released", dim=3)
    assert len(wd.val_traj) == 1
    assert not np.isin(wd.train_win[:, 0], wd.val_traj).any()
    assert np.isin(wd.val_win[:, 0], wd.val_traj).all() and len(wd.val_win)
    xi, yi = wd.gather(wd.train_win[:5])
    assert xi.shape == (5, 4, 42, 3) and yi.shape == (5, 8, 42, 3)


@needs_mujoco
def test_each_reader_refuses_the_other_dimension_in_one_line(file3d, file2d):
    from tpnet_ref.training.recipe import WindowData
    calls = [lambda: D.load_windows(str(file3d)),
             lambda: D.load_trajectories(str(file3d), "train"),
             lambda: D.load_windows(str(file3d), allow_other_scene=True),
             lambda: WindowData(file3d, 0.1, 0)]
    for call in calls:
        with pytest.raises(ValueError) as info:
            call()
        msg = str(info.value)
        assert "\n" not in msg and "a 3-D dataset (dim = 3)" in msg and "expects dim = 2" in msg
    calls = [lambda: D.load_windows(str(file2d), dim=3),
             lambda: D.load_trajectories(str(file2d), "train", scene=SceneParams3D()),
             lambda: WindowData(file2d, 0.1, 0, dim=3)]
    for call in calls:
        with pytest.raises(ValueError) as info:
            call()
        msg = str(info.value)
        assert "\n" not in msg and "a 2-D dataset (dim = 2)" in msg and "expects dim = 3" in msg
    with h5py.File(file2d, "r") as h:
        assert D.file_dim(h) == 2
    # generating into a file of the other dimension
    with pytest.raises(ValueError, match=r"holds a 2-D dataset \(dim = 2\), not dim = 3"):
        D.generate(str(file2d), D.train_grid3d(positions=1)[:1], steps=STEPS, dim=3,
                   progress=False)


@needs_mujoco
def test_generate_3d_resumes_and_is_deterministic(tmp_path):
    grid = D.train_grid3d([1.0], [215.0], [-45.0, -60.0])
    test = np.asarray(TEST_CASES3D[:1])
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    got = D.generate(str(a), grid, test, steps=STEPS, dim=3, progress=False,
                     windows="released")
    assert got["train_trajectories"] == 2 and got["test_trajectories"] == 1
    again = D.generate(str(a), grid, test, steps=STEPS, dim=3, progress=False,
                       windows="released")
    assert again["train_skipped"] == 2 and again["test_skipped"] == 1
    D.generate(str(b), grid, test, steps=STEPS, dim=3, progress=False, windows="released")
    with h5py.File(a, "r") as ha, h5py.File(b, "r") as hb:
        for name in ("train/rows", "train/positions", "train/windows", "train/windows_released",
                     "test/positions", "test/params"):
            np.testing.assert_array_equal(ha[name][...], hb[name][...])
        assert ha["test/params"].shape == (1, 6)


@pytest.mark.parametrize("call, says", [
    (lambda p: D.generate(p, D.train_grid([1.0], [200.0], 1), steps=STEPS, dim=3),
     "grid: expected shape (T, 6) (force, azimuth_deg, elevation_deg, x, y, z) for dim = 3, "
     "got (1, 4); 4 columns are 2-D cases"),
    (lambda p: D.generate(p, D.train_grid3d(positions=1)[:1], steps=STEPS),
     "grid: expected shape (T, 4)"),
    (lambda p: D.generate(p, D.train_grid3d(positions=1)[:1], steps=STEPS, dim=3,
                          params=SceneParams()),
     "params: dim = 3 needs a SceneParams3D, got SceneParams"),
    (lambda p: D.generate(p, D.train_grid3d(positions=1)[:1], steps=STEPS, dim=4),
     "dim: must be 2 or 3"),
    (lambda p: D.generate(p, [[1.0, 200.0, -30.0, 30.0, 30.0, 43.0]], steps=STEPS, dim=3),
     "grid[0]: z: start centre 43.0 puts the ball outside the box"),
    (lambda p: D.generate(p, D.train_grid3d(positions=1)[:1], [[1.0, 200.0, 95.0, 30, 30, 30]],
                          steps=STEPS, dim=3),
     "test_cases[0]: elevation_deg: must be in [-90, 90]"),
])
def test_bad_3d_settings_are_one_line_before_the_file_is_touched(tmp_path, call, says):
    path = str(tmp_path / "x.h5")
    with pytest.raises(ValueError) as info:
        call(path)
    assert str(info.value).startswith(says) and "\n" not in str(info.value)
    assert not (tmp_path / "x.h5").exists()


# ----------------------------------------------------------------- the command's settings
@pytest.fixture
def calls(monkeypatch):
    got = []

    def fake(path, grid, test_cases=None, **kw):
        got.append(dict(path=path, grid=grid, test_cases=test_cases, **kw))
        return {"train": len(grid), "test": 0 if test_cases is None else len(test_cases)}
    monkeypatch.setattr(D, "generate", fake)
    return got


def test_dim3_defaults_are_the_3d_grid_its_test_cases_and_released_windows(tmp_path, calls):
    assert main(["data", "generate", "--dim", "3", "-o", str(tmp_path / "d.h5")]) == 0
    (c,) = calls
    np.testing.assert_array_equal(c["grid"], D.train_grid3d())
    assert len(c["grid"]) == 342
    np.testing.assert_array_equal(c["test_cases"], np.asarray(TEST_CASES3D))
    assert (c["dim"], c["windows"], c["whole"], c["m"], c["steps"]) == (3, "released", 11, 4, 600)
    assert isinstance(c["params"], SceneParams3D) and c["params"] == SceneParams3D()


def test_dim3_flags_reach_the_grid(tmp_path, calls):
    assert main(["data", "generate", "--dim", "3", "-o", str(tmp_path / "d.h5"), "--forces",
                 "1.0", "1.6", "--azimuths", "190", "--elevations", "0", "-40", "--positions",
                 "3", "--per-direction", "2", "--limit", "3", "--windows", "model", "--whole",
                 "0", "--workers", "2"]) == 0
    (c,) = calls
    want = D.train_grid3d([1.0, 1.6], [190.0], [0.0, -40.0], positions=3, per_direction=2)[:3]
    np.testing.assert_array_equal(c["grid"], want)
    assert {tuple(r[3:]) for r in c["grid"]} <= set(TRAIN_POSITIONS3D[:3])
    assert (c["windows"], c["whole"], c["workers"]) == ("model", 0, 2)


@pytest.mark.parametrize("argv, says", [
    (["--dim", "3", "--angles", "200"], "--angles: a 2-D flag; this is --dim 3"),
    (["--dim", "3", "--sleep"], "--sleep: a 2-D flag; this is --dim 3"),
    (["--dim", "3", "--impulse-point", "particle_centre"], "--impulse-point: a 2-D flag"),
    (["--azimuths", "200"], "--azimuths: a 3-D flag; this is --dim 2"),
    (["--per-direction", "2"], "--per-direction: a 3-D flag; this is --dim 2"),
    (["--dim", "3", "--per-direction", "0"], "per_direction: must be >= 1"),
])
def test_flags_of_the_other_dimension_are_one_line(tmp_path, calls, capsys, argv, says):
    assert main(["data", "generate", "-o", str(tmp_path / "d.h5"), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0]
    assert not calls


def test_a_dimension_other_than_2_or_3_is_a_usage_error(tmp_path, calls, capsys):
    with pytest.raises(SystemExit) as info:
        main(["data", "generate", "-o", str(tmp_path / "d.h5"), "--dim", "4"])
    err = capsys.readouterr().err.strip().splitlines()
    assert info.value.code == 2 and len(err) == 1 and "--dim: invalid choice: 4" in err[0]
    assert not calls

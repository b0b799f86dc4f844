"""Dataset generation and reading (tpnet_ref.sim.dataset) on a tiny grid."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

h5py = pytest.importorskip("h5py")

from tpnet_ref.sim import dataset as D  # noqa: E402
from tpnet_ref.config import NORM_HI, NORM_LO, normalize  # noqa: E402
from tpnet_ref.sim import simulate  # noqa: E402
from tpnet_ref.sim.cases import TEST_CASES, TRAIN_POSITIONS  # noqa: E402


def test_constants_match_spec():
    assert len(TRAIN_POSITIONS) == 75 and len(TEST_CASES) == 60
    assert D.train_grid().shape == (5 * 19 * 75, 4)
    g = D.train_grid([1.0, 1.6], [180.0, 270.0], positions=2)
    assert g.tolist()[:3] == [[1.0, 180.0, *TRAIN_POSITIONS[0]], [1.0, 180.0, *TRAIN_POSITIONS[1]],
                              [1.0, 270.0, *TRAIN_POSITIONS[0]]]
    assert getattr(D, "normalize", normalize) is normalize   # one normalize: tpnet_ref.config
    assert normalize(NORM_LO) == 0.0 and normalize(NORM_HI) == 1.0


def test_sample_windows_kinds_and_counts():
    contact = np.zeros(150, dtype=bool)
    contact[40:50] = True
    contact[100:110] = True
    w = D.sample_windows(contact, np.random.default_rng(0), m=4)
    assert w.shape == (20, 2)
    coll = w[w[:, 1] == D.KIND_COLLISION, 0]
    norm = w[w[:, 1] == D.KIND_NORMAL, 0]
    assert len(coll) == 15 and len(norm) == 5

    def holds_onset(s):
        return ((s <= 40) & (s + 12 > 40)) | ((s <= 100) & (s + 12 > 100))
    assert holds_onset(coll).all() and not holds_onset(norm).any()
    # one onset gives only 12 collision starts: the rest are normal windows
    contact[100:110] = False
    w = D.sample_windows(contact, np.random.default_rng(0), m=4)
    assert np.bincount(w[:, 1]).tolist() == [8, 12]
    # no contact at all: every window is "normal"
    w = D.sample_windows(np.zeros(150, bool), np.random.default_rng(0), m=4)
    assert (w[:, 1] == D.KIND_NORMAL).all() and len(w) == 20
    with pytest.raises(ValueError, match="shorter"):
        D.sample_windows(np.zeros(5, bool), np.random.default_rng(0), m=4)


def test_generate_layout_resume_and_load(tmp_path):
    path = str(tmp_path / "tiny.h5")
    grid = D.train_grid([1.3], [200.0, 250.0], positions=1)
    test = np.asarray(TEST_CASES[:2])
    c = D.generate(path, grid, test, m=3, steps=121, seed=1, whole=1, progress=False)
    assert c["train_trajectories"] == 2 and c["test_trajectories"] == 2
    n_frames = 31
    with h5py.File(path, "r") as h:
        assert int(h.attrs["m"]) == 3 and int(h.attrs["frame_every"]) == 4
        for split, t in (("train", 2), ("test", 2)):
            g = h[split]
            assert g["positions"].shape == (t, n_frames, 30, 2)
            assert g["positions"].dtype == np.float32
            assert g["done"][...].all()
            np.testing.assert_allclose(g["normalized"][...],
                                       normalize(g["positions"][...]), atol=1e-6)
        assert "windows" not in h["test"]
        win = h["train/windows"][...]
        # frame j is simulation row 4 j; frame 0 the initial state
        ref = simulate(*grid[1], steps=121)[::4]
        np.testing.assert_allclose(h["train/positions"][1], ref, atol=1e-4)
        np.testing.assert_allclose(h["test/params"][...], test)
    assert win.shape[1] == 3
    assert (np.bincount(win[:, 0], minlength=2)[:2] >= 20).all()
    whole = win[win[:, 2] == D.KIND_WHOLE]
    assert len(whole) == n_frames - 3 - 8 + 1
    # resume: nothing re-simulated, same windows
    c2 = D.generate(path, grid, test, m=3, steps=121, seed=1, whole=1, progress=False)
    assert c2["train_skipped"] == 2 and c2["test_skipped"] == 2
    with h5py.File(path, "r") as h:
        assert np.array_equal(h["train/windows"][...], win)
    x, y = D.load_windows(path)
    assert x.shape == (len(win), 3, 30, 2) and y.shape == (len(win), 8, 30, 2)
    i, s = win[0, 0], win[0, 1]
    frames, _ = D.load_trajectories(path, "train", normalized=True)
    np.testing.assert_array_equal(x[0], frames[i, s:s + 3])
    np.testing.assert_array_equal(y[0], frames[i, s + 3:s + 11])
    xc, _ = D.load_windows(path, kinds=[D.KIND_COLLISION])
    assert len(xc) < len(x)
    # other settings on the same file are refused
    with pytest.raises(ValueError, match="m="):
        D.generate(path, grid, test, m=4, steps=121, seed=1, whole=1, progress=False)


def test_generate_rejects_bad_settings(tmp_path):
    grid = D.train_grid([1.3], [200.0], positions=1)
    with pytest.raises(ValueError, match="steps"):
        D.generate(str(tmp_path / "a.h5"), grid, steps=20, progress=False)
    with pytest.raises(ValueError, match="m"):
        D.generate(str(tmp_path / "b.h5"), grid, m=0, progress=False)
    with pytest.raises(ValueError, match="positions"):
        D.train_grid(positions=0)


def test_contact_onset_per_wall():
    from tpnet_ref.sim import simulate
    frames = simulate(1.6, 250.0, 30.0, 30.0)[::4]
    c = D.wall_contact(frames)
    assert c.shape == (150, 4) and c.any()
    onset = D.collision_frames(c)
    assert onset.shape == (150,) and onset.sum() >= 1
    # sliding along one wall into another: the second wall's contact is a new collision
    c2 = np.zeros((10, 4), bool)
    c2[2:, 0] = True
    c2[6:, 2] = True
    assert np.nonzero(D.collision_frames(c2))[0].tolist() == [2, 6]


@settings(max_examples=40, deadline=None)
@given(contact=st.lists(st.booleans(), min_size=12, max_size=160), m=st.integers(3, 5),
       seed=st.integers(0, 2 ** 16))
def test_sample_windows_properties(contact, m, seed):
    c = np.asarray(contact)
    if len(c) < m + 8:
        with pytest.raises(ValueError):
            D.sample_windows(c, np.random.default_rng(seed), m=m)
        return
    w = D.sample_windows(c, np.random.default_rng(seed), m=m)
    assert w.shape == (20, 2)
    assert (w[:, 0] >= 0).all() and (w[:, 0] + m + 8 <= len(c)).all()
    onset = D.collision_frames(c)
    for s, kind in w:
        has = onset[s:s + m + 8].any()
        assert has == (kind == D.KIND_COLLISION)
    again = D.sample_windows(c, np.random.default_rng(seed), m=m)
    assert np.array_equal(w, again)


# ----------------------------------------------------------------- the scene convention
def _tiny(path, **scene):
    from tpnet_ref.sim import SceneParams
    grid = D.train_grid([1.3], [225.0], positions=1)
    D.generate(str(path), grid, m=3, steps=81, whole=0, progress=False,
               params=SceneParams(**scene))
    return str(path)


def test_file_records_the_scene_convention_and_loaders_refuse_another(tmp_path):
    from tpnet_ref.sim import SceneParams
    released = _tiny(tmp_path / "r.h5")
    with h5py.File(released, "r") as h:
        assert D.scene_convention(h) == {"impulse_point": "ring_centre", "sleep": False}
    D.load_windows(released)
    com = _tiny(tmp_path / "c.h5", impulse_point="particle_centre")
    with pytest.raises(ValueError, match="impulse_point='particle_centre'.*allow_other_scene"):
        D.load_windows(com)
    with pytest.raises(ValueError, match="allow_other_scene") as exc:
        D.load_trajectories(com, "train")
    assert "\n" not in str(exc.value)
    x, _ = D.load_windows(com, allow_other_scene=True)
    frames, _ = D.load_trajectories(com, "train", scene=SceneParams(impulse_point="particle_centre"))
    assert len(x) == 20 and frames.shape == (1, 21, 30, 2)
    with pytest.raises(ValueError, match="sleep"):
        D.load_windows(_tiny(tmp_path / "s.h5", sleep=True))


def test_file_without_the_attributes_is_the_old_centre_of_mass_convention(tmp_path):
    from tpnet_ref.sim import SceneParams
    path = _tiny(tmp_path / "old.h5", impulse_point="particle_centre", sleep=True)
    with h5py.File(path, "a") as h:                 # as written before the convention was kept
        del h.attrs["impulse_point"], h.attrs["sleep"]
        assert D.scene_convention(h) == {"impulse_point": "particle_centre", "sleep": True}
    with pytest.raises(ValueError, match="particle_centre"):
        D.load_trajectories(path, "train")
    old = SceneParams(impulse_point="particle_centre", sleep=True)
    assert D.load_trajectories(path, "train", scene=old)[0].shape == (1, 21, 30, 2)


def test_default_dataset_follows_the_simulator_default(tmp_path):
    path = _tiny(tmp_path / "d.h5")
    frames, params = D.load_trajectories(path, "train")
    np.testing.assert_allclose(frames[0], simulate(*params[0], steps=81)[::4], atol=1e-4)

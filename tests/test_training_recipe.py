"""The training recipe: schedules, sizes, and the windows of a dataset file (scene convention checked)."""
from __future__ import annotations

import dataclasses
import json

import pytest

torch = pytest.importorskip("torch")

from tpnet_ref.training import recipe as R  # noqa: E402
from training_helpers import dataset, tiny_recipe  # noqa: E402,F401


def test_recipe_schedules():
    r = R.Recipe(recipe="curriculum", pretrain_epochs=2, ramp_epochs=4, warmup_steps=10,
                 lr=1e-3, lr_min=1e-5)
    ks = [r.steps_at(e / 4) for e in range(0, 32)]
    assert ks[:8] == [1] * 8 and ks[-1] == 8 and ks == sorted(ks) and set(ks) == set(range(1, 9))
    assert R.Recipe(recipe="paper").steps_at(0.0) == 8
    assert r.lr_at(0, 1000) == pytest.approx(1e-4)
    assert r.lr_at(10, 1000) == pytest.approx(1e-3, rel=1e-3)
    assert r.lr_at(999, 1000) == pytest.approx(1e-5)
    with pytest.raises(ValueError):
        R.Recipe(recipe="nope")
    assert R.Recipe.from_dict(json.loads(json.dumps(dataclasses.asdict(r)))) == r


def test_a_dataset_of_another_scene_convention_is_refused_unless_allowed(dataset, tmp_path, capsys):
    import shutil

    import h5py

    from tpnet_ref import cli

    other = tmp_path / "other.h5"
    shutil.copy(dataset, other)
    with h5py.File(other, "r+") as h:
        h.attrs["impulse_point"] = ("particle_centre" if h.attrs["impulse_point"] != "particle_centre"
                                    else "ring_centre")
    with pytest.raises(ValueError, match="scene convention impulse_point=.*--allow-other-scene"):
        R.WindowData(other, 0.2, 0)
    data = R.WindowData(other, 0.2, 0, allow_other_scene=True)
    assert len(data.train_win) > 0
    assert cli.main(["train", "baselines", str(other)]) == 2
    assert "scene convention" in capsys.readouterr().err
    assert cli.main(["train", "baselines", str(other), "--allow-other-scene"]) == 0
    assert cli.main(["train", "run", str(other), "-o", str(tmp_path / "r"), "--size", "tiny",
                     "--epochs", "1", "--quiet"]) == 2
    assert not (tmp_path / "r" / "checkpoint.json").exists()


def test_a_longer_rollout_gathers_its_targets_from_the_whole_trajectories(dataset, tmp_path):
    """``horizon`` > 8 keeps the windows with that many frames after their inputs, and gathers
    those frames (the file's own targets are its first 8); the validation trajectories are the
    same for every horizon, and a horizon past the longest allowed is refused."""
    import numpy as np

    d8 = R.WindowData(dataset, 0.2, 0)
    d16 = R.WindowData(dataset, 0.2, 0, horizon=16)
    T = d8.frames.shape[1]
    assert np.array_equal(d8.val_traj, d16.val_traj)
    for w8, w16 in ((d8.train_win, d16.train_win), (d8.val_win, d16.val_win)):
        keep = w8[w8[:, 1] + d8.m + 16 <= T]
        assert np.array_equal(w16, keep)
        assert 0 < len(w16) < len(w8)                    # the last windows have too few frames
    x8, y8 = d8.gather(d16.train_win[:5])
    x16, y16 = d16.gather(d16.train_win[:5])
    assert y16.shape[1] == 16 and np.array_equal(x8, x16) and np.array_equal(y8, y16[:, :8])
    t, s = d16.train_win[0, :2]
    assert np.array_equal(y16[0, 15], d16.frames[t, s + d16.m + 15])
    with pytest.raises(ValueError, match="rollout must be in 1..32"):
        R.Recipe(rollout=33)
    with pytest.raises(ValueError, match="horizon must be in 1..32"):
        R.WindowData(dataset, 0.2, 0, horizon=40)
    # a run with the 16-step loss: every step and its validation see 16 predictions
    from tpnet_ref.training import loop as L

    st = L.train(dataset, tmp_path / "run", tiny_recipe(epochs=1, rollout=16), threads=1,
                 progress=False)
    assert st["stopped"] == "done" and st["train_windows"] == len(d16.train_win)
    assert "val_cd16" in st["last_val"]

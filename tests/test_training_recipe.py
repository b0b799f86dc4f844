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

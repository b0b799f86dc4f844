"""``tpnet data generate`` (tpnet_ref.cli.data): a small real dataset, every flag reaching
tpnet_ref.sim.dataset.generate, and one-line errors for bad settings."""
from __future__ import annotations

import numpy as np
import pytest

h5py = pytest.importorskip("h5py")

from tpnet_ref.sim import dataset as D  # noqa: E402
from tpnet_ref.cli import main  # noqa: E402
from tpnet_ref.sim.cases import TEST_CASES, TRAIN_ANGLES_DEG, TRAIN_FORCES  # noqa: E402


def test_cli_generate(tmp_path):
    out = tmp_path / "new_dir" / "c.h5"
    rc = main(["data", "generate", "-o", str(out), "--forces", "1.0", "--angles", "225",
               "--positions", "2", "--limit", "1", "--steps", "81", "--no-test", "--quiet",
               "--whole", "0"])
    assert rc == 0
    with h5py.File(out, "r") as h:
        assert h["train/positions"].shape == (1, 21, 30, 2)
        assert "test" not in h
        assert D.scene_convention(h) == {"impulse_point": "ring_centre", "sleep": False}
    com = tmp_path / "com.h5"
    assert main(["data", "generate", "-o", str(com), "--forces", "1.0", "--angles", "225",
                 "--positions", "1", "--steps", "81", "--no-test", "--quiet", "--whole", "0",
                 "--impulse-point", "particle_centre"]) == 0
    with h5py.File(com, "r") as h:
        assert D.scene_convention(h)["impulse_point"] == "particle_centre"


@pytest.fixture
def calls(monkeypatch):
    """tpnet_ref.sim.dataset.generate replaced by a recorder: what the command asks for, without
    simulating."""
    got = []

    def fake(path, grid, test_cases=None, **kw):
        got.append(dict(path=path, grid=grid, test_cases=test_cases, **kw))
        return {"train": len(grid), "test": 0 if test_cases is None else len(test_cases)}
    monkeypatch.setattr(D, "generate", fake)
    return got


def test_defaults_are_the_paper_grid_and_the_60_test_cases(tmp_path, calls, capsys):
    assert main(["data", "generate", "-o", str(tmp_path / "d.h5")]) == 0
    (c,) = calls
    np.testing.assert_array_equal(c["grid"], D.train_grid(TRAIN_FORCES, TRAIN_ANGLES_DEG, None))
    np.testing.assert_array_equal(c["test_cases"], np.asarray(TEST_CASES))
    assert (c["m"], c["steps"], c["seed"], c["workers"], c["whole"]) == (4, 600, 0, 1, 240)
    assert c["progress"] is True
    assert (c["params"].impulse_point, c["params"].sleep) == ("ring_centre", False)
    assert capsys.readouterr().out.strip() == (f"wrote {tmp_path / 'd.h5'}: "
                                               f"train {len(c['grid'])}, test 60")


def test_every_flag_reaches_generate(tmp_path, calls):
    assert main(["data", "generate", "-o", str(tmp_path / "d.h5"), "--forces", "1.1", "1.2",
                 "--angles", "190", "--positions", "3", "--limit", "4", "--m", "5",
                 "--steps", "300", "--seed", "7", "--whole", "2", "--workers", "2", "--no-test",
                 "--quiet", "--sleep", "--impulse-point", "particle_centre"]) == 0
    (c,) = calls
    np.testing.assert_array_equal(c["grid"], D.train_grid([1.1, 1.2], [190.0], 3)[:4])
    assert c["test_cases"] is None and c["progress"] is False
    assert (c["m"], c["steps"], c["seed"], c["workers"], c["whole"]) == (5, 300, 7, 2, 2)
    assert (c["params"].impulse_point, c["params"].sleep) == ("particle_centre", True)


@pytest.mark.parametrize("argv, says", [
    (["--limit", "0"], "--limit: must be >= 1, got 0"),
    (["--positions", "0"], "positions"),
])
def test_bad_settings_are_one_line(tmp_path, calls, capsys, argv, says):
    assert main(["data", "generate", "-o", str(tmp_path / "d.h5"), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tpnet data: error:") and says in err[0]
    assert not calls


def test_usage_errors(capsys):
    for argv, says in ((["data"], "required: DATA_COMMAND"),
                       (["data", "generate"], "required: -o/--output"),
                       (["data", "generate", "-o", "x.h5", "--impulse-point", "top"],
                        "invalid choice: 'top'")):
        with pytest.raises(SystemExit) as info:
            main(argv)
        assert info.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and says in err[0], err

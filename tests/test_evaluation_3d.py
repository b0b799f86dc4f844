"""3-D evaluation: ``tpnet eval`` of 3-D weights (tpnet_ref.evaluation.suite3d) and ``tpnet
animate`` of a 3-D model (tpnet_ref.evaluation.animate3d), on a random tiny 3-D network."""
from __future__ import annotations

import importlib.util
import warnings

import numpy as np
import pytest

pytest.importorskip("matplotlib")
if importlib.util.find_spec("mujoco") is None:
    pytest.skip("the 3-D scene needs mujoco: pip install 'tpnet-ref[sim3d]'",
                allow_module_level=True)

from tpnet_ref.checks import OutsideTrainingRangeWarning  # noqa: E402
from tpnet_ref.cli import main  # noqa: E402
from tpnet_ref.config import TPNetConfig  # noqa: E402
from tpnet_ref.evaluation import suite3d as S  # noqa: E402
from tpnet_ref.evaluation.animate3d import animate3d  # noqa: E402
from tpnet_ref.model import init_random  # noqa: E402

pytestmark = pytest.mark.lane("3-D")   # in a second test process (tests/lane.py)

TINY3D = TPNetConfig(m=4, dim=3, mlp1=(8, 8), mlp2=(8, 16, 16), global_features=8,
                     lstm_units=(8, 8, 8), n_out=42)


@pytest.fixture(scope="module")
def weights3d(tmp_path_factory):
    path = tmp_path_factory.mktemp("w3") / "tiny3d.h5"
    init_random(TINY3D, seed=3).save(str(path))
    return str(path)


@pytest.fixture(autouse=True)
def _random_net_is_out_of_range():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutsideTrainingRangeWarning)
        yield


def test_eval_of_3d_weights_writes_the_3d_tables(weights3d, tmp_path, capsys):
    out = tmp_path / "ev"
    rc = main(["eval", "--weights", weights3d, "--cases", "3", "--horizon", "80", "--out",
               str(out), "--repeats", "1", "--quiet"])
    assert rc == 0
    text = (out / "results3d.md").read_text()
    assert "3 held-out throws" in text and "E_p @40" in text and "E_p @80" in text
    for name in ("TP-Net tiny3d.h5", "copy last", "constant velocity"):
        assert name in text
    assert "B = 1 latency" in text and (out / "front3d.png").stat().st_size > 5000
    rows = (out / "eval3d_cases.csv").read_text().splitlines()
    assert len(rows) == 1 + 3 * 3 * 2          # 3 methods x 3 cases x 2 horizons
    assert "E_p @40" in capsys.readouterr().out


def test_eval3d_agrees_with_copy_last_computed_by_hand(tmp_path):
    from tpnet_ref.config import normalize
    from tpnet_ref.metrics import position_error
    from tpnet_ref.sim.cases3d import TEST_CASES3D
    path = S.run_eval3d([], cases=2, horizon=40, out=tmp_path, plots=False)
    frames = S.simulate_cases3d(TEST_CASES3D[:2])
    f = normalize(frames)
    want = np.mean([position_error(f[c, 3 + 40], f[c, 3], variant="squared") for c in range(2)])
    csv = (tmp_path / "eval3d_cases.csv").read_text().splitlines()
    head = csv[0].split(",")
    got = [float(r.split(",")[head.index("Ep_squared")]) for r in csv[1:]
           if ",copy last," in r and r.split(",")[head.index("step")] == "40"]
    assert np.mean(got) == pytest.approx(want, rel=1e-5)          # the CSV keeps 6 digits
    assert "results3d.md" in str(path)


def test_2d_and_3d_weights_together_are_refused_in_one_line(weights3d, tmp_path, capsys):
    w2 = tmp_path / "tiny2d.h5"
    init_random(TPNetConfig(m=4, mlp1=(8, 8), mlp2=(8, 16, 16), global_features=8,
                            lstm_units=(8, 8, 8)), seed=1).save(str(w2))
    for argv, says in (
            (["--weights", weights3d, "--weights", str(w2)], "2-D and 3-D models together"),
            (["--weights", weights3d, "--dim", "2"], "--dim 2: the weights are 3-D")):
        assert main(["eval", *argv, "--out", str(tmp_path)]) != 0
        err = [x for x in capsys.readouterr().err.splitlines() if "error" in x]
        assert len(err) == 1 and says in err[0]


def test_animate_of_a_3d_model_writes_three_views(weights3d, tmp_path, capsys):
    gif = tmp_path / "r3.gif"
    rc = main(["animate", "--weights", weights3d, "-o", str(gif), "--last-frame", "12",
               "--every", "4", "--dpi", "40"])
    assert rc == 0 and gif.stat().st_size > 1000
    from PIL import Image
    im = Image.open(gif)
    assert im.n_frames == 4 + 3 and im.size[0] > 2 * im.size[1]      # three panels side by side
    assert "E_p (squared)" in capsys.readouterr().out
    assert main(["animate", "--weights", weights3d, "-o", str(gif), "--case", "1", "200", "30",
                 "30"]) != 0
    assert "a 3-D model's scene has 6 numbers, got 4" in capsys.readouterr().err


def test_animate3d_refuses_a_2d_model(tmp_path):
    net = init_random(TPNetConfig(m=4, mlp1=(8, 8), mlp2=(8, 16, 16), global_features=8,
                                  lstm_units=(8, 8, 8)), seed=1)
    with pytest.raises(ValueError, match="needs a 3-D model"):
        animate3d(tmp_path / "x.gif", model=net)

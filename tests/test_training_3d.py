"""Training on a 3-D dataset (``tpnet data generate --dim 3``): the file's dimension picks the
network's, the released recipe runs, validates and snapshots a native file that records
``dim = 3``; the template head is a sphere of the body's rest radius; a 2-D parent refuses a
3-D file in one line."""
from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
h5py = pytest.importorskip("h5py")

from tpnet_ref.cli import main  # noqa: E402
from tpnet_ref.training import loop as L  # noqa: E402
from tpnet_ref.training import recipe as R  # noqa: E402
from tpnet_ref.training.torch_model import TorchTPNet  # noqa: E402
import tpnet_ref  # noqa: E402


@pytest.fixture(scope="module")
def file3d(tmp_path_factory):
    """Six short 3-D throws with released windows, made by the command."""
    if importlib.util.find_spec("mujoco") is None:
        pytest.skip("the 3-D scene needs mujoco: pip install 'tpnet-ref[sim3d]'")
    out = tmp_path_factory.mktemp("d3") / "grid3d.h5"
    rc = main(["data", "generate", "--dim", "3", "-o", str(out), "--forces", "1.3", "1.6",
               "--azimuths", "200", "230", "260", "--elevations", "-30", "--steps", "121",
               "--no-test", "--quiet", "--whole", "1"])
    assert rc == 0
    return out


def test_a_3d_file_trains_a_3d_network_with_the_released_recipe(file3d, tmp_path):
    run = tmp_path / "run"
    rc = main(["train", "run", str(file3d), "-o", str(run), "--preset", "released",
               "--size", "tiny", "--max-steps", "2", "--batch", "8", "--val-every", "2",
               "--val-fraction", "0.2", "--snapshots", "--device", "cpu", "--threads", "1",
               "--quiet"])
    assert rc == 0
    state = json.loads((run / "checkpoint.json").read_text())
    assert state["recipe"]["config"]["dim"] == 3 and state["step"] == 2
    assert state["recipe"]["config"]["n_out"] == 42              # the ball's points
    vals = [json.loads(x) for x in (run / "log.jsonl").read_text().splitlines()]
    val = [v for v in vals if v["kind"] == "val"][-1]
    assert np.isfinite([val["val_loss"], val["val_cd8"], val["val_es8"]]).all()
    snap = run / "snapshots" / "step-0000002.h5"
    assert tpnet_ref.load(str(snap)).config.dim == 3


def test_the_template_head_is_a_sphere_of_the_rest_radius(file3d):
    r = R.Recipe(recipe="paper", epochs=1, batch=8, val_fraction=0.2, head_init="template",
                 config=R.size_config("tiny", dim=3, n_out=42).to_dict())
    data = R.WindowData(file3d, r.val_fraction, r.split_seed, dim=3)
    torch.manual_seed(0)
    net = TorchTPNet(r.tpnet_config)
    L.init_head_template(net, data)
    x, _ = data.gather(data.train_win[:4])
    with torch.no_grad():
        y = net(torch.from_numpy(x)).numpy().astype(np.float64)          # (4, N, 3)
    f0 = data.frames[:, 0].astype(np.float64)
    radius = np.linalg.norm(f0 - f0.mean(1, keepdims=True), axis=-1).mean()
    c = y.mean(1, keepdims=True)
    r_out = np.linalg.norm(y - c, axis=-1)
    assert abs(r_out.mean() - radius) < 0.25 * radius
    assert np.median(np.abs(r_out / radius - 1)) < 0.5
    z = (y - c)[..., 2] / radius                         # spread over the sphere, not a ring
    assert z.min() < -0.5 and z.max() > 0.5


def test_a_2d_network_refuses_a_3d_file_in_one_line(file3d, tmp_path):
    r = R.Recipe(recipe="paper", epochs=1, batch=8, val_fraction=0.2,
                 config=R.size_config("tiny").to_dict())
    with pytest.raises(ValueError, match="3-D dataset") as err:
        L.train(file3d, tmp_path / "run2d", r, max_steps=1, device="cpu", threads=1,
                progress=False)
    assert "\n" not in str(err.value)


def test_score_and_baselines_read_a_3d_file_as_3d(file3d, tmp_path, capsys):
    """``tpnet train score`` / ``baselines`` take the file's dimension: a 3-D snapshot is scored
    on the 3-D validation trajectories beside copy last."""
    from tpnet_ref.config import TPNetConfig
    from tpnet_ref.model import init_random
    w = tmp_path / "tiny3d.h5"
    init_random(TPNetConfig(m=4, dim=3, n_out=42, mlp1=(8, 8), mlp2=(8, 16, 16),
                            global_features=8, lstm_units=(8, 8, 8)), seed=2).save(str(w))
    assert main(["train", "score", str(file3d), str(w), "--horizon", "10",
                 "--val-fraction", "0.2"]) == 0
    out = capsys.readouterr().out
    assert "copy last" in out and "tiny3d.h5" in out and "Ep@10" in out
    assert main(["train", "baselines", str(file3d), "--val-fraction", "0.2"]) == 0
    assert "copy_last" in capsys.readouterr().out


def test_a_resumed_run_keeps_its_snapshots(file3d, tmp_path):
    """``--snapshots`` is the run's: a resume without the flag keeps writing them."""
    run = tmp_path / "run"
    common = ["--device", "cpu", "--threads", "1", "--quiet"]
    assert main(["train", "run", str(file3d), "-o", str(run), "--preset", "released",
                 "--size", "tiny", "--max-steps", "2", "--batch", "8", "--val-every", "2",
                 "--val-fraction", "0.2", "--snapshots", *common]) == 0
    assert main(["train", "run", str(file3d), "-o", str(run), "--resume", "--max-steps", "4",
                 *common]) == 0
    assert json.loads((run / "checkpoint.json").read_text())["snapshots"] is True
    assert (run / "snapshots" / "step-0000004.h5").is_file()

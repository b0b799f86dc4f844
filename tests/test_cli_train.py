"""``tpnet train run|export|bench|score|baselines`` (tpnet_ref.cli.train): every flag of ``run``
reaches the recipe or the run's settings, a small real ``bench``, one-line errors before any
training. Training runs themselves: test_training_*.py."""
from __future__ import annotations

import dataclasses

import pytest

torch = pytest.importorskip("torch")
h5py = pytest.importorskip("h5py")

from tpnet_ref.cli import build_parser, main  # noqa: E402
from tpnet_ref.training import loop as L  # noqa: E402
from tpnet_ref.training import recipe as R  # noqa: E402


@pytest.fixture
def fake_data(tmp_path):
    """A file that says m = 5: all `train run` reads before handing over to the loop."""
    p = tmp_path / "d.h5"
    with h5py.File(p, "w") as f:
        f.attrs["m"] = 5
    return str(p)


@pytest.fixture
def runs(monkeypatch):
    got = []

    def fake_train(data, run_dir, recipe, **kw):
        got.append((data, run_dir, recipe, kw))
        return {"step": 3, "total_steps": 10, "stopped": "max_steps", "windows_seen": 48,
                "wall_s": 2.0, "last_val": {"val_loss": 1.5}}
    monkeypatch.setattr(L, "train", fake_train)
    return got


#: a non-default value for every recipe field that `train run` has a flag for
RECIPE_FLAGS = {
    "recipe": ("--recipe", "paper"), "epochs": ("--epochs", 3.5), "batch": ("--batch", 16),
    "lr": ("--lr", 0.002), "beta1": ("--beta1", 0.9), "beta2": ("--beta2", 0.99),
    "eps": ("--adam-eps", 1e-6), "schedule": ("--schedule", "constant"),
    "lr_min": ("--lr-min", 1e-4), "warmup_steps": ("--warmup-steps", 5), "clip": ("--clip", 2.0),
    "noise": ("--noise", 0.01), "noise_kind": ("--noise-kind", "walk"),
    "shape_weight": ("--shape-weight", 0.5),
    "match_weight": ("--match-weight", 0.25), "pretrain_epochs": ("--pretrain-epochs", 1.0),
    "ramp_epochs": ("--ramp-epochs", 1.5), "rollout": ("--rollout", 4),
    "grad_steps": ("--grad-steps", 2),
    "head_init": ("--head-init", "template"), "val_windows": ("--val-windows", 9),
    "val_fraction": ("--val-fraction", 0.1), "split_seed": ("--split-seed", 2),
    "seed": ("--seed", 11), "init": ("--init", "keras"), "windows": ("--windows", "released"),
}


def test_every_run_flag_reaches_the_recipe(fake_data, tmp_path, runs, capsys):
    argv = ["train", "run", fake_data, "-o", str(tmp_path / "run"), "--size", "tiny",
            "--lstm-activation", "tanh", "--quiet"]
    for flag, value in RECIPE_FLAGS.values():
        argv += [flag, str(value)]
    assert main(argv) == 0
    (data, run_dir, r, kw) = runs[0]
    assert data == fake_data and run_dir == str(tmp_path / "run")
    for field, (_, value) in RECIPE_FLAGS.items():
        assert getattr(r, field) == value, field
        assert getattr(R.Recipe(), field) != value, f"{field}: pick a non-default value"
    # the recipe fields without a flag: the network (from --size, the data's m) and first_weight
    # (init_from and init_optimizer need a parent run: tests/test_training_ablations.py;
    # quantize_aware too: tests/test_training_fake_quant.py)
    flagged = set(RECIPE_FLAGS) | {"config", "first_weight", "init_from", "init_optimizer",
                                   "quantize_aware"}
    assert {f.name for f in dataclasses.fields(R.Recipe)} == flagged
    assert r.tpnet_config == R.size_config("tiny", m=5, lstm_activation="tanh")
    out = capsys.readouterr().out
    assert out.startswith(f"{tmp_path / 'run'}: step 3/10 (max_steps), 48 windows seen, 2 s")


def test_every_run_flag_reaches_the_settings(fake_data, tmp_path, runs):
    assert main(["train", "run", fake_data, "-o", str(tmp_path / "r"), "--device", "cpu",
                 "--threads", "1", "--compile", "eager", "--max-steps", "7", "--max-minutes",
                 "2.5", "--budget-minutes", "3", "--checkpoint-minutes", "1",
                 "--checkpoint-part-mib", "16", "--checkpoint-optimizer", "bf16",
                 "--allow-other-scene", "--log-every", "5", "--val-every", "6",
                 "--export", "w.h5", "--precision", "bf16", "--snapshots", "--quiet"]) == 0
    kw = runs[0][3]
    want = dict(resume=False, epochs=None, device="cpu", threads=1, max_steps=7,
                max_minutes=2.5, checkpoint_minutes=1.0, log_every=5, val_every=6,
                progress=False, export_path="w.h5", budget_minutes=3.0,
                checkpoint_part_mib=16.0, checkpoint_optimizer="bf16", allow_other_scene=True,
                compile="eager", precision="bf16", snapshots=True)
    assert kw == want
    names = {f.name for f in dataclasses.fields(L.TrainSettings)}
    assert set(kw) <= names and names - set(kw) == {"limit_windows"}   # library-only setting
    s = L.TrainSettings(**kw)                   # every flag is a setting of the run
    assert s.compile == "eager"


def test_resume_reads_no_recipe_from_the_flags(tmp_path, runs):
    assert main(["train", "run", str(tmp_path / "gone.h5"), "-o", str(tmp_path / "r"),
                 "--resume", "--epochs", "4", "--quiet"]) == 0
    (_, _, r, kw) = runs[0]
    assert r is None and kw["resume"] is True and kw["epochs"] == 4.0


def test_bad_run_inputs_are_one_line_before_training(tmp_path, runs, capsys):
    for argv, says in (
            (["train", "run", str(tmp_path / "none.h5"), "-o", str(tmp_path / "r")],
             "dataset not found"),
            (["train", "run", str(tmp_path), "-o", str(tmp_path / "r")], "dataset not found")):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("tpnet train: error:") and says in err[0]
    assert not runs
    for argv, says in ((["train"], "required: TRAIN_COMMAND"),
                       (["train", "run", "d.h5"], "required: -o/--run-dir"),
                       (["train", "run", "d.h5", "-o", "r", "--compile", "fast"],
                        "invalid choice: 'fast'"),
                       (["train", "run", "d.h5", "-o", "r", "--checkpoint-optimizer", "half"],
                        "invalid choice: 'half'"),
                       (["train", "run", "d.h5", "-o", "r", "--noise-kind", "pink"],
                        "invalid choice: 'pink'"),
                       (["train", "bench", "--size", "huge"], "invalid choice: 'huge'")):
        with pytest.raises(SystemExit) as info:
            main(argv)
        assert info.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and says in err[0], err


def test_grad_steps_past_the_rollout_is_one_line_before_training(fake_data, tmp_path, runs,
                                                                 capsys):
    assert main(["train", "run", fake_data, "-o", str(tmp_path / "r"), "--rollout", "4",
                 "--grad-steps", "5", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["tpnet train: error: grad_steps must be in 0..rollout (4), got 5"]
    assert not runs


def test_resume_of_a_directory_without_a_run_is_one_line(tmp_path, capsys):
    (tmp_path / "r").mkdir()
    assert main(["train", "run", "d.h5", "-o", str(tmp_path / "r"), "--resume", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "tpnet train: error:" in err[0]


def test_bench_runs_a_tiny_network(capsys):
    assert main(["train", "bench", "--size", "tiny", "--batch", "4", "--rollouts", "1", "2",
                 "--iters", "1", "--threads", "1", "--device", "cpu", "--precisions",
                 "float32"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].startswith("train step throughput, size tiny, batch 4, compile off")
    assert [ln.split(":")[0].strip() for ln in lines[1:]] == ["1-step loss, float32",
                                                              "2-step loss, float32"]
    assert all(float(ln.split(":")[1].split()[0]) > 0 for ln in lines[1:])


def test_parser_defaults_are_the_recipes():
    a = build_parser().parse_args(["train", "run", "d.h5", "-o", "r"])
    d = R.Recipe()
    assert (a.recipe, a.batch, a.lr, a.rollout, a.val_fraction, a.grad_steps, a.noise_kind) == (
        d.recipe, d.batch, d.lr, d.rollout, d.val_fraction, d.grad_steps, d.noise_kind)
    assert a.epochs is None and a.threads == 2 and a.compile == "off" and a.precision == "float32"
    assert (a.checkpoint_minutes, a.log_every) == (L.TrainSettings.checkpoint_minutes,
                                                   L.TrainSettings.log_every)

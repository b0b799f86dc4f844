"""tools/gpu_train.sh, the script a GPU call runs, end to end on the CPU at tiny size.

Two calls and the step between them, as a GPU session does them: call 1 generates a tiny grid,
starts a run with the step traced by TorchDynamo (``--compile eager``: the capture front end of
``reduce-overhead``, without CUDA) and stops half-way; what it leaves in $OUT is what a device
returns (at most 8 files of 16 MiB); ``collect`` puts those files into a fresh ``.gpu/NAME``
(the machine went back: nothing of call 1 is left but what came back) and exports the weights;
call 2 resumes from those parts and finishes.

The script's runs are early jobs (tests/background.py): they start with the session, beside the
in-process tests, each with a Numba cache of its own.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("torch")
pytest.importorskip("pymunk")

import tpnet_ref  # noqa: E402
from background import early, seeded_cache  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
SCRIPT = REPO / "tools" / "gpu_train.sh"


def _call(work: Path, *args: str, **env: str) -> str:
    e = {**seeded_cache(work.parent), "WORK": str(work), "PY": sys.executable, "NAME": "ci",
         "M": "4", "SIZE": "tiny", "INIT": "", "BUDGET": "", "BATCH": "8", "LR": "3e-3",
         "MATCH": "4", "WORKERS": "1", "THREADS": "1", "COMPILE": "eager", "OPTIM": "none",
         "DATA_ARGS": "--forces 1.3 --angles 200 245 --positions 2 --steps 100 --whole 0",
         "TRAIN_ARGS": "--epochs 2 --val-fraction 0.25 --warmup-steps 2 --val-windows 0",
         **env}
    r = subprocess.run(["bash", str(SCRIPT), *args], env=e, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
    return r.stdout


def _returned(out: Path) -> list[Path]:
    files = [p for p in out.rglob("*") if p.is_file()]
    assert 0 < len(files) <= 8 and all(p.stat().st_size <= 16 << 20 for p in files)
    assert all(len(p.relative_to(out).parts) <= 3 for p in files)     # $OUT/a/b/file at most
    return files


def _two_calls(tmp_path: Path) -> Path:
    work = tmp_path / "repo"
    work.mkdir()
    out1 = _call(work, OUT=str(tmp_path / "out1"), STOP_STEP="6")
    assert "step 6/14" in out1 and "max_steps" in out1
    back = tmp_path / "files_at"                        # what a device call brings back here
    shutil.copytree(tmp_path / "out1", back)
    names = {p.name for p in _returned(back)}
    assert {"checkpoint.json", "log.jsonl", "checkpoint.pt.000"} <= names
    shutil.rmtree(work / ".gpu")                        # a fresh machine: only the parts remain
    _call(work, "collect", str(back))
    shutil.copy(work / "runs" / "gpu-ci.h5", tmp_path / "first.h5")   # the weights of call 1

    out2 = _call(work, OUT=str(tmp_path / "out2"))       # the next call, data kept (warm)
    assert "step 14/14" in out2 and "done" in out2
    _returned(tmp_path / "out2")
    state = json.loads((work / ".gpu" / "ci" / "checkpoint.json").read_text())
    assert state["step"] == state["total_steps"] == 14
    assert state["optimizer_resets"] == [6]             # model-only parts: a fresh Adam at 6
    assert [c["mode"] for c in state["compile"]] == ["eager", "eager"]
    steps = [json.loads(s)["step"] for s in (work / ".gpu" / "ci" / "log.jsonl").open()]
    assert steps[0] == 0 and steps[-1] == 14 and steps == sorted(steps)
    return tmp_path / "first.h5"


@early(_two_calls)
def test_two_calls_resume_from_the_parts_that_came_back(early_result):
    first = tpnet_ref.load(early_result)                 # what `collect` exported after call 1
    assert first.meta["training_steps"] == 6 and first.config.lstm_units == (8, 8, 8)


def _released_preset(tmp_path: Path) -> None:
    work = tmp_path / "repo"
    work.mkdir()
    out = _call(work, OUT=str(tmp_path / "out"), PRESET="released", OPTIM="full", MATCH="0",
                COMPILE="off", BENCH="1", BENCH_BATCHES="4 8", BENCH_COMPILE="off",
                BATCH_AUTO="1", LR="3e-3",
                TRAIN_ARGS="--epochs 1 --val-fraction 0.25 --val-windows 0")
    picked = [ln for ln in out.splitlines() if ln.startswith("gpu_train: fastest batch")]
    assert len(picked) == 1
    batch = int(picked[0].split()[3])
    assert batch in (4, 8) and "gpu_train: bench batch 4 compile off:" in out
    assert (work / "data" / "grid-m4-released.h5").is_file()
    state = json.loads((work / ".gpu" / "ci" / "checkpoint.json").read_text())
    r = state["recipe"]
    assert (r["init"], r["windows"], r["schedule"], r["clip"], r["warmup_steps"], r["batch"],
            r["lr"]) == ("keras", "released", "constant", 0.0, 0, batch, 3e-3)
    assert "optimizer_resets" not in state
    assert len(_returned(tmp_path / "out")) >= 3


@early(_released_preset)
def test_the_released_preset_starts_from_scratch_on_released_windows(early_result):
    """PRESET=released: the grid made with --windows released, a new run with the authors'
    recipe (Keras initialisation, constant rate, no clipping) whose Adam state comes back."""


def test_unknown_subcommand_is_refused(tmp_path):
    r = subprocess.run(["bash", str(SCRIPT), "bogus"], env={**os.environ, "WORK": str(tmp_path)},
                       capture_output=True, text=True)
    assert r.returncode == 2 and "usage" in r.stderr


def test_the_cli_lists_the_loops_compile_modes():
    from tpnet_ref.cli import train as cli_train
    from tpnet_ref.training import precision

    assert cli_train.COMPILE_MODES == precision.COMPILE_MODES
    assert precision.resolve_compile("auto", "cuda") == "reduce-overhead"
    assert precision.resolve_compile("auto", "cpu") == "off"
    with pytest.raises(ValueError, match="compile must be one of"):
        precision.resolve_compile("fast", "cpu")


def _in_pieces(tmp_path: Path) -> None:
    """The full network's state with Adam's (85 MB) is more than one call may bring back (64
    MiB) or carry up (64 MiB with the tree): `rest` calls return what a call could not, `collect`
    takes them all and refuses an incomplete set, `stage` cuts the state in bundles, `receive`
    keeps each on the machine, and the training call of a fresh machine resumes from them with
    Adam's state. The limits are scaled down to the tiny network's 125 kB state."""
    work = tmp_path / "repo"
    work.mkdir()
    lim = dict(PRESET="released", OPTIM="full", MATCH="0", COMPILE="off", PART_MIB="0.03",
               MAX_TOTAL_MIB="0.08", UP_MIB="0.05",
               TRAIN_ARGS="--epochs 4 --val-fraction 0.25 --val-windows 0")
    out = _call(work, OUT=str(tmp_path / "o0"), STOP_STEP="2", **lim)
    assert "files stay on the machine" in out
    backs = [tmp_path / "o0"]
    while (work / ".gpu" / "ci.rest").is_file():        # the next calls, on the warm machine
        backs.append(tmp_path / f"o{len(backs)}")
        _call(work, "rest", OUT=str(backs[-1]), **lim)
        _returned(backs[-1])
        assert sum(p.stat().st_size for p in backs[-1].rglob("*") if p.is_file()) <= 0.08 * 2**20
    assert len(backs) >= 2
    state = json.loads((work / ".gpu" / "ci" / "checkpoint.json").read_text())
    shutil.rmtree(work / ".gpu")                        # the machine went back
    e = {**seeded_cache(tmp_path), "WORK": str(work), "PY": sys.executable, "NAME": "ci"}
    bad = subprocess.run(["bash", str(SCRIPT), "collect", str(backs[0])], env=e,
                         capture_output=True, text=True)
    assert bad.returncode != 0 and "did not come back" in bad.stderr
    assert not (work / ".gpu" / "ci").exists()
    _call(work, "collect", *map(str, backs), **lim)
    assert json.loads((work / ".gpu" / "ci" / "checkpoint.json").read_text()) == state

    staged = _call(work, "stage", **lim)                 # here: bundles for a fresh machine
    bundles = sorted((work / ".up" / "ci").iterdir(), key=lambda p: int(p.name))
    assert len(bundles) >= 3 and f"device call {len(bundles)}" in staged
    fresh = tmp_path / "fresh"                           # a new machine: the data, no .gpu
    (fresh / "data").mkdir(parents=True)
    shutil.copy(work / "data" / "grid-m4-released.h5", fresh / "data")
    for b in bundles[:-1]:                               # one call per bundle: carry + receive
        shutil.copytree(b, fresh / ".up" / "ci" / b.name)
        assert "not on the machine yet" in _call(fresh, "receive", **lim)
    stuck = subprocess.run(["bash", str(SCRIPT)], capture_output=True, text=True,
                           env={**e, "WORK": str(fresh), "OUT": str(tmp_path / "x"), **lim})
    assert stuck.returncode == 3 and not (fresh / ".gpu" / "ci").exists()
    shutil.copytree(bundles[-1], fresh / ".up" / "ci" / bundles[-1].name)
    out = _call(fresh, OUT=str(tmp_path / "last"), **lim)
    assert "assembled from" in out and "step 4/4" in out
    end = json.loads((fresh / ".gpu" / "ci" / "checkpoint.json").read_text())
    assert "optimizer_resets" not in end                # Adam's state came up with the model
    assert end["windows_seen"] > state["windows_seen"] and not (fresh / ".up" / "ci").exists()


@early(_in_pieces)
def test_a_state_over_the_devices_limits_goes_back_and_up_in_pieces(early_result):
    """A state over a call's limits goes back in pieces and up in bundles (``_in_pieces``)."""

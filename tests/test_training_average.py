"""``tpnet train average`` (tpnet_ref.training.average): the weighted mean of fine-tunes of one
network, NumPy only. The mean is exact (float64 sum, one rounding), the predictions of the
average are what the averaged parameters give, the provenance names every input with its
weight and digest, and everything that would make a broken network is refused in one line."""
from __future__ import annotations

import json

import numpy as np
import pytest

from tpnet_ref import load
from tpnet_ref.weights import native
from tpnet_ref.cli import main
from tpnet_ref.config import TPNetConfig, param_shapes
from tpnet_ref.training.average import average

TINY = TPNetConfig(mlp1=(4, 4), mlp2=(4, 8), global_features=6, lstm_units=(5, 3), n_out=7)


def _write(path, params, **meta):
    native.write_native(path, TINY, params, "float32", meta or {"source": str(path.name)})
    return path


@pytest.fixture
def family(tmp_path):
    """A parent file and two fine-tunes of it (small perturbations: one basis)."""
    rng = np.random.default_rng(0)
    base = {k: rng.standard_normal(s).astype(np.float32) for k, s in param_shapes(TINY).items()}
    kids = [{k: (v + 0.05 * rng.standard_normal(v.shape)).astype(np.float32)
             for k, v in base.items()} for _ in range(2)]
    p0 = _write(tmp_path / "parent.h5", base, source="runs/parent", training_steps=100,
                epochs=10.0, windows_seen=1000, wall_time_s=60.0, hardware="cpu")
    p1 = _write(tmp_path / "a.h5", kids[0], source="runs/a", training_steps=150, epochs=15.0,
                windows_seen=1500, wall_time_s=90.0, hardware="cuda:GPU")
    p2 = _write(tmp_path / "b.h5", kids[1], source="runs/b", training_steps=120, epochs=12.0,
                windows_seen=1200, wall_time_s=70.0, hardware="cpu")
    return [p0, p1, p2], [base] + kids


def test_the_average_is_the_weighted_mean_of_the_parameters(family, tmp_path):
    paths, params = family
    out = tmp_path / "avg.h5"
    average(paths[:2], out, [0.25, 0.75])
    _, got, _ = native.read_native(out)
    for k, v in got.items():
        want = (0.25 * params[0][k].astype(np.float64)
                + 0.75 * params[1][k].astype(np.float64)).astype(np.float32)
        assert v.dtype == np.float32
        np.testing.assert_array_equal(v, want)
    # equal weights by default, any number of files
    average(paths, out)
    _, got, _ = native.read_native(out)
    k = "head.w"
    want = sum(p[k].astype(np.float64) for p in params) / 3
    np.testing.assert_allclose(got[k], want, rtol=1e-6, atol=1e-7)


def test_the_average_predicts_what_its_parameters_give(family, tmp_path):
    paths, params = family
    out = tmp_path / "avg.h5"
    average(paths[1:], out)
    mean = {k: ((params[1][k].astype(np.float64) + params[2][k]) / 2).astype(np.float32)
            for k in params[1]}
    ref = tmp_path / "ref.h5"
    _write(ref, mean)
    w = np.random.default_rng(1).uniform(5, 30, (3, TINY.m, 7, 2))
    np.testing.assert_array_equal(load(out).predict_batch(w), load(ref).predict_batch(w))


def test_provenance_names_every_input_and_keeps_the_longest_chain(family, tmp_path):
    paths, _ = family
    out = tmp_path / "avg.h5"
    average(paths, out, [0.5, 0.3, 0.2])
    meta = native.read_native(out)[2]
    parts = json.loads(meta["average_of"])
    assert [q["weight"] for q in parts] == [0.5, 0.3, 0.2]
    assert [q["content_sha256"] for q in parts] == [native.read_native(p)[2]["content_sha256"]
                                                     for p in paths]
    assert meta["source"] == "tpnet train average"
    assert json.loads(meta["recipe"]) == {"recipe": "average", "mix": [0.5, 0.3, 0.2],
                                          "files": [p.name for p in paths]}
    # the counters of the input with the most epochs (a.h5): the longest chain's compute
    assert int(meta["training_steps"]) == 150 and float(meta["epochs"]) == 15.0
    assert meta["hardware"] == "cpu; cuda:GPU"
    runs = json.loads(meta["parent_runs"])
    assert [r["steps"] for r in runs] == [100, 150, 120]
    text = native.describe(out)
    assert "average of   0.5 x " in text and "a.h5" in text
    # each run of the chain once, even where the inputs share it
    chain = [line for line in text.splitlines() if line.strip()[:2].rstrip(".").isdigit()]
    assert len(chain) == len(set(line.split(". ", 1)[1] for line in chain))
    # the average is a native file like any other: sealed, and damage is detected
    assert native.read_native(out)[2][native.DIGEST_ATTR].startswith("sha256:")


@pytest.mark.parametrize("mix, why", [([0.5], "1 weights for 2 files"),
                                      ([0.6, 0.6], "sum to 1"), ([1.5, -0.5], ">= 0"),
                                      ([float("nan"), 0.5], "sum to 1")])
def test_weights_that_do_not_fit_are_refused(family, tmp_path, mix, why):
    paths, _ = family
    with pytest.raises(ValueError, match=why.replace("(", r"\(")):
        average(paths[:2], tmp_path / "x.h5", mix)
    assert not (tmp_path / "x.h5").exists()


def test_one_file_or_another_network_or_another_basis_is_refused(family, tmp_path):
    paths, params = family
    with pytest.raises(ValueError, match="at least two"):
        average(paths[:1], tmp_path / "x.h5")
    other = TPNetConfig(mlp1=(4, 4), mlp2=(4, 8), global_features=6, lstm_units=(5, 3), n_out=7,
                        m=5)
    rng = np.random.default_rng(2)
    p5 = tmp_path / "m5.h5"
    native.write_native(p5, other, {k: rng.standard_normal(s).astype(np.float32)
                                    for k, s in param_shapes(other).items()}, "float32")
    with pytest.raises(ValueError, match=r"another network .*\(m 5 vs 4\)"):
        average([paths[0], p5], tmp_path / "x.h5")
    # the same shapes with the units of every layer shuffled: not the same basis
    shuffled = {k: rng.permutation(v.ravel()).reshape(v.shape) for k, v in params[0].items()}
    ps = _write(tmp_path / "shuffled.h5", shuffled)
    with pytest.raises(ValueError, match="not in the basis of .*parameter .* correlates"):
        average([paths[0], ps], tmp_path / "x.h5")
    assert not (tmp_path / "x.h5").exists()


def test_the_command_line(family, tmp_path, capsys):
    paths, _ = family
    out = tmp_path / "cli.h5"
    assert main(["train", "average", *map(str, paths[:2]), "--mix", "0.5", "0.5", "-o",
                 str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    ref = tmp_path / "ref.h5"
    average(paths[:2], ref)
    a, b = native.read_native(out)[1], native.read_native(ref)[1]
    assert all(np.array_equal(a[k], b[k]) for k in a)
    assert main(["train", "average", str(paths[0]), str(paths[1]), "--mix", "0.3", "0.6", "-o",
                 str(tmp_path / "y.h5")]) != 0
    err = capsys.readouterr().err
    assert "sum to 1" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "y.h5").exists()


def test_a_fine_tune_of_an_average_names_it_in_its_chain(family, tmp_path):
    """The chain of a file fine-tuned from an average (its ``parent_runs`` entry, as
    ``--init-from`` records it) says what the average was."""
    from tpnet_ref.training.lineage import file_state, inherited

    paths, _ = family
    out = tmp_path / "avg.h5"
    average(paths[:2], out)
    child = tmp_path / "child.h5"
    _, params, _ = native.read_native(out)
    _write(child, params, source="runs/child", training_steps=200, epochs=20.0,
           parent_runs=json.dumps(inherited(out, file_state(out, native.read_native(out)[2]))
                                  ["runs"]))
    text = native.describe(child)
    assert "written by tpnet train average (the mean of 2 files)" in text

"""tpnet info / tpnet predict (tpnet_ref.cli.model, tpnet_ref.cli.files) and the parser's
one-line usage errors (tpnet_ref.cli)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from tpnet_ref.cli import main
from tpnet_ref.model import init_random


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    p = tmp_path_factory.mktemp("w") / "net.h5"
    init_random(seed=1).save(str(p), note="a test network")
    return str(p)


@pytest.fixture
def window(tmp_path):
    a = np.arange(30) * 2 * np.pi / 30
    ring = np.stack([20 + 2 * np.sin(a), 20 + 2 * np.cos(a)], axis=1)
    p = tmp_path / "w.npy"
    np.save(p, np.stack([ring + 0.2 * i for i in range(4)]))
    return str(p)


def test_predict_writes_exactly_the_path_given(tmp_path, weights, window, capsys):
    out = tmp_path / "pred.out"
    assert main(["predict", window, "--weights", weights, "--steps", "3", "-o", str(out)]) == 0
    assert out.is_file() and not (tmp_path / "pred.out.npy").exists()
    assert np.load(out, allow_pickle=False).shape == (3, 30, 2)
    assert str(out) in capsys.readouterr().out


def test_predict_warns_in_one_line_for_a_window_outside_the_training_range(
        tmp_path, weights, window, capsys):
    assert main(["predict", window, "--weights", weights, "--normalized"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tpnet predict: warning:")
    assert "normalized" in err[0]


@pytest.mark.parametrize("argv, msg", [
    (["predict", "W", "--steps", "abc"], "invalid int value: 'abc'"),
    (["predict"], "required"),
    (["no-such-command"], "invalid choice"),
])
def test_usage_errors_are_one_line(argv, msg, capsys, window):
    argv = [window if a == "W" else a for a in argv]
    with pytest.raises(SystemExit) as info:
        main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert info.value.code == 2 and len(err) == 1 and msg in err[0] and "--help" in err[0]


def test_a_text_file_named_npy_is_refused_without_numpy_pickle_hints(tmp_path, weights, capsys):
    p = tmp_path / "t.npy"
    p.write_text("hello\n")
    assert main(["predict", str(p), "--weights", weights]) == 2
    err = capsys.readouterr().err
    assert "not a numeric .npy array" in err and "pickle" not in err.lower()


def test_info_is_a_readable_summary_and_json_on_request(weights, capsys):
    assert main(["info", weights]) == 0
    out = capsys.readouterr().out
    assert "stored as float32" in out and "m=4 frames" in out
    assert max(len(line) for line in out.splitlines()) < 200
    assert main(["info", weights, "--json"]) == 0
    full = json.loads(capsys.readouterr().out)
    assert full["config"]["m"] == 4 and full["meta"]["note"] == "a test network"


@pytest.mark.parametrize("argv, engine", [
    ([], "numpy"),                                   # one window: loading numba costs more
    (["--steps", "1000"], "auto"),                   # a long rollout: the compiled engine
    (["--steps", "2", "--engine", "numba"], "numba"),
])
def test_predict_picks_the_engine_faster_for_its_work(monkeypatch, tmp_path, weights, window,
                                                     argv, engine):
    import tpnet_ref
    asked = []
    real = tpnet_ref.load

    def load(*a, **k):
        asked.append(k.get("engine"))
        return real(*a, **k)
    monkeypatch.setattr(tpnet_ref, "load", load)
    assert main(["predict", window, "--weights", weights, "-o", str(tmp_path / "p.npy")] + argv) == 0
    assert asked == [engine]

"""The shipped models (weights/tpnet-m{3,4,5}.h5): m = 4 is what `tpnet_ref.load()` returns; each
says where it came from, and what it reaches on the 60 held-out cases (docs/spec.md §5 protocol, 80
predictions); where they are looked up (environment, wheel, repository)."""
from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

import tpnet_ref
from tpnet_ref import evaluation as E
from tpnet_ref.sim.cases import TEST_CASES
from tpnet_ref.model import TPNetConfig, init_random
from tpnet_ref.weights import default_weights_path, shipped_weights_path
from tpnet_ref.weights import shipped as lookup

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


@pytest.fixture(scope="module")
def shipped():
    path = default_weights_path()
    assert path.is_file(), f"the shipped weights are missing: {path}"
    return tpnet_ref.load()


def test_default_load_is_the_full_m4_network(shipped):
    assert shipped.config == TPNetConfig()            # m = 4, released widths, Keras semantics
    assert shipped.config.m == 4 and shipped.config.n_out == 30
    assert shipped.dtype == np.float32
    for key in ("producer", "recipe", "windows_seen", "wall_time_s", "hardware"):
        assert key in shipped.meta, key


REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def weights_of(tmp_path_factory):
    """``weights_of(m)``: the shipped file for m; m = 3 and 5 are not tracked by git, so in a
    fresh clone they come from ``tools/restore_weights.sh`` (git history, SHA-256 checked)."""
    restored: list[Path] = []

    def get(m: int) -> Path:
        try:
            return shipped_weights_path(m)
        except FileNotFoundError:
            if not restored:
                dest = tmp_path_factory.mktemp("restored")
                r = subprocess.run(["bash", str(REPO / "tools" / "restore_weights.sh"), str(dest)],
                                   capture_output=True, text=True)
                if r.returncode != 0:
                    pytest.skip(f"tpnet-m{m}.h5 is not here and cannot be restored: {r.stderr.strip()}")
                restored.append(dest)
            return restored[0] / f"tpnet-m{m}.h5"
    return get


@pytest.fixture(scope="module")
def frames():
    return E.normalize(E.simulate_cases(np.asarray(TEST_CASES), rows=4 * (5 + 80), workers=1))


def test_the_example_window_is_the_simulated_training_grid_scene_it_says():
    w = tpnet_ref.example_window()
    np.testing.assert_array_equal(w, tpnet_ref.sim.simulate(1.3, 225.0, 28.6, 32.5)[0:16:4])
    assert (28.6, 32.5) not in {(c[2], c[3]) for c in TEST_CASES}


def test_the_other_window_lengths_are_shipped_with_their_m(weights_of):
    for m in (3, 5):
        model = tpnet_ref.load(weights_of(m))
        assert model.config == TPNetConfig(m=m) and model.dtype == np.float32
        chain = json.loads(model.meta["parent_runs"])          # fine-tuned from the m = 4 chain
        assert chain
        recipe = json.loads(model.meta["recipe"])
        if recipe.get("recipe") == "average":       # the mean of fine-tunes (tpnet train average)
            inputs = json.loads(model.meta["average_of"])
            assert len(inputs) >= 2 and all(e["content_sha256"] for e in inputs)
            assert chain[-1]["data"] == model.meta["data"]     # its inputs' runs, on its data
        else:
            assert recipe["config"]["m"] == m
    assert shipped_weights_path() == default_weights_path()
    with pytest.raises(ValueError, match="m = 3, 4 and 5"):
        shipped_weights_path(6)


@pytest.fixture(scope="module")
def rollout_of(frames, weights_of):
    """``rollout_of(m)``: (windows, truth, predictions) of the shipped m model, each made once."""
    done: dict[int, tuple] = {}

    def get(m: int) -> tuple:
        if m not in done:
            model = tpnet_ref.load(weights_of(m))
            windows, truth = E.split_protocol(frames, m, 80)
            done[m] = windows, truth, E.batched_rollout(model, windows, 80, normalized=True)
        return done[m]
    return get


@pytest.fixture(scope="module", params=[3, 4, 5], ids=lambda m: f"m{m}")
def rollouts(request, rollout_of):
    return rollout_of(request.param)


def _at(errs: dict, key: str, h: int) -> float:
    return float(errs[key][:, h - 1].mean())


@pytest.mark.parametrize("baseline", ["copy_last", "constant_velocity"])
def test_shipped_model_beats_the_baselines_on_position_error(rollouts, baseline):
    """E_p (mean over the 60 held-out cases) below both baselines at 40 and 80 predicted frames
    in the squared and the released readings, for every shipped m."""
    windows, truth, pred = rollouts
    ours = E.errors(truth, pred)
    theirs = E.errors(truth, getattr(E, baseline)(windows, 80))
    for key in ("Ep_squared", "Ep_released"):
        for h in (40, 80):
            a, b = _at(ours, key, h), _at(theirs, key, h)
            assert a < b, f"{key}@{h}: model {a:.4f} >= {baseline} {b:.4f}"


def test_shipped_model_shape_error_stays_near_copy_last(rollouts):
    """Regression guard for what the shipped models reach on E_s: within 1.5x of copying the
    last frame at 40 and 80 frames (m = 4: 1.13x and 1.25x; m = 5: 1.14x and 1.48x, released
    reading, docs/history.md), and the one-step shape error within 1.2x (m = 4) or 1.25x (m = 3
    and 5, fewer epochs) of the random-phase ring floor (0.147)."""
    windows, truth, pred = rollouts
    ours, base = E.errors(truth, pred), E.errors(truth, E.copy_last(windows, 80))
    for h in (40, 80):
        a, b = _at(ours, "Es_released", h), _at(base, "Es_released", h)
        assert a < 1.5 * b, f"Es_released@{h}: model {a:.4f} vs copy-last {b:.4f}"
    m = windows.shape[1]
    assert _at(ours, "Es_released", 1) < (1.2 if m == 4 else 1.25) * E.ring_phase_floor()


#: the paper's TP-Net rows in the squared reading (docs/spec.md §4): m -> (E_p@40, E_p@80)
PAPER_EP = {3: (0.094, 0.246), 4: (0.071, 0.164), 5: (0.101, 0.225)}


def test_shipped_model_keeps_the_shape_lead_over_the_paper(rollouts):
    """The shape target, squared reading: E_s at most 0.002 at 40 and 80
    predictions (the paper: 0.007-0.008), for every shipped m."""
    windows, truth, pred = rollouts
    ours = E.errors(truth, pred)
    for h in (40, 80):
        assert _at(ours, "Es_squared", h) <= 0.002, f"Es_squared@{h}: {_at(ours, 'Es_squared', h)}"


@pytest.mark.xfail(strict=True, reason="not reached: "
                   "the paper's position error in the squared reading at 40 and 80 predictions; "
                   "the shipped models reach 0.67/7.61 (m=3), 0.12/1.30 (m=4), 0.20/4.46 (m=5) "
                   "against 0.094/0.246, 0.071/0.164, 0.101/0.225 (docs/results.md), trained for "
                   "far fewer epochs than the paper's 100-120 (weights/MODEL_CARD.md); strict, so "
                   "meeting it turns this red until the marker is removed")
def test_shipped_model_reaches_the_papers_position_error(rollouts):
    windows, truth, pred = rollouts
    ours = E.errors(truth, pred)
    m = windows.shape[1]
    for h, paper in zip((40, 80), PAPER_EP[m]):
        assert _at(ours, "Ep_squared", h) <= paper, f"m={m} Ep_squared@{h}"


@pytest.mark.parametrize("size", [
    "half", "quarter"])
def test_reduced_size_halves_copy_lasts_position_error_at_80(size, frames):
    """The target for the reduced sizes: E_p@80 (squared reading, the 60 held-out
    cases) at most half of copying the last frame's, and E_s@80 at most the paper's 0.007."""
    model = tpnet_ref.load(size=size, engine="numpy")
    windows, truth = E.split_protocol(frames, 4, 80)
    ours = E.errors(truth, E.batched_rollout(model, windows, 80, normalized=True))
    base = E.errors(truth, E.copy_last(windows, 80))
    a, b = _at(ours, "Ep_squared", 80), _at(base, "Ep_squared", 80)
    assert a <= 0.5 * b, f"{size}: E_p@80 {a:.3f} > half of copy-last's {b:.3f}"
    assert _at(ours, "Es_squared", 80) <= 0.007


def test_shipped_rollout_stays_finite_and_in_the_box(rollouts):
    _, _, pred = rollouts
    assert np.isfinite(pred).all()
    assert pred.min() >= 0.0 and pred.max() <= 1.0       # sigmoid head, normalised box


# ------------------------------------------------------------------ the lookup
def _shipped(tmp_path, monkeypatch, wheel, repo):
    """A fake wheel dir holding ``wheel`` and a fake repository weights/ holding ``repo``."""
    w, r = tmp_path / "shipped", tmp_path / "weights"
    for d, ms in ((w, wheel), (r, repo)):
        d.mkdir()
        for m in ms:
            (d / f"tpnet-m{m}.h5").write_bytes(b"")
    monkeypatch.setattr(lookup, "SHIPPED_DIR", w)
    monkeypatch.setattr(lookup, "REPO_WEIGHTS_DIR", r)
    monkeypatch.delenv("TPNET_WEIGHTS_DIR", raising=False)
    return w, r


def test_shipped_lookup_prefers_env_then_wheel_then_repository(tmp_path, monkeypatch):
    w, r = _shipped(tmp_path, monkeypatch, wheel=[4], repo=[3, 4, 5])
    assert lookup.default_weights_path() == w / "tpnet-m4.h5"
    assert lookup.shipped_weights_path(3) == r / "tpnet-m3.h5"      # the wheel has m = 4 only
    assert lookup.weights_dir() == w
    env = tmp_path / "env"
    env.mkdir()
    (env / "tpnet-m4.h5").write_bytes(b"")
    monkeypatch.setenv("TPNET_WEIGHTS_DIR", str(env))
    assert lookup.default_weights_path() == env / "tpnet-m4.h5"
    assert lookup.weights_dir() == env
    with pytest.raises(FileNotFoundError, match="no shipped weights tpnet-m5.h5 in .*env"):
        lookup.shipped_weights_path(5)                                  # no silent fallback


def test_missing_model_in_a_wheel_install_is_one_line(tmp_path, monkeypatch):
    _shipped(tmp_path, monkeypatch, wheel=[4], repo=[])
    (tmp_path / "weights").rmdir()                                       # no repository checkout
    with pytest.raises(FileNotFoundError) as exc:
        lookup.shipped_weights_path(3)
    msg = str(exc.value)
    assert "\n" not in msg and "pass the path" in msg and "TPNET_WEIGHTS_DIR" in msg
    assert lookup.shipped_weights_path(4).parent.name == "shipped"
    with pytest.raises(ValueError, match="m = 3, 4 and 5"):
        lookup.shipped_weights_path(6)


def test_reduced_sizes_and_untracked_files_are_found_or_named(tmp_path, monkeypatch):
    w, r = _shipped(tmp_path, monkeypatch, wheel=[4], repo=[4])
    for size in lookup.SHIPPED_SIZES:
        (r / f"tpnet-m4-{size}.h5").write_bytes(b"")
        assert lookup.shipped_weights_path(4, size) == r / f"tpnet-m4-{size}.h5"
        with pytest.raises(ValueError, match="m = 4 only"):
            lookup.shipped_weights_path(3, size)
    assert lookup.shipped_weights_path(4, "full") == w / "tpnet-m4.h5"
    with pytest.raises(ValueError, match="no model is shipped at size='huge'"):
        lookup.shipped_weights_path(4, "huge")
    with pytest.raises(FileNotFoundError, match="tools/restore_weights.sh") as exc:
        lookup.shipped_weights_path(5)                  # not tracked by git: the command says how
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("name", sorted(lookup.UNTRACKED))
def test_loading_a_missing_untracked_file_by_path_names_the_restore_command(tmp_path, name):
    """``load("weights/tpnet-m3.h5")`` in a checkout without it says what ``load(m=3)`` says."""
    import tpnet_ref
    with pytest.raises(FileNotFoundError, match=r"weights file not found: .*tpnet-m\d\.h5 \(git "
                       r"does not track .*`bash tools/restore_weights.sh`") as exc:
        tpnet_ref.load(tmp_path / "weights" / name)
    assert "\n" not in str(exc.value)
    with pytest.raises(FileNotFoundError) as exc:        # any other missing file: the path only
        tpnet_ref.load(tmp_path / "weights" / "mine.h5")
    assert str(exc.value) == f"weights file not found: {tmp_path / 'weights' / 'mine.h5'}"


def test_load_by_size_reads_the_shipped_file(tmp_path, monkeypatch):
    import tpnet_ref
    _shipped(tmp_path, monkeypatch, wheel=[], repo=[])
    cfg = TPNetConfig(mlp1=(4, 4), mlp2=(4, 8), global_features=6, lstm_units=(5, 3), n_out=7)
    size = lookup.SHIPPED_SIZES[0]
    init_random(cfg).save(tmp_path / "weights" / f"tpnet-m4-{size}.h5")
    model = tpnet_ref.load(size=size)
    assert model.config == cfg
    with pytest.raises(ValueError, match="either a path or m= / size="):
        tpnet_ref.load(tmp_path / "weights" / f"tpnet-m4-{size}.h5", size=size)

"""tpnet_ref.evaluation: protocol indexing, baselines, orderings, report writer, demo and eval CLI.

Trained weights do not exist yet: everything runs on small random networks saved to tmp_path,
a few cases and short rollouts.
"""
from __future__ import annotations

import argparse
import importlib.util

import numpy as np
import pytest

pytest.importorskip("h5py")

from tpnet_ref import evaluation as E  # noqa: E402
from tpnet_ref.cli import main  # noqa: E402
from tpnet_ref.metrics import position_error  # noqa: E402
from tpnet_ref.model import TPNetConfig, init_random  # noqa: E402

SMALL = dict(input_tnet_mlp=(4, 8), input_tnet_fc=(8,), mlp1=(8, 8), feature_tnet_mlp=(8,),
             feature_tnet_fc=(8,), mlp2=(16, 32), global_features=16, lstm_units=(16, 8, 8))
HAS_MPL = importlib.util.find_spec("matplotlib") is not None


def small_model(m: int = 4, seed: int = 0, dtype: str = "float64"):
    return init_random(TPNetConfig(m=m, **SMALL), seed=seed, dtype=dtype)


@pytest.fixture(scope="module")
def weights_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("w") / "small_m4.h5"
    small_model(4, seed=3, dtype="float32").save(str(path))
    return str(path)


@pytest.fixture(scope="module")
def frames3():
    """Model frames of the first three held-out cases, long enough for m=4 + 6 predictions."""
    return E.simulate_cases(E.TEST_CASES[:3], E.FRAME_EVERY * 10 + 1, workers=1)


# ----------------------------------------------------------------------- protocol
def test_split_protocol_frame_indexing():
    C, F = 2, 20
    frames = np.broadcast_to(np.arange(F, dtype=float)[None, :, None, None], (C, F, 5, 2))
    for m in (3, 4, 5):
        inputs, targets = E.split_protocol(frames, m, 7)
        assert inputs[0, :, 0, 0].tolist() == list(range(m))              # frames 0..m-1
        assert targets[0, :, 0, 0].tolist() == list(range(m, m + 7))      # h-th -> frame m-1+h
    with pytest.raises(ValueError, match="too short"):
        E.split_protocol(frames, 4, 17)


def test_simulated_frames_are_every_fourth_row(frames3):
    from tpnet_ref.sim import simulate
    rows = simulate(*E.TEST_CASES[1], 41)
    assert frames3.shape == (3, 11, 30, 2)
    np.testing.assert_array_equal(frames3[1], rows[::4])
    np.testing.assert_array_equal(frames3[1, 0], rows[0])                  # frame 0 = initial ring


def test_evaluate_feeds_frames_0_to_m_minus_1(frames3):
    model = small_model(4)
    curves = E.evaluate(frames3, [E.ModelSpec("net", model)], ms=[4], horizon=5,
                        orderings=("given",))
    net = [c for c in curves if c.name == "net"][0]
    n = E.normalize(frames3)
    for c in range(3):
        pred = model.rollout(n[c, :4], 5, normalized=True)
        want = position_error(n[c, 4:9], pred, variant="released")
        np.testing.assert_allclose(net.err["Ep_released"][c], want, rtol=1e-9, atol=1e-12)
    copy = [c for c in curves if c.name == "copy last"][0]
    np.testing.assert_allclose(copy.err["Ep_released"][:, 0],
                               position_error(n[:, 4], n[:, 3], variant="released"))


def test_batched_rollout_matches_model_rollout():
    model = small_model(3, seed=1)
    w = np.random.default_rng(0).uniform(0.2, 0.8, (5, 3, 30, 2))
    got = E.batched_rollout(model, w, 4, batch=2)
    for b in range(5):
        np.testing.assert_allclose(got[b], model.rollout(w[b], 4, normalized=True),
                                   rtol=1e-10, atol=1e-12)
    world = E.batched_rollout(model, E.denormalize(w), 2, normalized=False)
    np.testing.assert_allclose(E.normalize(world), got[:, :2], atol=1e-9)
    with pytest.raises(ValueError, match="m=3"):
        E.batched_rollout(model, w[:, :2], 1)


# ----------------------------------------------------------------------- baselines
def uniform_motion(C=2, F=12, N=6, v=(0.01, -0.02)):
    """Points 1 apart on a line, all moving by ``v`` per frame."""
    base = np.stack([np.arange(N, dtype=float), np.zeros(N)], axis=1)
    base = base[None] + np.arange(C)[:, None, None] * 3.0
    return base[:, None] + np.arange(F)[None, :, None, None] * np.asarray(v)


def test_constant_velocity_exact_on_uniform_motion():
    frames = uniform_motion()
    inputs, targets = E.split_protocol(frames, 4, 8)
    pred = E.constant_velocity(inputs, 8)
    np.testing.assert_allclose(pred, targets, atol=1e-12)
    err = E.errors(targets, pred)
    for k, v in err.items():
        assert v.shape == (2, 8) and np.abs(v).max() < 1e-10, k


def test_copy_last_error_equals_displacement():
    v = np.array([0.01, -0.02])
    N, H = 6, 8
    frames = uniform_motion(N=N, v=v)
    inputs, targets = E.split_protocol(frames, 4, H)
    pred = E.copy_last(inputs, H)
    np.testing.assert_array_equal(pred, np.broadcast_to(inputs[:, -1:], pred.shape))
    err = E.errors(targets, pred)
    d = np.arange(1, H + 1) * np.linalg.norm(v)        # displacement after h frames
    # every point's nearest neighbour is its own displaced copy (spacing 1 >> displacement)
    np.testing.assert_allclose(err["Ep_released"], np.broadcast_to(2 * N * d, (2, H)), rtol=1e-12)
    np.testing.assert_allclose(err["Ep_paper"], np.broadcast_to(2 * d ** 2, (2, H)), rtol=1e-12)
    assert np.abs(err["Es_released"]).max() < 1e-12        # a translation keeps the shape


# ----------------------------------------------------------------------- orderings
def test_orderings_really_permute():
    rng = np.random.default_rng(5)
    w = rng.random((3, 4, 30, 2))
    key = lambda a: np.sort(a.view([("x", float), ("y", float)])[..., 0], axis=-1)  # noqa: E731
    assert np.array_equal(E.order_points(w, "given"), w)
    for o in E.ORDERINGS:
        got = E.order_points(w, o, seed=1)
        assert got.shape == w.shape
        assert np.array_equal(key(got), key(w))             # same points in every frame
    ax = E.order_points(w, "ascending_x")
    assert (np.diff(ax[..., 0], axis=-1) >= 0).all() and not np.array_equal(ax, w)
    dy = E.order_points(w, "descending_y")
    assert (np.diff(dy[..., 1], axis=-1) <= 0).all() and not np.array_equal(dy, w)
    sh = E.order_points(w, "shuffle", seed=1)
    assert not np.array_equal(sh, w)
    perms = [tuple(np.argsort(np.argsort(sh[0, f, :, 0]))) for f in range(4)]
    assert len(set(perms)) > 1                               # frames shuffled independently
    assert np.array_equal(sh, E.order_points(w, "shuffle", seed=1))      # deterministic
    with pytest.raises(ValueError, match="ordering"):
        E.order_points(w, "sideways")


def test_tpnet_invariant_and_constant_velocity_not(frames3):
    curves = E.evaluate(frames3, [E.ModelSpec("net", small_model(4))], ms=[4], horizon=3)
    by = {(c.name, c.ordering): c for c in curves}
    for o in E.ORDERINGS:
        np.testing.assert_array_equal(by[("net", o)].err["Ep_released"],
                                      by[("net", "given")].err["Ep_released"])
        np.testing.assert_allclose(by[("copy last", o)].err["Ep_released"],
                                   by[("copy last", "given")].err["Ep_released"], rtol=1e-12)
    assert (by[("constant velocity", "shuffle")].at(3)
            > 2 * by[("constant velocity", "given")].at(3))


# ----------------------------------------------------------------------- simulator rows
def test_sim_coarse_indexing():
    from tpnet_ref.sim import simulate
    case = E.TEST_CASES[0]
    np.testing.assert_array_equal(E.sim_coarse(case, 1, 6), simulate(*case, 21)[::4])
    np.testing.assert_array_equal(E.sim_coarse(case, 2, 6), simulate(*case, 11, dt=2 / 45)[::2])
    rows8 = simulate(*case, 4, dt=8 / 45)
    got = E.sim_coarse(case, 8, 6)                       # a state every 2 frames
    np.testing.assert_array_equal(got[::2], rows8[:3])
    np.testing.assert_allclose(got[1], 0.5 * (rows8[0] + rows8[1]))


def test_timing_table_rows(frames3):
    model = small_model(4, dtype="float32")
    rows = E.timing_table(frames3, np.asarray(E.TEST_CASES[:3]), [E.ModelSpec("net", model)],
                          m=4, horizon=3, repeats=1, peers=True)
    names = [r.name for r in rows]
    assert names[:2] == ["net NumPy float64", "net NumPy float32"]
    assert "copy last input frame" in names and "constant velocity" in names
    assert [n for n in names if n.startswith("pymunk")] == [
        f"pymunk simulator dt x{k}" for k in (1, 2, 4, 8)]
    t = {r.name: r for r in rows}
    assert t["pymunk simulator dt x1"].err["Ep_released"].max() == 0.0   # it is the reference
    f64 = t["net NumPy float64"].err["Ep_released"]
    np.testing.assert_allclose(t["net NumPy float32"].err["Ep_released"], f64, rtol=1e-3, atol=1e-4)
    for peer in ("net PyTorch", "net onnxruntime"):
        if t[peer].err:                                   # installed: same network, same errors
            np.testing.assert_allclose(t[peer].err["Ep_released"], f64, rtol=1e-3, atol=1e-4)
            assert t[peer].ms_batch > 0
    md = E.timing_md(rows, 3)
    assert "ms/frame (batch of 3)" in md and "E_p @3" in md
    rep = E.Report(command="x", n_cases=3, horizon=3, source="s", curves=_fake_curves(H=3),
                   timing=rows, models=["w.h5"])
    text = E.render_markdown(rep)
    assert "## Error against run time" in text and "Fastest here for one rollout: net" in text


def test_generalisation_cases_outside_training_ranges():
    g = E.generalisation_cases(10, seed=0)
    assert set(g) == {"force > 1.6", "angle outside 180-270", "start near other walls"}
    assert (g["force > 1.6"][:, 0] > 1.6).all()
    a = g["angle outside 180-270"][:, 1]
    assert ((a < 180) | (a > 270)).all()
    xy = g["start near other walls"][:, 2:]
    assert (xy.min(axis=1) <= 8.0).all() and (xy >= 2.85).all()
    for cases in g.values():
        assert cases.shape == (10, 4)
    np.testing.assert_array_equal(g["force > 1.6"], E.generalisation_cases(10, 0)["force > 1.6"])


# ----------------------------------------------------------------------- report writer
def _fake_curves(m=4, H=90, names=("copy last", "TP-Net x.h5")):
    out = []
    for i, n in enumerate(names):
        for o in E.ORDERINGS:
            err = {f"{k}_{v}": np.tile(np.linspace(0.01, 1, H) * (i + 1), (3, 1))
                   for k in ("Ep", "Es") for v in E.VARIANTS}
            out.append(E.Curve(n, m, o, err))
    return out


def test_markdown_tables():
    assert E.md_table(["a", "b"], [[1, "x"]]) == "| a | b |\n|---|---|\n| 1 | x |"
    curves = _fake_curves()
    t = E.results_tables(curves)
    lines = t.splitlines()
    assert lines[0] == "| m | method | E_p @40 | E_s @40 | E_p @80 | E_s @80 |"
    assert lines[2] == "| 4 | TP-Net, paper (SPEC §4) | 0.071 | 0.007 | 0.164 | 0.007 |"
    want40 = f"{np.linspace(0.01, 1, 90)[39]:.3f}"
    assert lines[3].startswith(f"| 4 | copy last | {want40} |")
    assert "paper (SPEC" not in E.results_tables(curves, "paper")
    assert len(E.ordering_table(curves).splitlines()) == 2 + 8
    short = _fake_curves(H=5)
    assert "E_p @5" in E.results_tables(short)            # horizons beyond the rollout dropped


def test_write_results_structure(tmp_path):
    rep = E.Report(command="tpnet eval --baselines-only", n_cases=3, horizon=90,
                   source="test", curves=_fake_curves(), timing=None,
                   generalisation={"force > 1.6": _fake_curves()})
    path = E.write_results(rep, tmp_path / "out", plots=False)
    text = path.read_text()
    assert path.name == "results.md"
    for s in ("`tpnet eval --baselines-only`", "No trained weights yet", "## Protocol",
              "## Input orderings", "### force > 1.6", "0.071"):
        assert s in text, s
    csv = (tmp_path / "out" / "eval_curves.csv").read_text().splitlines()
    assert csv[0] == "group,method,m,ordering,step,frame,Ep_released,Es_released,Ep_paper,Es_paper"
    assert len(csv) == 1 + 2 * 2 * 4 * 90                  # (test + 1 group) x 2 names x 4 x 90
    assert csv[1].startswith("test,copy last,4,given,1,4,")  # step 1 -> frame m
    assert "eval_curves.csv" in text
    rep.models = ["w.h5"]
    assert "No trained weights yet" not in E.render_markdown(rep)


# ----------------------------------------------------------------------- CLI
def test_demo_without_shipped_weights_exits_2(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("TPNET_WEIGHTS_DIR", str(tmp_path))
    monkeypatch.chdir(tmp_path)
    assert main(["demo"]) == 2
    err = capsys.readouterr().err
    assert "tpnet demo: error: no shipped weights" in err
    assert not list(tmp_path.iterdir())                   # nothing faked, nothing written


def test_demo_with_weights_prints_errors(weights_file, tmp_path, capsys):
    png = tmp_path / "demo.png"
    args = ["demo", "--weights", weights_file, "--steps", "12", "--horizons", "1", "10", "40",
            "-o", str(png)]
    if not HAS_MPL:
        args.append("--no-png")
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "shuffled" in out and "ms/frame" in out
    lines = [ln.split() for ln in out.splitlines() if ln.strip()[:1].isdigit()]
    assert [ln[:2] for ln in lines] == [["1", "4"], ["10", "13"]]   # step h -> frame m-1+h
    assert all(np.isfinite(float(x)) for ln in lines for x in ln[2:])
    if HAS_MPL:
        assert png.stat().st_size > 1000 and f"wrote {png}" in out


def test_demo_returns_numbers(weights_file, tmp_path):
    import io
    r = E.demo(weights_file, steps=3, horizons=(1, 3), png=None, out=io.StringIO())
    assert r["m"] == 4 and r["steps"] == 3 and set(r["errors"]) == {1, 3}
    assert r["errors"][1]["Ep_released"] > 0


def test_eval_cli_small(weights_file, tmp_path, capsys):
    out = tmp_path / "docs"
    args = ["eval", "--weights", weights_file, "--cases", "2", "--horizon", "3", "--out", str(out),
            "--no-timing", "--quiet"]
    if not HAS_MPL:
        args.append("--no-plots")
    assert main(args) == 0
    text = (out / "results.md").read_text()
    assert "TP-Net small_m4.h5" in text and "E_p @3" in text and "descending_y" in text
    assert f"`tpnet eval --weights {weights_file} --cases 2 --horizon 3 --out {out}`" in text
    assert "No trained weights" not in text
    if HAS_MPL:
        assert {p.name for p in out.glob("*.png")} == {"eval_error_vs_frame.png",
                                                       "eval_gallery.png"}


def test_eval_cli_needs_weights_or_baselines_only(tmp_path, capsys):
    assert main(["eval", "--out", str(tmp_path)]) == 2
    assert "--baselines-only" in capsys.readouterr().err
    assert main(["eval", "--weights", str(tmp_path / "nope.h5"), "--out", str(tmp_path)]) == 2


def test_eval_baselines_only_with_timing(tmp_path):
    pytest.importorskip("matplotlib")
    ns = argparse.Namespace(weights=[], baselines_only=True, m=None, data=None, cases=2,
                            horizon=2, orderings=list(E.ORDERINGS), no_timing=False,
                            no_peers=True, repeats=1, generalisation=True, gen_cases=1,
                            workers=1, seed=0, out=str(tmp_path), no_plots=False, quiet=True)
    path = E.run_eval(ns, command="tpnet eval --baselines-only")
    text = path.read_text()
    assert "No trained weights yet" in text and "pymunk simulator dt x8" in text
    assert "### start near other walls" in text
    assert (tmp_path / "eval_error_vs_time.png").is_file()
    assert (tmp_path / "eval_generalisation.png").is_file()


def test_eval_from_dataset_file(tmp_path):
    from tpnet_ref.data import generate, train_grid
    path = str(tmp_path / "d.h5")
    generate(path, train_grid(positions=1)[:1], np.asarray(E.TEST_CASES[:2]), steps=49,
             progress=False)
    base = dict(weights=[], baselines_only=True, m=[4], cases=None, horizon=3,
                orderings=["given"], no_timing=True, no_peers=True, repeats=1,
                generalisation=False, gen_cases=1, workers=1, seed=0, no_plots=True, quiet=True)
    a = E.run_eval(argparse.Namespace(data=path, out=str(tmp_path / "a"), **base), command="x")
    b = E.run_eval(argparse.Namespace(data=None, out=str(tmp_path / "b"), **dict(base, cases=2)),
                   command="x")
    ta, tb = a.read_text(), b.read_text()
    assert "test split of" in ta and "2 cases" in ta
    # the same numbers from the file (float32 positions) as simulated on the fly: E_p equal to
    # the printed digits (E_s of the baselines is ~0 and only shows the float32 rounding)
    def ep_cells(text):
        rows = text.split("## Rollout error")[1].split("Same, paper metric")[0].splitlines()
        return [r.split("|")[:4] for r in rows if r.startswith("| 4 |")]
    assert ep_cells(ta) == ep_cells(tb) and len(ep_cells(ta)) == 2


def test_ring_phase_floor_matches_its_closed_form():
    """E_s of the rest ring against itself turned by phase φ is 60 · 2r·sin(d/2), d = the
    angular distance to the nearest particle (both directions alike); averaged over φ uniform
    in one spacing this is the floor results.md quotes."""
    from tpnet_ref.metrics import shape_error
    from tpnet_ref.config import NORM_HI, NORM_LO
    n, r = 30, 2.0 / (NORM_HI - NORM_LO)
    s = 2 * np.pi / n
    ph = (np.arange(720) + 0.5) / 720 * s
    d = np.minimum(ph, s - ph)
    closed = float(np.mean(60 * 2 * r * np.sin(d / 2)))
    assert E.ring_phase_floor() == pytest.approx(closed, rel=1e-9)
    assert 0.14 < closed < 0.15
    a = 2 * np.pi * np.arange(n) / n
    ring = np.stack([r * np.sin(a), r * np.cos(a)], -1)
    assert shape_error(ring, ring[::-1] + 0.3, variant="released") == pytest.approx(0, abs=1e-12)


def _ring(n=30, r=2.0, turn_deg=0.0, centre=(10.0, 20.0)):
    """The body's start ring (SPEC §5 particle order), turned counter-clockwise by turn_deg."""
    a = 2 * np.pi * np.arange(n) / n - np.radians(turn_deg)
    return np.stack([centre[0] + r * np.sin(a), centre[1] + r * np.cos(a)], -1)


@pytest.mark.parametrize("turn", [0.0, 5.0, -30.0, 179.0])
def test_ring_rotation_reads_how_far_the_body_has_turned(turn):
    assert E.ring_rotation(_ring(turn_deg=turn)) == pytest.approx(turn, abs=1e-9)
    moved = _ring(turn_deg=turn, centre=(30.0, 5.0))        # any place, and batched
    np.testing.assert_allclose(E.ring_rotation(np.stack([moved, moved])), [turn, turn], atol=1e-9)
    with pytest.raises(ValueError, match="particle order"):
        E.ring_rotation(moved[:29])


def test_resample_outline_spaces_points_evenly_along_the_same_polygon():
    """An evenly spaced ring comes back as itself (offset 0) or turned by half a spacing
    (offset 0.5); a ring with one point moved onto its neighbour (a clump and a gap) comes back
    evenly spaced, on the clumped polygon."""
    from tpnet_ref.metrics import shape_error
    ring = _ring()
    rng = np.random.default_rng(1)
    shuffled = ring[rng.permutation(30)][None]
    back = E.resample_outline(shuffled)
    assert shape_error(ring, back[0], variant="released") == pytest.approx(0, abs=1e-9)
    half = E.resample_outline(shuffled, 0.5)[0]              # midpoints of the polygon's sides
    mid = 0.5 * (ring + np.roll(ring, -1, axis=0))
    assert shape_error(mid, half, variant="released") == pytest.approx(0, abs=1e-9)
    clumped = ring.copy()
    clumped[7] = ring[8] + 1e-3
    st0 = E.spacing_stats(E.normalize(clumped)[None])
    st1 = E.spacing_stats(E.normalize(E.resample_outline(clumped[None], [0.25])))
    assert st0["nn_min"] < 0.01 and st1["nn_min"] > 0.38      # world units; the ring has 0.418
    d = np.linalg.norm(np.diff(E.resample_outline(clumped[None])[0], axis=0), axis=1)
    assert d.std() < 0.05 * d.mean()
    with pytest.raises(ValueError, match="sets"):
        E.resample_outline(ring)


def test_radial_fit_reads_radius_squash_and_raggedness():
    """A circle fits with its radius and no residual; an ellipse (a mode-2 squash) needs mode 2;
    a ragged ring (every other point pushed out) leaves its raggedness in the residual."""
    a = 2 * np.pi * np.arange(30) / 30
    circle = _ring(r=2.0)
    coef, res = E.radial_fit(circle[None], modes=4)
    assert coef[0, 0] == pytest.approx(2.0, abs=1e-9)
    np.testing.assert_allclose(coef[0, 1:], 0, atol=1e-9)
    np.testing.assert_allclose(res, 0, atol=1e-9)
    ellipse = np.stack([2.2 * np.cos(a), 1.8 * np.sin(a)], -1)
    _, r0 = E.radial_fit(ellipse[None], modes=0)
    c2, r2 = E.radial_fit(ellipse[None], modes=2)
    assert c2[0, 3] > 0.15 and np.abs(r2).max() < 0.2 * np.abs(r0).max()
    ragged = circle + 0.05 * np.where(np.arange(30) % 2, 1, -1)[:, None] * (circle - circle.mean(0)) / 2
    _, rr = E.radial_fit(ragged[None], modes=4)
    assert np.abs(rr).mean() == pytest.approx(0.05, rel=1e-6)
    with pytest.raises(ValueError, match="sets"):
        E.radial_fit(circle)


@pytest.mark.parametrize("phase", [0.0, 0.1])
def test_radial_outline_is_the_evenly_spaced_smooth_outline(phase):
    """modes = 0 turns a ragged, clumped, shuffled ring into the evenly spaced circle of its
    mean radius at the given phase; a circle at that phase comes back unchanged."""
    from tpnet_ref.metrics import shape_error
    a = 2 * np.pi * np.arange(30) / 30 + phase
    circle = np.stack([3 + 2 * np.cos(a), 4 + 2 * np.sin(a)], -1)
    np.testing.assert_allclose(E.radial_outline(circle[None], 0, phase)[0], circle, atol=1e-12)
    rng = np.random.default_rng(0)
    messy = circle * 1.0
    messy[3] = messy[4] + 1e-3
    messy = (messy - messy.mean(0)) * (1 + 0.01 * rng.standard_normal((30, 1))) + messy.mean(0)
    out = E.radial_outline(messy[rng.permutation(30)][None], 0, [phase])[0]
    r = np.linalg.norm(out - out.mean(0), axis=1)
    assert r.std() < 1e-12
    assert shape_error(circle, out, variant="released") < 0.05 * 60
    ang = np.unwrap(np.arctan2(*(out - out.mean(0)).T[::-1]))
    assert ang[0] == pytest.approx(phase, abs=1e-12)
    np.testing.assert_allclose(np.diff(ang), 2 * np.pi / 30, atol=1e-12)

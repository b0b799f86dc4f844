"""tpnet_ref.evaluation.plots: every figure is written, and what a reader sees is whole -- no title
cut at the figure's edges, no legend over the points, the timing markers explained -- and
tools/redraw_eval_figures.py reads back what ``tpnet eval`` writes."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from tpnet_ref import evaluation as E  # noqa: E402
from tpnet_ref.evaluation import plots as P  # noqa: E402
from evaluation_helpers import fake_curves  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def kept_figures(monkeypatch):
    """The figures the plot functions close, kept open to be measured."""
    import matplotlib.pyplot as plt
    close, figs = plt.close, []
    monkeypatch.setattr(plt, "close", figs.append)
    yield figs
    for f in figs:
        close(f)


def _png(path: Path) -> np.ndarray:
    from matplotlib.image import imread
    assert path.is_file() and path.stat().st_size > 5_000, path
    return imread(path)


def _inside(fig, artist) -> bool:
    fig.canvas.draw()
    box = artist.get_window_extent(fig.canvas.get_renderer())
    W, H = fig.bbox.width, fig.bbox.height
    return box.x0 >= 0 and box.y0 >= 0 and box.x1 <= W and box.y1 <= H


def _timing_rows(h: int = 80) -> list[E.TimingRow]:
    def err(v40: float, v80: float) -> dict[str, np.ndarray]:
        e = np.zeros((2, h))
        e[:, 39], e[:, 79] = v40, v80
        return {f"Ep_{E.HEADLINE}": e}
    rows = [E.TimingRow(f"net {i}", 1.0, 2.0 + i, err(0.1 * (i + 1), 1.0 + i)) for i in range(8)]
    rows += [E.TimingRow("copy last input frame", 1e-4, 1e-4, err(20.0, 14.0), kind="baseline"),
             E.TimingRow("pymunk simulator dt x1", 0.5, 0.5, err(0.0, 0.0), kind="simulator"),
             E.TimingRow("not installed", None, None, {})]
    return rows


@pytest.mark.parametrize("n_models", [1, 3])
def test_models_figure_title_is_whole(tmp_path, kept_figures, n_models):
    """One model gives one narrow column: the title wraps instead of running off both sides."""
    curves = [c for m in (3, 4, 5)[:n_models] for c in fake_curves(m=m, H=90)]
    path = P.plot_models(curves, tmp_path / "f.png")
    img = _png(path)
    fig = kept_figures[-1]
    assert _inside(fig, fig._suptitle), fig._suptitle.get_text()
    assert ("\n" in fig._suptitle.get_text()) == (n_models == 1)
    assert img.shape[1] == pytest.approx(4.6 * n_models * 90, abs=2)


def test_timing_figure_legend_is_beside_the_points_and_says_what_the_markers_mean(tmp_path,
                                                                                   kept_figures):
    path = P.plot_timing(_timing_rows(), tmp_path / "t.png")
    _png(path)
    fig = kept_figures[-1]
    (ax,), (legend,) = fig.axes, fig.legends
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    lbox, abox = legend.get_window_extent(r), ax.get_window_extent(r)
    assert lbox.x0 >= abox.x1 and _inside(fig, legend)     # beside the axes, not over points
    texts = [t.get_text() for t in legend.get_texts()]
    assert texts[:2] == ["hollow: after 40 predictions", "filled: after 80 predictions"]
    assert "pymunk simulator dt x1 (reference, error 0)" in texts
    assert "not installed" not in texts and texts.count("net 0") == 1
    assert "hollow" not in ax.get_ylabel()


def test_timing_figure_of_short_rollouts_has_no_marker_key(tmp_path, kept_figures):
    """Rollouts shorter than 40: one filled marker per row, nothing to explain."""
    rows = [E.TimingRow("net", 1.0, 2.0, {f"Ep_{E.HEADLINE}": np.full((2, 6), 0.5)})]
    P.plot_timing(rows, tmp_path / "t.png")
    texts = [t.get_text() for t in kept_figures[-1].legends[0].get_texts()]
    assert texts == ["net"]


def test_groups_gallery_and_demo_figures_are_written(tmp_path):
    P.plot_groups({"force > 1.6": fake_curves(H=20), "short": fake_curves(m=3, H=20)},
                  tmp_path / "g.png")
    rng = np.random.default_rng(0)
    truth = 22.5 + rng.normal(0, 2, (2, 10, 30, 2))
    preds = {"net": truth + rng.normal(0, 0.3, truth.shape),
             "far": truth + 100.0}                               # left the box: said on the panel
    P.plot_gallery(tmp_path / "gal.png", truth, preds, (1, 5, 40), ["case a", "case b"], m=4)
    frames = 22.5 + rng.normal(0, 2, (14, 30, 2))
    P.plot_demo(tmp_path / "d.png", frames, frames[4:] + 0.2, 4, (1, 5, 10), {1: "h = 1"},
                suptitle="demo")
    for name, min_w in (("g.png", 800), ("gal.png", 400), ("d.png", 1300)):
        assert _png(tmp_path / name).shape[1] >= min_w


def _redraw_tool():
    spec = importlib.util.spec_from_file_location("redraw_eval_figures",
                                                  REPO / "tools" / "redraw_eval_figures.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault(spec.name, mod)
    spec.loader.exec_module(mod)
    return mod


def test_redraw_tool_reads_back_what_tpnet_eval_writes(tmp_path, capsys):
    """write_results (what `tpnet eval` writes) -> the tool's readers give the same means and
    timings to the digits written -> both figures drawn from them."""
    tool = _redraw_tool()
    curves = fake_curves(m=4, H=90)
    rows = _timing_rows()
    rep = E.Report(command="tpnet eval", n_cases=2, horizon=90, source="test", curves=curves,
                   timing=rows)
    E.write_results(rep, tmp_path, plots=False)
    back = {(c.name, c.ordering): c for c in tool.read_curves(tmp_path / "eval_curves.csv")}
    assert len(back) == len(curves)
    for c in curves:
        np.testing.assert_allclose(back[c.name, c.ordering].mean(), c.mean(), rtol=5e-4)
    got = tool.read_timing(tmp_path / "results.md")
    assert [r.name for r in got] == [r.name for r in rows]
    for a, b in zip(got, rows):
        assert (a.ms_single is None) == (b.ms_single is None)
        if b.err:
            for h in (40, 80):
                assert a.err[f"Ep_{E.HEADLINE}"][0, h - 1] == pytest.approx(
                    b.err[f"Ep_{E.HEADLINE}"][:, h - 1].mean(), rel=5e-3)
    cases = {(c.name, c.ordering): c for c in tool.read_cases(tmp_path / "eval_cases.csv")}
    assert set(cases) == {(c.name, "given") for c in curves}        # the csv holds "given"
    for c in curves:
        if c.ordering == "given":
            for h in (40, 80):
                np.testing.assert_allclose(cases[c.name, "given"].err["Ep_squared"][:, h - 1],
                                           c.err["Ep_squared"][:, h - 1], rtol=1e-5)
    assert tool.main([str(tmp_path), "--out", str(tmp_path / "fig")]) == 0
    for name in ("eval_error_vs_frame.png", "eval_error_vs_time.png", "eval_spread.png"):
        _png(tmp_path / "fig" / name)
    with pytest.raises(ValueError, match="no curves of group 'nope'"):
        tool.read_curves(tmp_path / "eval_curves.csv", group="nope")
    (tmp_path / "x.md").write_text("# Evaluation results\n")
    with pytest.raises(ValueError, match="Error against run time"):
        tool.read_timing(tmp_path / "x.md")


def test_missing_matplotlib_names_the_plot_extra(tmp_path, monkeypatch):
    from tpnet_ref.extras import MissingExtraError
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(MissingExtraError, match=r"tpnet-ref\[plot\]"):
        P.plot_models(fake_curves(), tmp_path / "f.png")
    assert not (tmp_path / "f.png").exists()


def test_save_png_writes_few_colours_alike_to_matplotlibs_own(tmp_path):
    """save_png: a palette PNG (one palette of <= 256 colours, no dithering) of the same pixels
    as matplotlib's RGBA PNG to the eye, in fewer bytes; another suffix is matplotlib's."""
    from PIL import Image
    plt = P.pyplot()
    fig, ax = plt.subplots(figsize=(5, 3))
    x = np.linspace(0, 10, 200)
    for k in range(6):
        ax.plot(x, np.sin(x + k), label=f"curve {k}")
    ax.legend()
    ax.grid(True)
    ours, theirs = tmp_path / "a.png", tmp_path / "b.png"
    assert P.save_png(fig, ours, dpi=90) == ours
    fig.savefig(theirs, dpi=90)
    with Image.open(ours) as a, Image.open(theirs) as b:
        assert a.mode == "P" and len(a.getcolors(256)) <= 256
        pa = np.asarray(a.convert("RGB"), dtype=float)
        pb = np.asarray(b.convert("RGB"), dtype=float)
    assert pa.shape == pb.shape
    assert np.abs(pa - pb).mean() < 1.0 and (np.abs(pa - pb).max(axis=2) > 64).mean() < 1e-3
    assert ours.stat().st_size < theirs.stat().st_size
    with Image.open(P.save_png(fig, tmp_path / "d.png", dpi=90, colours=16)) as d:
        assert d.mode == "P" and len(d.getcolors(256)) <= 16
    svg = P.save_png(fig, tmp_path / "c.svg")
    assert svg.read_text().lstrip().startswith("<?xml")
    plt.close(fig)

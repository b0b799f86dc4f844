"""tpnet_ref.evaluation.report: the paper-style tables, the reading evidence, results.md and the csv.
"""
from __future__ import annotations


import numpy as np
import pytest

pytest.importorskip("h5py")

from tpnet_ref import evaluation as E  # noqa: E402
from evaluation_helpers import fake_curves  # noqa: E402,F401


def test_markdown_tables():
    assert E.md_table(["a", "b"], [[1, "x"]]) == "| a | b |\n|---|---|\n| 1 | x |"
    curves = fake_curves()
    t = E.results_tables(curves)
    lines = t.splitlines()
    assert lines[0] == "| m | method | E_p @40 | E_s @40 | E_p @80 | E_s @80 |"
    assert lines[2] == "| 4 | **TP-Net, paper** (docs/spec.md §4) | 0.071 | 0.007 | 0.164 | 0.007 |"
    want40 = f"{np.linspace(0.01, 1, 90)[39]:.3f}"
    assert lines[3].startswith("| 4 | **TP-Net x.h5** |")          # the model next to the paper
    assert lines[4].startswith(f"| 4 | copy last | {want40} [{want40}, {want40}] med {want40} |")
    assert E.report.fmt_err(0.00084) == "0.00084" and E.report.fmt_err(1.185) == "1.185"
    # the paper's row only in the reading its table was published in
    assert "TP-Net, paper" in E.results_tables(curves, "squared")
    assert "TP-Net, paper" not in E.results_tables(curves, "released")
    assert "TP-Net, paper" not in E.results_tables(curves, "paper")
    assert len(E.ordering_table(curves).splitlines()) == 2 + 8
    short = fake_curves(H=5)
    assert "E_p @5" in E.results_tables(short)            # horizons beyond the rollout dropped


def test_a_kept_section_survives_a_rewrite(tmp_path):
    rep = E.Report(command="tpnet eval --baselines-only", n_cases=3, horizon=90,
                   source="test", curves=fake_curves(), timing=None)
    path = E.write_results(rep, tmp_path, plots=False)
    path.write_text(E.put_kept_section(path.read_text(), "sizes", "## Network sizes\n\nv1"))
    path.write_text(E.put_kept_section(path.read_text(), "sizes", "## Network sizes\n\nv2"))
    assert path.read_text().count("## Network sizes") == 1 and "v2" in path.read_text()
    E.write_results(rep, tmp_path, plots=False)                   # tpnet eval again
    text = path.read_text()
    assert text.count("<!-- kept: sizes -->") == 1 and "v2" in text and "v1" not in text
    assert "## Protocol" in text


def test_write_results_structure(tmp_path):
    rep = E.Report(command="tpnet eval --baselines-only", n_cases=3, horizon=90,
                   source="test", curves=fake_curves(), timing=None,
                   generalisation={"force > 1.6": fake_curves()})
    path = E.write_results(rep, tmp_path / "out", plots=False)
    text = path.read_text()
    assert path.name == "results.md"
    for s in ("`tpnet eval --baselines-only`", "No weights given", "## Protocol",
              "## The paper's table, side by side (\"squared\" reading)",
              "## Which reading the paper's table is: the evidence", "### \"released\"",
              "### \"paper\"", "## Input orderings", "### force > 1.6", "0.071"):
        assert s in text, s
    csv = (tmp_path / "out" / "eval_curves.csv").read_text().splitlines()
    assert csv[0] == ("group,method,m,ordering,step,frame,Ep_squared,Es_squared,Ep_released,"
                      "Es_released,Ep_paper,Es_paper")
    assert len(csv) == 1 + 2 * 2 * 4 * 90                  # (test + 1 group) x 2 names x 4 x 90
    assert csv[1].startswith("test,copy last,4,given,1,4,")  # step 1 -> frame m
    assert "eval_curves.csv" in text
    rep.models = ["w.h5"]
    assert "No weights given" not in E.render_markdown(rep)
    # the headline comes before the other readings
    text = E.render_markdown(rep)
    assert text.index("side by side") < text.index("## The other readings")


def test_evidence_singles_out_the_squared_reading():
    """From the scene alone: every E_s of the paper's table lies below a perfect ring at a
    random rotation in the released reading, above the collapsed ring in the paper's
    equation, and between the two only in the squared reading (docs/spec.md §3)."""
    rows = {r["reading"]: r for r in E.evidence_rows(fake_curves())}
    assert rows["released"]["verdict"].startswith("impossible")
    assert rows["paper"]["verdict"].startswith("implausible")
    assert rows["squared"]["verdict"].startswith("consistent")
    assert rows["squared"]["floor"] == pytest.approx(0.00048, rel=0.01)
    assert rows["squared"]["collapsed"] == pytest.approx(0.1316, rel=0.01)
    assert rows["released"]["floor"] == pytest.approx(0.147, rel=0.01)
    assert rows["paper"]["collapsed"] == pytest.approx(0.00439, rel=0.01)
    assert set(rows["squared"]["copy_last"]) == {40, 80}
    md = E.evidence_md(fake_curves())
    assert "copy last (m=4) @40" in md and md.count("\n") == 4

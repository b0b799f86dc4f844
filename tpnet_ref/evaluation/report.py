"""``results.md`` and ``eval_curves.csv``: the tables of an evaluation run.

The headline is the paper's table side by side with ours in the ``"squared"`` reading (the one
the paper's numbers can physically be, docs/spec.md §3), followed by the evidence computed here
for each reading (a perfect ring at a random rotation, copy-last, the ring collapsed to its
centre); the ``"released"`` and ``"paper"`` readings come below.
"""
from __future__ import annotations

import datetime as _dt
import math
import os
import platform
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..config import NORM_HI, NORM_LO
from ..sim.protocol import FRAME_EVERY, HORIZONS, SIM_ROWS
from . import plots as P
from .run import HEADLINE, PAPER_TABLE, VARIANTS, Curve, table_horizons
from .shape import reading_evidence
from .spread import LEVEL, N_RESAMPLES, SEED, fmt_err, fmt_spread, spread  # noqa: F401  (fmt_err re-exported)
from .timing import TimingRow

#: one line on what each reading is (docs/spec.md §3)
READING_TEXT = {
    "squared": "squared nearest distances summed over both sets, no 1/|P| (the released "
               "`get_squared_cd_loss_func`)",
    "released": "Euclidean nearest distances, not squared, summed over both sets, no 1/|P| "
                "(the released evaluation script's `get_cd_loss_func`)",
    "paper": "the paper's equation: squared nearest distances summed over both sets, "
             "divided by |P| = 30",
}


def _fmt(x: float | None, digits: int = 3) -> str:
    if x is None or not np.isfinite(x):
        return "–"
    if x != 0 and abs(x) < 10 ** -digits:
        return f"{x:.1e}"
    return f"{x:.{digits}f}"


def md_table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A GitHub markdown table (cells converted with ``str``)."""
    lines = ["| " + " | ".join(header) + " |",
             "|" + "|".join("---" for _ in header) + "|"]
    for r in rows:
        lines.append("| " + " | ".join(str(c) for c in r) + " |")
    return "\n".join(lines)


def _curves_h(curves: Sequence[Curve]) -> tuple[int, ...]:
    return table_horizons(min(c.err[f"Ep_{HEADLINE}"].shape[1] for c in curves))


def cell(values: Any) -> str:
    """One table cell: the per-case ``values`` as ``mean [lo, hi] med median`` (the mean with
    its 95 % bootstrap interval, and the median: :mod:`.spread`)."""
    return fmt_spread(spread(np.asarray(values, dtype=np.float64).ravel()))


def _err_cells(c: Curve, variant: str, hs: Sequence[int]) -> list[str]:
    return [cell(c.err[f"{k}_{variant}"][:, h - 1]) for h in hs for k in ("Ep", "Es")]


#: what a cell holds, said once above the tables of results.md
CELL_TEXT = (f"Each cell: the mean over the cases [its {LEVEL:.0%} bootstrap interval] and the "
             f"per-case median (`mean [lo, hi] med median`; percentile bootstrap, {N_RESAMPLES:,} "
             f"resamples of the cases, seed {SEED}: docs/glossary.md, \"spread\"). The paper "
             "gives means only.")


def results_tables(curves: Sequence[Curve], variant: str = HEADLINE,
                   ordering: str = "given", with_paper: bool = True) -> str:
    """The paper-style table (one block per m): E_p and E_s at 40 and 80 predictions; with the
    paper's TP-Net row first in the reading it was published in (``"squared"``)."""
    hs = _curves_h(curves)
    header = ["m", "method"] + [f"{k} @{h}" for h in hs for k in ("E_p", "E_s")]
    rows = []
    for m in sorted({c.m for c in curves}):
        if with_paper and variant == "squared" and m in PAPER_TABLE and set(hs) & set(HORIZONS):
            paper = dict(zip(HORIZONS, np.reshape(PAPER_TABLE[m], (2, 2))))
            rows.append([m, "**TP-Net, paper** (docs/spec.md §4)"]
                        + [f"{paper[h][i]:g}" if h in paper else "–" for h in hs
                           for i in (0, 1)])
        mine = [c for c in curves if c.m == m and c.ordering == ordering]
        for c in sorted(mine, key=lambda c: not c.name.startswith("TP-Net")):  # models first
            name = f"**{c.name}**" if c.name.startswith("TP-Net") else c.name
            rows.append([m, name] + _err_cells(c, variant, hs))
    return md_table(header, rows)


def ordering_table(curves: Sequence[Curve], variant: str = HEADLINE) -> str:
    hs = _curves_h(curves)
    header = ["m", "method", "ordering"] + [f"{k} @{h}" for h in hs for k in ("E_p", "E_s")]
    rows = [[c.m, c.name, c.ordering] + _err_cells(c, variant, hs)
            for c in sorted(curves, key=lambda c: (c.m, c.name))]
    return md_table(header, rows)


def _copy_last(curves: Sequence[Curve]) -> Curve | None:
    cands = [c for c in curves if c.name == "copy last" and c.ordering == "given"]
    return next((c for c in cands if c.m == 4), cands[0] if cands else None)


def evidence_rows(curves: Sequence[Curve]) -> list[dict[str, Any]]:
    """For each reading: the perfect ring at a random rotation, the ring collapsed to its
    centre (both computed from the scene), copy-last's E_s at the table's horizons (measured on
    the cases), the paper's TP-Net E_s range and what follows (docs/spec.md §3)."""
    cl = _copy_last(curves)
    hs = _curves_h(curves) if curves else HORIZONS
    es_paper = [v for row in PAPER_TABLE.values() for v in (row[1], row[3])]
    lo, hi = min(es_paper), max(es_paper)
    out = []
    for v in VARIANTS:
        ev = reading_evidence(v)
        if hi < ev["floor"]:
            verdict = ("impossible: every paper E_s lies below a perfect ring at an unknown "
                       "rotation")
        elif lo > ev["collapsed"]:
            verdict = "implausible: TP-Net's E_s above a ring collapsed to a point"
        else:
            verdict = ("consistent: between a perfect ring at an unknown rotation and the "
                       "collapsed ring")
        out.append({"reading": v, "floor": ev["floor"], "collapsed": ev["collapsed"],
                    "copy_last": {h: cl.at(h, f"Es_{v}") for h in hs} if cl else {},
                    "copy_last_m": cl.m if cl else None, "paper": (lo, hi), "verdict": verdict})
    return out


def evidence_md(curves: Sequence[Curve]) -> str:
    rows = evidence_rows(curves)
    hs = list(rows[0]["copy_last"]) if rows and rows[0]["copy_last"] else []
    m = rows[0]["copy_last_m"] if rows else None
    header = (["reading", "perfect ring, random rotation"]
              + [f"copy last (m={m}) @{h}" for h in hs]
              + ["ring collapsed to its centre", "paper's TP-Net", "the paper's E_s is"])
    body = [[f"`{r['reading']}`", fmt_err(r["floor"])]
            + [fmt_err(r["copy_last"][h]) for h in hs]
            + [fmt_err(r["collapsed"]), f"{r['paper'][0]:g}–{r['paper'][1]:g}", r["verdict"]]
            for r in rows]
    return md_table(header, body)


def headline_md(rep: "Report") -> str:
    """The headline sections of ``results.md`` (also what ``tpnet eval`` prints)."""
    n, scale = 30, NORM_HI - NORM_LO
    p40 = PAPER_TABLE[4][0]
    L = ["## The paper's table, side by side (\"squared\" reading)", "",
         f"{rep.n_cases} held-out cases, ordered input, normalised coordinates; reading "
         f"`squared`: {READING_TEXT['squared']}. \"@40\" is the 40th recursive prediction. "
         "This is the reading the paper's numbers can physically be (next section; "
         "docs/spec.md §3). " + CELL_TEXT, "",
         results_tables(rep.curves, "squared"), "",
         f"Scale: E_p / {2 * n} is the mean squared nearest-point distance, so the paper's "
         f"E_p {p40} @40 (m = 4) is a root-mean-square nearest-point distance of "
         f"{math.sqrt(p40 / (2 * n)):.4f} normalised = {math.sqrt(p40 / (2 * n)) * scale:.2f} "
         "world units (the body's radius is 2).", "",
         "## Which reading the paper's table is: the evidence", "",
         "Shape error E_s of references computed by this project in each reading: the body's "
         "rest ring against itself turned by a random fraction of one particle spacing "
         "(`evaluation.ring_phase_floor`), copying the last input frame (these cases), and the "
         "ring collapsed to its centre (`evaluation.collapsed_ring_error`). A model that keeps "
         "the shape scores between the first and the last.", "",
         evidence_md(rep.curves), ""]
    return "\n".join(L)


def timing_md(rows: Sequence[TimingRow], n_cases: int, variant: str = HEADLINE) -> str:
    key = f"Ep_{variant}"
    hs = table_horizons(min((r.err[key].shape[1] for r in rows if r.err), default=80))
    header = ["way of obtaining the next frames", "ms/frame (batch of %d)" % n_cases,
              "ms/frame (one rollout)"] + [f"{k} @{h}" for h in hs for k in ("E_p", "E_s")] \
        + ["note"]
    out = []
    for r in rows:
        cells = []
        for h in hs:
            for k in ("Ep", "Es"):
                e = r.err.get(f"{k}_{variant}")
                cells.append(cell(e[:, h - 1]) if e is not None else "–")
        out.append([r.name, _fmt(r.ms_batch, 3), _fmt(r.ms_single, 3)] + cells + [r.note])
    return md_table(header, out)


@dataclass
class Report:
    """Everything ``tpnet eval`` measured, for :func:`write_results`."""

    command: str
    n_cases: int
    horizon: int
    source: str
    curves: list[Curve]
    timing: list[TimingRow] | None = None
    timing_m: int = 4
    generalisation: dict[str, list[Curve]] = field(default_factory=dict)
    models: list[str] = field(default_factory=list)
    elapsed_s: float = 0.0
    figures: list[str] = field(default_factory=list)
    blas: str = ""


def render_markdown(rep: Report) -> str:
    """The text of ``results.md``."""
    now = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    L: list[str] = ["# Evaluation results", "",
                    f"Made by `{rep.command}` ({now}, {rep.elapsed_s:.0f} s; python "
                    f"{platform.python_version()}, numpy {np.__version__}, "
                    f"{os.cpu_count()} CPU cores, {platform.machine()}{_load()}"
                    + (f"; BLAS {rep.blas}" if rep.blas else "") + ").", ""]
    if not rep.models:
        L += ["**No weights given: baselines and the simulator only** (run the same command "
              "with `--weights` for each m). The numbers below are computed with the protocol "
              "the model rows use; they are real and reproducible.", ""]
    else:
        L += ["Weights: " + ", ".join(f"`{w}`" for w in rep.models), ""]
    L += [headline_md(rep)]
    L += ["## Protocol", "",
          f"{rep.n_cases} cases ({rep.source}); {SIM_ROWS} simulator rows, model frame j = row "
          f"{FRAME_EVERY}j. "
          "A model with m input frames gets frames 0..m-1 and predicts recursively; its h-th "
          "prediction is compared with frame m-1+h (\"@40\" = the 40th prediction, as the "
          f"paper's \"prediction steps\"). Rollouts of {rep.horizon} predictions. Errors: "
          "Chamfer position error E_p and shape error E_s on normalised coordinates, ground "
          "truth first, averaged over the cases (docs/spec.md §3). *Copy last*: every "
          "prediction is the last input frame. *Constant velocity*: each point moves on by its "
          "displacement between the last two input frames (points matched by index, so it "
          "needs ordered input).", ""]
    L += ["## The other readings", "",
          f"### \"released\": {READING_TEXT['released']}", "",
          results_tables(rep.curves, "released"), "",
          *_released_scale_note(rep.curves),
          f"### \"paper\": {READING_TEXT['paper']}", "",
          results_tables(rep.curves, "paper"), ""]
    L += ["## Input orderings", "",
          "The paper's real-world study orders the points of each input frame in three ways; "
          "`given` is the simulator's particle order. TP-Net sorts every frame canonically, so "
          "its four rows must be identical; the constant-velocity baseline matches points by "
          "index and breaks when the order changes between frames. Reading `squared`.", "",
          ordering_table(rep.curves), ""]
    if rep.timing is not None:
        L += ["## Error against run time", "",
              f"One run, {rep.n_cases} cases, m = {rep.timing_m}, ordering `given`; ms per "
              "predicted frame (wall time, best of the repeats; batch: all cases together). "
              "Errors: reading `squared`.", "",
              timing_md(rep.timing, rep.n_cases), "", *_timing_paragraph(rep), ""]
    if rep.generalisation:
        L += ["## Generalisation (outside the training ranges)", "",
              "Cases generated on the fly by `generalisation_cases()` (seed 0): forces above "
              "1.6, angles outside 180–270°, starts near the left/bottom walls (training starts "
              "are all in the upper-right quadrant). Reading `squared`.", ""]
        for g, cs in rep.generalisation.items():
            L += [f"### {g}", "", results_tables(cs, "squared", with_paper=False), ""]
    if rep.figures:
        L += ["## Figures", ""] + [f"![{Path(f).stem}]({Path(f).name})" for f in rep.figures] + [""]
    return "\n".join(L)


def _load() -> str:
    """The machine's load average when the report is written (timings depend on it)."""
    try:
        return f", load average {os.getloadavg()[0]:.1f}"
    except (AttributeError, OSError):
        return ""


def _released_scale_note(curves: Sequence[Curve]) -> list[str]:
    """What the released-reading numbers mean in distances (from the copy-last row)."""
    c = _copy_last(curves)
    if c is None or c.err["Ep_released"].shape[1] < HORIZONS[0]:
        return []
    n, scale, h = 30, NORM_HI - NORM_LO, HORIZONS[0]
    e = c.at(h, "Ep_released")
    return [f"Scale: this reading sums the nearest-point distances of both sets (2 × {n} "
            f"terms), so E_p / {2 * n} is the mean nearest-point distance in normalised units "
            f"(× {scale:.2f} for world units). Copy last (m={c.m}) @{h}: E_p {e:.3f}, i.e. "
            f"{e / (2 * n):.4f} = {e / (2 * n) * scale:.2f} world units. In this reading a "
            f"perfect ring at an unknown rotation already scores E_s "
            f"{reading_evidence('released')['floor']:.3f}, above every E_s of the paper's "
            "table: the table cannot be in this reading.", ""]


def _timing_paragraph(rep: Report) -> list[str]:
    key = f"Ep_{HEADLINE}"
    t = {r.name: r for r in rep.timing or []}
    sim = t.get("pymunk simulator dt x1")
    cv = t.get("constant velocity")
    lines = ["What it means for a user choosing between them: the simulator is the ground truth "
             "when the full state (initial velocity, spring constants) is known"]
    if sim and sim.ms_single is not None:
        lines[0] += f" and costs about {sim.ms_single:.2f} ms per frame on this machine"
    lines[0] += (". Coarser time steps are cheaper (not proportionally: each step has a fixed "
                 "cost) but their error grows quickly with dt, because the discretisation of "
                 "the springs and of the wall contacts changes when and how the body bounces, "
                 "and Box2D's per-step translation clamp (2 units per step) caps the speed at "
                 "2/dt (22.5 units/s at dt x4, where the fastest test bodies start at 22.6; "
                 "11.25 at dt x8). The baselines cost nothing but are only useful for a few "
                 "frames")
    if cv and cv.err[key].shape[1] >= 40:
        lines[0] += f" (constant velocity reaches E_p {fmt_err(cv.err[key][:, 39].mean())} " \
                    "at 40 predictions)"
    lines[0] += (". TP-Net needs only m unordered point sets (no velocities, no correspondence, "
                 "no physical parameters), which is what a camera gives; its rows show what that "
                 "costs per frame and in accuracy.")
    net = [r for r in rep.timing or [] if r.err and r.kind == "model" and r.ms_single is not None]
    if net:
        fs = min(net, key=lambda r: r.ms_single)
        fb = min(net, key=lambda r: r.ms_batch if r.ms_batch is not None else math.inf)
        lines[0] += (f" Fastest here for one rollout: {fs.name} ({fs.ms_single:.2f} ms/frame); "
                     f"for many rollouts stepped together: {fb.name} ({fb.ms_batch:.2f} ms/frame "
                     "per rollout). NumPy float64 is for checking; its errors and float32's "
                     "should agree to the digits shown.")
    else:
        lines += ["", "(No TP-Net rows: no weights given.)"]
    return lines


def write_curves_csv(curves: Sequence[Curve], path: str | os.PathLike) -> Path:
    """Mean over cases of every error at every prediction step, one row per (curve, step)."""
    keys = [f"{k}_{v}" for v in VARIANTS for k in ("Ep", "Es")]
    lines = ["group,method,m,ordering,step,frame," + ",".join(keys)]
    for c in curves:
        means = [c.mean(k) for k in keys]
        for i in range(len(means[0])):
            lines.append(f"{c.group},{c.name},{c.m},{c.ordering},{i + 1},{c.m + i},"
                         + ",".join(f"{mu[i]:.4g}" for mu in means))
    Path(path).write_text("\n".join(lines) + "\n")
    return Path(path)


def write_cases_csv(curves: Sequence[Curve], path: str | os.PathLike) -> Path:
    """Every case's errors at the tables' horizons (40 and 80 predictions), one row per
    (curve, case, step), input ordering ``given``: what the cells' intervals and medians are
    computed from."""
    keys = [f"{k}_{v}" for v in VARIANTS for k in ("Ep", "Es")]
    lines = ["group,method,m,ordering,case,step," + ",".join(keys)]
    for c in curves:
        if c.ordering != "given":
            continue
        for h in table_horizons(c.err[keys[0]].shape[1]):
            for i in range(c.err[keys[0]].shape[0]):
                lines.append(f"{c.group},{c.name},{c.m},{c.ordering},{i + 1},{h},"
                             + ",".join(f"{c.err[k][i, h - 1]:.6g}" for k in keys))
    Path(path).write_text("\n".join(lines) + "\n")
    return Path(path)


#: a section of ``results.md`` written by another command (``bench/sizes.py --md``), kept when
#: ``tpnet eval`` rewrites the file: ``<!-- kept: NAME -->`` ... ``<!-- /kept: NAME -->``
_KEPT = re.compile(r"<!-- kept: (?P<name>[\w.-]+) -->\n.*?<!-- /kept: (?P=name) -->\n?", re.S)


def kept_sections(text: str) -> dict[str, str]:
    """The kept sections of a ``results.md`` text, ``{name: block with its markers}``."""
    return {m["name"]: m[0] if m[0].endswith("\n") else m[0] + "\n" for m in _KEPT.finditer(text)}


def put_kept_section(text: str, name: str, body: str) -> str:
    """``text`` with the kept section ``name`` replaced by ``body`` (appended if absent)."""
    block = f"<!-- kept: {name} -->\n{body.rstrip()}\n<!-- /kept: {name} -->\n"
    old = kept_sections(text).get(name)
    if old is not None:
        return text.replace(old, block, 1)
    return text.rstrip("\n") + "\n\n" + block


def write_results(rep: Report, out_dir: str | os.PathLike, *, plots: bool = True,
                  gallery: dict[str, Any] | None = None) -> Path:
    """Write ``results.md``, ``eval_curves.csv`` and (``plots``: matplotlib, the ``plot``
    extra) the PNG figures into ``out_dir``; returns the markdown's path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rep.figures = []
    if plots:
        rep.figures.append(str(P.plot_models(rep.curves, out / "eval_error_vs_frame.png")))
        rep.figures.append(str(P.plot_spread(rep.curves, out / "eval_spread.png")))
        if gallery:
            rep.figures.append(str(P.plot_gallery(out / "eval_gallery.png", **gallery)))
        if rep.timing:
            rep.figures.append(str(P.plot_timing(rep.timing, out / "eval_error_vs_time.png")))
        if rep.generalisation:
            rep.figures.append(str(P.plot_groups(rep.generalisation,
                                                 out / "eval_generalisation.png")))
    csv = write_curves_csv([*rep.curves, *(c for cs in rep.generalisation.values() for c in cs)],
                           out / "eval_curves.csv")
    cases = write_cases_csv([*rep.curves, *(c for cs in rep.generalisation.values() for c in cs)],
                            out / "eval_cases.csv")
    path = out / "results.md"
    kept = kept_sections(path.read_text()) if path.is_file() else {}
    text = (render_markdown(rep) + f"\nPer-step means of every curve: [{csv.name}]({csv.name}); "
            f"every case's errors at the tables' horizons: [{cases.name}]({cases.name}).\n")
    path.write_text("".join([text, *("\n" + b for b in kept.values())]))
    return path


__all__ = ["READING_TEXT", "md_table", "fmt_err", "table_horizons", "results_tables",
           "ordering_table", "evidence_rows", "evidence_md", "headline_md", "timing_md", "Report",
           "render_markdown", "write_curves_csv", "write_cases_csv", "cell", "CELL_TEXT", "write_results", "kept_sections",
           "put_kept_section"]

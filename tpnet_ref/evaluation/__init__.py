"""Evaluation of TP-Net on the held-out cases (docs/spec.md §4–§5), by concern:

* :mod:`.run`     simulate the cases, roll the models out, errors in the three metric readings,
                  :func:`evaluate` (one :class:`Curve` per method, m and input ordering)
* :mod:`.timing`  error against run time (NumPy, PyTorch, onnxruntime, baselines, simulator)
* :mod:`.shape`   ring geometry: the shape-error references and outline analysis
* :mod:`.spread`  the per-case spread of a cell: mean, 95 % bootstrap interval, median
* :mod:`.report`  ``results.md`` (the paper's table in the ``squared`` reading, the evidence
                  for that reading, the other readings) and ``eval_curves.csv``
* :mod:`.plots`   the figures (matplotlib: the ``plot`` extra)
* :mod:`.demo`    ``tpnet demo``
* :mod:`.suite`   ``tpnet eval`` end to end

The protocol itself (frames, horizons, orderings, the baselines) is :mod:`tpnet_ref.sim.protocol`;
its names are re-exported here so ``from tpnet_ref import evaluation as E; E.copy_last`` works.
matplotlib, tqdm, torch and onnxruntime are imported only when asked for.
"""
from __future__ import annotations

from ..config import NORM_HI, NORM_LO, denormalize, normalize
from ..sim.protocol import (FRAME_EVERY, HORIZONS, ORDERINGS, REFERENCE_DT, SIM_ROWS,
                        constant_velocity, copy_last, order_points, split_protocol)
from .demo import DEMO_CASE, DEMO_HORIZONS, demo
from .report import (Report, evidence_md, evidence_rows, headline_md, kept_sections, md_table,
                     ordering_table, put_kept_section, render_markdown, results_tables,
                     timing_md, write_curves_csv, write_results)
from .run import (HEADLINE, PAPER_TABLE, TEST_CASES, VARIANTS, Curve, ModelSpec,
                  batched_rollout, errors, evaluate, generalisation_cases, simulate_cases,
                  table_horizons)
from .shape import (collapsed_ring_error, radial_fit, radial_outline, reading_evidence,
                    resample_outline, rest_ring, ring_phase_floor, ring_rotation, spacing_stats)
from .spread import Spread, bootstrap_ci, fmt_spread, spread
from .suite import command_line, default_out_dir, run_eval
from .timing import TimingRow, sim_coarse, timing_table

__all__ = ["Spread", "bootstrap_ci", "fmt_spread", "spread", "simulate_cases", "split_protocol", "order_points", "copy_last", "constant_velocity",
           "batched_rollout", "errors", "evaluate", "generalisation_cases", "timing_table",
           "sim_coarse", "results_tables", "ordering_table", "md_table", "render_markdown",
           "write_results", "write_curves_csv", "kept_sections", "put_kept_section", "timing_md", "headline_md", "evidence_md",
           "evidence_rows", "demo", "run_eval", "command_line", "default_out_dir", "Curve",
           "Report", "TimingRow", "ModelSpec", "PAPER_TABLE", "VARIANTS", "HEADLINE", "HORIZONS",
           "ORDERINGS", "FRAME_EVERY", "SIM_ROWS", "REFERENCE_DT", "TEST_CASES", "DEMO_CASE",
           "DEMO_HORIZONS", "table_horizons", "normalize", "denormalize", "NORM_LO", "NORM_HI", "ring_phase_floor",
           "collapsed_ring_error", "reading_evidence", "spacing_stats", "rest_ring",
           "resample_outline", "ring_rotation", "radial_fit", "radial_outline"]

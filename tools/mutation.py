#!/usr/bin/env python
"""Mutation score of the inference core, with cosmic-ray (the ``mutation`` extra).

Each listed module is mutated one small change at a time (cosmic-ray's operators: a comparison,
an arithmetic or boolean operator, a number, a keyword, a loop run zero times, a removed
decorator ...) and the test files that cover it (:data:`MODULES`) are run against each mutant,
fastest first, stopping at the first failure (``pytest -x``), under a per-mutant timeout. A
mutant is killed when the tests fail or time out, survives when they pass.

    python tools/mutation.py                         # every module, every mutant (hours)
    python tools/mutation.py layers checks --sample 60 --seed 1   # 60 mutants of each
    python tools/mutation.py checks --sample 40 --fresh-seed       # a sample no test has seen
    python tools/mutation.py --report                # the score so far, from the saved sessions
    python tools/mutation.py layers --rerun-survivors    # after new tests: the survivors again

The work happens in a copy of the repository per module (``--workdir``, default
``$TMPDIR/tpnet-mutation``), never in the working tree: cosmic-ray edits the module in place. A
session is kept there (``<module>/session.sqlite``): running the same command again goes on with
the mutants not yet run (``--fresh`` starts over). ``--sample N`` runs a seeded random N of a
module's mutants and marks the others skipped. ``--fresh-seed`` draws the seed from the clock,
prints it before anything runs and starts the sessions over (a sample the tests were not written
against: the honest score); the seed is kept beside the session (``<module>/seed``) and printed
by the report.

The report prints, per module, the mutants run, killed, survived, the equivalent survivors
(:data:`TRIAGE` file ``tools/mutation_triage.json``: the mutated line before and after, and why
the change cannot be seen -- inside a stated tolerance, dead code, the same function; and,
recognised by the tool, a mutant inside a type annotation of a module with ``from __future__
import annotations``, which Python never evaluates; "accepted": not equivalent, not killed, and
why) and the score, killed / (run - equivalent), then every survivor not triaged with its diff. docs/testing.md
("Mutation score") has the measured scores and the triage. Not part of CI: it takes hours for
all mutants on two cores.
"""
from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TRIAGE = ROOT / "tools" / "mutation_triage.json"

#: module (its file: :func:`source`) -> the test files that cover it, fastest first
MODULES = {
    # (the trace's own test of tests/test_conformance.py: the rest of that file builds vectors)
    "reference": ["tests/test_engines_reference.py", "tests/test_engines_layers.py",
                  "tests/test_conformance.py::test_trace_names_in_order_and_result_unchanged"],
    "layers": ["tests/test_engines_layers.py", "tests/test_engines_reference.py"],
    "checks": ["tests/test_checks.py", "tests/test_engines_numba_checks.py", "tests/test_model.py"],
    "native": ["tests/test_weights_native.py", "tests/test_integrity.py"],
    "hdf5": ["tests/test_weights_hdf5.py", "tests/test_untrusted_files.py", "tests/test_weights_native.py"],
    # (tests/test_invariance.py runs the same checkers on more networks: 70 s more a mutant)
    "testing": ["tests/test_testing.py"],
    "onnx_peer": ["tests/test_conformance_onnx_peer.py", "tests/test_conformance_onnx.py"],
}
#: the modules whose file is not tpnet_ref/<name>.py: their place in the package
PLACES = {"reference": "engines/reference", "layers": "engines/layers",
          "native": "weights/native", "hdf5": "weights/hdf5", "onnx_peer": "conformance/onnx_peer"}


def source(module: str) -> str:
    """``module``'s file, relative to the repository root."""
    return f"tpnet_ref/{PLACES.get(module, module)}.py"


#: what the copy of the repository leaves out
SKIP = {".git", ".venv", "__pycache__", ".pytest_cache", ".hypothesis", "build", "dist",
        ".mutation", "runs", "data", "checkpoints", "out"}


def _copy_tree(dst: Path) -> None:
    """The working tree (tracked and untracked files, no git, no caches) into ``dst``; the
    copy's ``__pycache__`` folders (numba's compiled kernels) are kept from the last run."""
    def ignore(d: str, names: list[str]) -> set[str]:
        return {n for n in names if n in SKIP or n.endswith(".egg-info")}
    for top in sorted(os.listdir(ROOT)):
        if top in SKIP or top.endswith(".egg-info"):
            continue
        src, out = ROOT / top, dst / top
        if src.is_dir():
            for old in out.rglob("*") if out.exists() else []:
                if old.is_file() and "__pycache__" not in old.parts:
                    old.unlink()
            shutil.copytree(src, out, ignore=ignore, dirs_exist_ok=True, symlinks=True)
        else:
            shutil.copy2(src, out)


def _config(module: str, timeout: float) -> str:
    tests = " ".join(MODULES[module])
    return "\n".join([
        "[cosmic-ray]",
        f'module-path = "{source(module)}"',
        f"timeout = {timeout}",
        "excluded-modules = []",
        # -x: the first failure kills the mutant; no cache, so runs do not write into the copy
        f'test-command = "{sys.executable} -m pytest -x -q -p no:cacheprovider {tests}"',
        "",
        "[cosmic-ray.distributor]",
        'name = "local"',
        "",
    ])


def _cr(*args: str, cwd: Path) -> None:
    exe = Path(sys.executable).with_name("cosmic-ray")
    subprocess.run([str(exe), *args], cwd=cwd, check=True)


def prepare(module: str, work: Path, timeout: float, sample: int | None, seed: int,
            fresh: bool) -> Path:
    """The copy, the config and the session of ``module``; returns the session's path."""
    from cosmic_ray.work_db import WorkDB, use_db
    from cosmic_ray.work_item import WorkerOutcome, WorkResult
    home = work / module
    tree, session = home / "tree", home / "session.sqlite"
    if fresh and session.exists():
        session.unlink()
    tree.mkdir(parents=True, exist_ok=True)
    _copy_tree(tree)
    (home / "config.toml").write_text(_config(module, timeout))
    if session.exists():
        return session
    (home / "seed").write_text(f"{seed}\n" if sample is not None else "all\n")
    _cr("init", str(home / "config.toml"), str(session), cwd=tree)
    with use_db(str(session), WorkDB.Mode.open) as db:
        items = list(db.work_items)
        if sample is not None and sample < len(items):
            keep = {w.job_id for w in random.Random(seed).sample(items, sample)}
            skipped = [w.job_id for w in items if w.job_id not in keep]
            db.set_multiple_results(skipped, WorkResult(worker_outcome=WorkerOutcome.SKIPPED))
    print(f"{module}: {len(items)} mutants, running "
          f"{len(items) if sample is None else min(sample, len(items))}", flush=True)
    return session


def forget_survivors(module: str, work: Path) -> int:
    """Make the survivors of ``module``'s session that are not triaged equivalent pending again
    (after new tests: the next run re-runs them against the freshly copied tree). Returns how
    many."""
    import sqlite3

    from cosmic_ray.work_db import WorkDB, use_db
    session, triage, spans = work / module / "session.sqlite", load_triage(), annotation_spans(module)
    with use_db(str(session), WorkDB.Mode.open) as db:
        items = {w.job_id: w for w in db.work_items}
    with sqlite3.connect(session) as con:
        rows = con.execute("SELECT job_id, diff FROM work_results "
                           "WHERE test_outcome = 'SURVIVED'").fetchall()
        again = [job for job, diff in rows
                 if triaged(module, *_changed_lines(diff or ""), triage) is None
                 and not in_annotation(items[job].mutations[0], spans)]
        con.executemany("DELETE FROM work_results WHERE job_id = ?", [(j,) for j in again])
    print(f"{module}: {len(again)} survivors to run again", flush=True)
    return len(again)


def clock_seed() -> int:
    """A seed drawn from the clock (nanoseconds), for a sample nobody chose."""
    return time.time_ns() % 1_000_000_007


def sample_seed(module: str, work: Path) -> str:
    """The seed of ``module``'s session as recorded by :func:`prepare` ('?' when unknown)."""
    f = work / module / "seed"
    return f.read_text().strip() if f.exists() else "?"


def run(module: str, work: Path) -> None:
    home = work / module
    _cr("exec", str(home / "config.toml"), str(home / "session.sqlite"), cwd=home / "tree")


# ------------------------------------------------------------------------------ report
def _changed_lines(diff: str) -> tuple[str, str]:
    minus = [ln[1:].strip() for ln in diff.splitlines()
             if ln.startswith("-") and not ln.startswith("---")]
    plus = [ln[1:].strip() for ln in diff.splitlines()
            if ln.startswith("+") and not ln.startswith("+++")]
    return " / ".join(minus), " / ".join(plus)


def _line_no(diff: str) -> int:
    for ln in diff.splitlines():
        if ln.startswith("@@"):
            return int(ln.split()[1].split(",")[0].lstrip("-"))
    return 0


def annotation_spans(module: str) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """The source spans of ``module``'s annotations, if the module has ``from __future__ import
    annotations`` (PEP 563: annotations are kept as strings, never evaluated, so a mutant inside
    one is equivalent)."""
    import ast
    tree = ast.parse((ROOT / source(module)).read_text())
    if not any(isinstance(n, ast.ImportFrom) and n.module == "__future__"
               and any(a.name == "annotations" for a in n.names) for n in tree.body):
        return []
    spans = []
    for node in ast.walk(tree):
        found = []
        if isinstance(node, ast.arg) and node.annotation is not None:
            found.append(node.annotation)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.returns:
            found.append(node.returns)
        elif isinstance(node, ast.AnnAssign):
            found.append(node.annotation)
        spans += [((a.lineno, a.col_offset), (a.end_lineno, a.end_col_offset)) for a in found]
    return spans


def in_annotation(mutation, spans) -> bool:
    start, end = tuple(mutation.start_pos), tuple(mutation.end_pos)
    return any(a <= start and end <= b for a, b in spans)


def load_triage() -> list[dict]:
    return json.loads(TRIAGE.read_text()) if TRIAGE.exists() else []


def triaged(module: str, before: str, after: str, triage: list[dict]) -> dict | None:
    return next((t for t in triage if t["module"] == module and t["before"] == before
                 and t["after"] == after), None)


def report(modules: list[str], work: Path, verbose: bool = True) -> dict:
    """Print the score per module and the survivors; returns ``{module: counts}``."""
    from cosmic_ray.work_db import WorkDB, use_db
    from cosmic_ray.work_item import TestOutcome, WorkerOutcome
    triage, scores, untriaged = load_triage(), {}, []
    for module in modules:
        session = work / module / "session.sqlite"
        if not session.exists():
            continue
        c = dict(total=0, run=0, killed=0, timeout=0, survived=0, equivalent=0, accepted=0,
                 incompetent=0, pending=0)
        spans = annotation_spans(module)
        with use_db(str(session), WorkDB.Mode.open) as db:
            results = dict(db.results)
            items = {w.job_id: w for w in db.work_items}
        c["total"] = len(items)
        for job, item in items.items():
            r = results.get(job)
            if r is None:
                c["pending"] += 1
                continue
            if r.worker_outcome in (WorkerOutcome.SKIPPED, WorkerOutcome.NO_TEST):
                continue
            if r.test_outcome == TestOutcome.INCOMPETENT:
                c["incompetent"] += 1          # the mutant breaks cosmic-ray itself: not counted
                continue
            c["run"] += 1
            if r.test_outcome == TestOutcome.KILLED:
                c["killed"] += 1
                c["timeout"] += (r.output or "") == "timeout"
                continue
            c["survived"] += 1
            before, after = _changed_lines(r.diff or "")
            t = triaged(module, before, after, triage)
            mut = item.mutations[0]
            if (t is not None and t.get("kind") != "accepted") or in_annotation(mut, spans):
                c["equivalent"] += 1
            elif t is not None:
                c["accepted"] += 1             # not equivalent, not killed: why, in the triage
            else:
                untriaged.append((module, mut.start_pos[0], mut.operator_name, before, after))
        live = c["run"] - c["equivalent"]
        c["score"] = c["killed"] / live if live else float("nan")
        scores[module] = c
    print(f"{'module':<11} {'seed':>10} {'mutants':>7} {'run':>4} {'killed':>6} {'(timeout)':>9} "
          f"{'survived':>8} {'equiv.':>6} {'accepted':>8} {'pending':>7}  "
          "score (killed / non-equivalent)")
    for module, c in scores.items():
        print(f"{module:<11} {sample_seed(module, work):>10} {c['total']:>7} {c['run']:>4} "
              f"{c['killed']:>6} {c['timeout']:>9} "
              f"{c['survived']:>8} {c['equivalent']:>6} {c['accepted']:>8} {c['pending']:>7}  "
              f"{100 * c['score']:.1f} %")
    if verbose and untriaged:
        print(f"\n{len(untriaged)} surviving mutants not triaged (tools/mutation_triage.json):")
        for module, line, op, before, after in sorted(untriaged):
            print(f"  {module}.py:{line} [{op.split('/')[-1]}]\n      - {before}\n      + {after}")
    return scores


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("modules", nargs="*", default=list(MODULES),
                    help=f"modules of tpnet_ref to mutate (default: all: {', '.join(MODULES)})")
    ap.add_argument("--sample", type=int, default=None,
                    help="run a seeded random N of each module's mutants (default: all)")
    ap.add_argument("--seed", type=int, default=0, help="the sample's seed")
    ap.add_argument("--fresh-seed", action="store_true",
                    help="draw the sample's seed from the clock, print it first, and start the "
                         "sessions over (a sample no test was written against)")
    ap.add_argument("--timeout", type=float, default=300.0,
                    help="seconds one mutant's tests may run before it counts as killed")
    ap.add_argument("--workdir", type=Path,
                    default=Path(tempfile.gettempdir()) / "tpnet-mutation",
                    help="where the copies and sessions live")
    ap.add_argument("--fresh", action="store_true", help="start the modules' sessions over")
    ap.add_argument("--rerun-survivors", action="store_true",
                    help="run the surviving mutants again (after adding tests)")
    ap.add_argument("--report", action="store_true", help="only print the score so far")
    ap.add_argument("--nice", type=int, default=10, help="niceness of the runs (default 10)")
    args = ap.parse_args(argv)
    bad = [m for m in args.modules if m not in MODULES]
    if bad:
        ap.error(f"unknown module(s) {', '.join(bad)}; choose from {', '.join(MODULES)}")
    try:
        import cosmic_ray  # noqa: F401
    except ImportError:
        ap.error("cosmic-ray is not installed: pip install -e '.[mutation]'")
    if args.fresh_seed:
        if args.seed:
            ap.error("--fresh-seed draws the seed: give it or --seed, not both")
        if args.sample is None:
            ap.error("--fresh-seed needs --sample N (a seed chooses a sample)")
        if args.report or args.rerun_survivors:
            ap.error("--fresh-seed starts a new sample: not with --report or --rerun-survivors")
        args.seed, args.fresh = clock_seed(), True
        print(f"fresh seed: {args.seed} (rerun this sample with --seed {args.seed})", flush=True)
    if not args.report:
        os.nice(args.nice)
        for module in args.modules:
            t0 = time.time()
            prepare(module, args.workdir, args.timeout, args.sample, args.seed, args.fresh)
            if args.rerun_survivors:
                forget_survivors(module, args.workdir)
            run(module, args.workdir)
            print(f"{module}: {time.time() - t0:.0f} s", flush=True)
    scores = report(args.modules, args.workdir)
    return 0 if scores else 1


if __name__ == "__main__":
    sys.exit(main())

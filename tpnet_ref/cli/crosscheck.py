"""``tpnet vectors``: conformance vectors for a port; ``tpnet crosscheck``: where a port or a
framework model stops agreeing with the reference, layer by layer (docs/crosscheck.md)."""
from __future__ import annotations

import argparse
from typing import Any

def add_cli(sub: Any) -> None:
    p = sub.add_parser(
        "vectors", help="write conformance vectors: DIR/manifest.json (cases, layers in forward "
                        "order, shapes, float32 tolerances) and DIR/vectors.npz (every case's "
                        "input, intermediates and output in float64, keys <case>.<layer>)")
    p.add_argument("--weights", default=None,
                   help="native weights file (default: the shipped m=4 model)")
    p.add_argument("-o", "--output", required=True, metavar="DIR",
                   help="folder to write (created; its parent must exist)")
    p.set_defaults(func=_cli_vectors)

    p = sub.add_parser(
        "crosscheck",
        help="compare a port's trace or a model file with conformance vectors layer by layer: "
             "per case the first layer beyond its tolerance, its max error and where it starts",
        description="Compare an implementation of TP-Net with conformance vectors (tpnet "
                    "vectors), layer by layer in forward order. Prints, per case, the first "
                    "layer beyond its float32 tolerance with its largest error and where it "
                    "starts (frame, point, channel; time step, direction, unit; point, "
                    "coordinate), then the layers after it. Exit status 0 when every case "
                    "agrees, 1 on any divergence, 2 on bad input.")
    p.add_argument("--vectors", required=True, metavar="DIR",
                   help="conformance vectors folder written by tpnet vectors")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--trace", metavar="PORT.npz",
                     help="a port's own trace: an .npz with keys <case>.<layer> as in "
                          "vectors.npz (layers may be left out; default: none, give --model)")
    src.add_argument("--model", metavar="FILE",
                     help="a model file to trace: an .onnx graph (onnxruntime), a PyTorch state "
                          "dict (hooks), a Keras .h5/.keras checkpoint (needs the keras extra) "
                          "or a native weights file (--engine); told apart by content "
                          "(default: none, give --trace)")
    p.add_argument("--engine", choices=("numpy", "numba"), default="numpy",
                   help="the engine that traces a native weights file given as --model "
                        "(default numpy)")
    p.add_argument("--json", action="store_true",
                   help='print {"first_divergence": {"case", "layer", "max_abs", "where"} or '
                        'null, "cases": ...} as JSON instead of the report (default: off)')
    p.add_argument("--after", type=int, default=6, metavar="K",
                   help="layers listed after a case's first divergence (default 6)")
    p.set_defaults(func=_cli_crosscheck)


def _cli_vectors(args: argparse.Namespace) -> int:
    import os

    import tpnet_ref

    from ..conformance.vectors import write_conformance_vectors
    model = tpnet_ref.load(args.weights, engine="numpy")
    weights = {"source": os.path.basename(args.weights) if args.weights else "shipped m=4",
               **{k: str(model.meta[k]) for k in ("digest", "content_digest", "sha256")
                  if k in model.meta}}
    man = write_conformance_vectors(model.config, model.params, args.output, weights=weights)
    tol = {e["name"]: e["tolerance"] for e in man["layers"]}
    print(f"wrote {args.output}/manifest.json and vectors.npz: {len(man['cases'])} cases "
          f"({', '.join(c['name'] for c in man['cases'])}), {len(tol)} layers each; float32 "
          f"tolerances from {min(tol.values()):.1e} ({min(tol, key=tol.get)}) to "
          f"{max(tol.values()):.1e} ({max(tol, key=tol.get)})")
    return 0


def _cli_crosscheck(args: argparse.Namespace) -> int:
    import json

    from ..conformance.compare import compare, first_divergence
    from ..conformance.report import report_json, report_text
    from ..conformance.vectors import load_trace, read_conformance_vectors
    if args.after < 0:
        raise ValueError(f"--after must be >= 0, got {args.after}")
    vec = read_conformance_vectors(args.vectors)
    if args.trace is not None:
        traces = load_trace(args.trace, vec)
        what = f"trace {args.trace}"
    else:
        from ..conformance.traces import model_tracer
        how, fn = model_tracer(args.model, vec, args.engine)
        traces = {c: fn(vec.window(c)) for c in vec.cases}
        what = f"{args.model} ({how})"
    results = compare(vec, traces)
    if args.json:
        print(json.dumps(report_json(results, vec.layers), indent=1))
    else:
        print(f"{what} against {args.vectors} ({len(results)} case(s), {len(vec.layers)} layers)")
        print(report_text(results, vec.layers, args.after))
    return 1 if first_divergence(results, vec.layers) else 0

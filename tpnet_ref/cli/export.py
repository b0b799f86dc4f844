"""``tpnet export onnx``: the model as an ONNX file, for runtimes this package does not replace."""
from __future__ import annotations

import argparse
from typing import Any


def add_cli(sub: Any) -> None:
    p = sub.add_parser("export", help="write the model in another format (onnx)")
    fmt = p.add_subparsers(dest="format", metavar="FORMAT")
    fmt.required = True
    q = fmt.add_parser("onnx", help="an ONNX file: input window (batch, m, N, dim) float32 in "
                                    "world units -> prediction (batch, n_out, dim) in world "
                                    "units, dim the model's (2, or 3 for a 3-D model); batch and "
                                    "N dynamic, LSTMs as ONNX LSTM ops (opset 17)")
    q.add_argument("--weights", default=None, help="native weights file (default: shipped m=4)")
    q.add_argument("-o", "--output", required=True, metavar="OUT.onnx",
                   help="the ONNX file to write, exactly at this path")
    q.set_defaults(func=_cli_export_onnx)


def _cli_export_onnx(args: argparse.Namespace) -> int:
    import os

    import tpnet_ref

    from ..extras import require
    from .files import output_path
    out = output_path(args.output, suffix=".onnx")   # a bad path fails before any work
    require("onnx", "onnx")
    from ..conformance.onnx_peer import export_onnx
    model = tpnet_ref.load(args.weights, engine="numpy")
    export_onnx(model, out)
    c = model.config
    print(f"wrote {out} ({os.path.getsize(out) / 2**20:.1f} MiB): window (batch, {c.m}, N, "
          f"{c.dim}) float32, world units -> prediction (batch, {c.n_out}, {c.dim})")
    return 0

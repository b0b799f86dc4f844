"""``tpnet import``: convert a Keras or PyTorch checkpoint to the native weights file;
``tpnet compress``: rewrite a native file with shuffle + gzip (optionally rounded first);
``tpnet scrub-provenance``: rewrite a native file's provenance without machine paths, with a
content digest, the parameters bit-identical; ``tpnet quantize``: a native file whose BiLSTM
matrices are bf16 or int8 codes (about two thirds or a quarter of their bytes)."""
from __future__ import annotations

import argparse
from typing import Any


def add_cli(sub: Any) -> None:
    p = sub.add_parser("import", help="convert a Keras (.h5, .weights.h5, .keras) or PyTorch "
                                      "(.pt) checkpoint to the native weights file")
    p.add_argument("src", help="checkpoint to read (kind told by content)")
    p.add_argument("dst", help="native HDF5 weights file to write")
    p.add_argument("--m", type=int, default=None,
                   help="input frames, where the file does not say (default 4)")
    p.add_argument("--layer-norm-eps", type=float, default=None,
                   help="LayerNorm eps, where the file does not say (default 1e-3)")
    p.add_argument("--lstm-activation", choices=("relu", "tanh"), default=None,
                   help="LSTM activation, where the file does not say (default relu)")
    p.add_argument("--dtype", choices=("float32", "float64"), default="float32",
                   help="dtype of the written parameters (default float32, as trained)")
    p.set_defaults(func=_cli_import)

    p = sub.add_parser("compress", help="rewrite a native weights file with shuffle + gzip "
                                        "(lossless), or rounded to fewer significand bits first")
    p.add_argument("src", help="native weights file to read")
    p.add_argument("dst", help="native weights file to write (may be src)")
    p.add_argument("--mantissa-bits", type=int, default=None, metavar="K",
                   help="round every value to K significand bits first (lossy, relative change "
                        "at most 2^-(K+1); float32 has 23): the reduced sizes ship with 15")
    p.set_defaults(func=_cli_compress)

    p = sub.add_parser("scrub-provenance",
                       help="rewrite a native weights file with every absolute path in its "
                            "provenance made relative (or a file name) and a content digest; "
                            "parameters, unit order and masks bit-identical (checked)")
    p.add_argument("src", help="native weights file to read")
    p.add_argument("dst", help="native weights file to write (may be src)")
    p.add_argument("--data", default=None, metavar="FILE",
                   help="the training data file: record its SHA-256 as data_sha256")
    p.add_argument("--root", action="append", default=None, metavar="DIR",
                   help="a path inside DIR is recorded relative to it (repeat: the first that "
                        "holds it; default: this repository checkout); a path in none of them "
                        "from its first folder named data, runs or weights, else by file name")
    p.set_defaults(func=_cli_scrub)

    p = sub.add_parser(
        "quantize", help="write a native weights file whose BiLSTM matrices (input kernels, "
                         "recurrent matrices: 96 %% of the paper size's weights) are bf16 or int8 "
                         "codes; tpnet_ref.load reads it with no flag, the Numba engine reads the "
                         "codes (docs/deployment.md)",
        description="Quantize a native weights file. bf16: each BiLSTM weight rounded to "
                    "bfloat16; BiLSTM 1's input kernels and the last BiLSTM's input kernels and "
                    "recurrent matrices in two bf16 planes (w = hi + lo / 256, about 16 bits). "
                    "int8: symmetric, one float32 scale per output column "
                    "(max |column| / 127), applied to each sum; BiLSTM 1's input kernels and "
                    "the last BiLSTM's recurrent matrices in two int8 planes (16 bits: the "
                    "matrices a prediction is most sensitive to); with --calibrate, every matrix "
                    "in one plane, its rows rounded in order with each row's error moved "
                    "onto the rows after it as training windows' inputs co-vary (GPTQ; smaller "
                    "and closer to float32: docs/deployment.md). The per-point MLP, the global "
                    "layer, the output "
                    "layer, biases and LayerNorm stay float32; sums and activations are float32. "
                    "The file records the scheme (quantization) and its source "
                    "(quantized_from: file name and digest), carries a content digest over the "
                    "codes and scales, and is written with shuffle + gzip; tpnet_ref.load(OUT.h5) "
                    "reads it with no flag. When to use which: docs/deployment.md.")
    p.add_argument("--weights", required=True, metavar="W",
                   help="the float32 native weights file to quantize")
    p.add_argument("--to", required=True, choices=("bf16", "int8"),
                   help="the scheme: bf16 (about two thirds of the bytes at the paper size) or "
                        "int8 (a quarter)")
    p.add_argument("-o", "--output", required=True, metavar="OUT.h5",
                   help="native weights file to write (may not be W)")
    p.add_argument("--calibrate", metavar="DATA",
                   help="round on windows of DATA's training split (a dataset of `tpnet data "
                        "generate` of the model's dimension; never the test cases), every matrix "
                        "in one plane")
    p.add_argument("--windows", type=int, default=256,
                   help="calibration windows drawn from DATA (default: 256)")
    p.add_argument("--seed", type=int, default=0,
                   help="the draw of the calibration windows (default: 0)")
    p.set_defaults(func=_cli_quantize)


def _cli_import(args: argparse.Namespace) -> int:
    from ..weights import import_checkpoint

    model = import_checkpoint(args.src, dtype=args.dtype, m=args.m,
                              layer_norm_eps=args.layer_norm_eps,
                              lstm_activation=args.lstm_activation)
    c = model.config
    print(f"read {args.src}: {model.meta.get('import_report', '')}")
    print(f"  {model}")
    print(f"  m={c.m} N={c.n_out} lstm_units={c.lstm_units} activation={c.lstm_activation} "
          f"layer_norm_eps={c.layer_norm_eps}")
    print(f"  transforms: input {'trained' if c.input_transform_trained else 'identity'}, "
          f"feature {'trained' if c.feature_transform_trained else 'identity'}")
    meta = {k: v for k, v in model.meta.items() if k in ("source", "source_format", "import_report")}
    model.save(args.dst, **meta)
    print(f"wrote {args.dst}")
    return 0


def _cli_compress(args: argparse.Namespace) -> int:
    import json
    import os

    from ..weights.native import convert_storage

    before = os.path.getsize(args.src)
    meta = convert_storage(args.src, args.dst, "gzip", args.mantissa_bits)
    after = os.path.getsize(args.dst)
    how = ("lossless" if args.mantissa_bits is None else
           f"rounded to {args.mantissa_bits} significand bits, largest relative change "
           f"{json.loads(meta['storage_rounding'])['max_rel_change']:.3g}")
    print(f"wrote {args.dst}: {after / 1e6:.2f} MB ({before / 1e6:.2f} MB before; shuffle + gzip, "
          f"{how})")
    return 0


def _cli_scrub(args: argparse.Namespace) -> int:
    from ..weights.provenance import absolute_paths, scrub

    rep = scrub(args.src, args.dst, args.data, args.root)
    for key, (before, after) in rep["changed"].items():
        b, a = (str(x) if x is not None else "-" for x in (before, after))
        if len(b) > 100 or len(a) > 100:
            paths = absolute_paths(b)
            b = f"{len(b):,} characters, {len(paths)} absolute path(s)"
            a = f"{len(a):,} characters, {len(absolute_paths(a))} absolute path(s)"
        print(f"  {key}: {b} -> {a}")
    print(f"wrote {args.dst}: {rep['arrays']} arrays ({rep['values']:,} parameters) "
          f"bit-identical to {args.src} (checked), {rep['digest']}")
    return 0


def _cli_quantize(args: argparse.Namespace) -> int:
    import os

    import numpy as np

    from ..model import load
    from ..weights.convert import with_weights
    from ..weights.native import extra_groups, write_replacing

    if os.path.abspath(args.output) == os.path.abspath(args.weights):
        raise ValueError("quantize: -o must name a new file, not --weights")
    if args.windows < 1:
        raise ValueError(f"quantize: --windows must be at least 1, got {args.windows}")
    base = load(args.weights, engine="numpy")
    if args.calibrate:
        from ..weights import calibrate as C
        c = base.config
        wins = C.training_windows(args.calibrate, c.m, c.dim, args.windows, args.seed)
        model = C.calibrated(base, wins, os.path.basename(args.calibrate), args.to)
    else:
        model = with_weights(base, args.to)
    meta = write_replacing(args.output, model.config, model.params, model.meta,
                           extra_groups(args.weights), "gzip")
    change = max(float(np.max(np.abs(model.params[k] - base.params[k]))) for k in base.params)
    print(f"wrote {args.output}: {os.path.getsize(args.output) / 1e6:.2f} MB "
          f"({os.path.getsize(args.weights) / 1e6:.2f} MB before), BiLSTM matrices as "
          f"{args.to}{' (calibrated, one plane)' if args.calibrate else ''}, largest change "
          f"of a weight {change:.3g}; {meta['content_sha256']}")
    return 0

"""``tpnet train run|export|average|bench|score|baselines``: training in PyTorch (``train`` extra).

argparse only: each handler imports the training modules when it runs, so ``tpnet --help`` and
the other commands work without torch, and a missing torch is one line naming the extra.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import Any

from ..training.recipe import (N_ROLLOUT_MAX, N_STEPS_MAX, NOISE_KINDS, OPTIMIZER_MODES, SIZES,
                               Recipe)
from ..weights.quantize import SCHEMES

#: as tpnet_ref.training.precision.COMPILE_MODES (not imported from there: that module needs torch)
COMPILE_MODES = ("off", "auto", "reduce-overhead", "default", "eager")
#: as tpnet_ref.training.precision.PRECISIONS
PRECISIONS = ("auto", "float32", "bf16")
_PRECISION_HELP = ("the step's arithmetic: float32 (default), bf16 (autocast to bfloat16; "
                   "parameters, Adam state, coordinates and loss stay float32; 1.7x faster on a "
                   "CPU with AVX512_BF16, but its fine-tunes of the shipped model rolled out much "
                   "worse at 40-80 predictions: docs/training.md), auto (bf16 where a short "
                   "timing at the start of the call finds it >= 1.15x faster, else float32)")
_COMPILE_HELP = ("capture the step's loss with torch.compile: auto (reduce-overhead, i.e. CUDA "
                 "graphs, on a GPU; off on the CPU), reduce-overhead, default, eager (traced by "
                 "TorchDynamo, eager kernels: proves on the CPU that the step traces), off")


#: ``train export --best --monitor``: the name of each choice in the validation records
MONITORS = {"val_loss": "val_loss", "ep80": "Ep@80 squared"}

#: ``--preset NAME``: recipe fields set unless the option is given explicitly
PRESETS: dict[str, dict[str, Any]] = {
    "released": dict(recipe="paper", init="keras", windows="released", schedule="constant",
                     lr=1e-3, batch=128, beta1=0.99, beta2=0.999, adam_eps=1e-7,
                     warmup_steps=0, clip=0.0, noise=0.0, shape_weight=0.0, match_weight=0.0,
                     rollout=N_STEPS_MAX, head_init="default"),
}


def _recorded(action_cls: type) -> type:
    """``action_cls`` that also adds its dest to ``namespace._given`` when the command line
    names it, so a preset can tell ``--warmup-steps 200`` from the default 200."""
    class Recorded(action_cls):  # type: ignore[misc, valid-type]
        def __call__(self, parser, namespace, values, option_string=None):  # noqa: ANN001
            super().__call__(parser, namespace, values, option_string)
            namespace._given = getattr(namespace, "_given", frozenset()) | {self.dest}
    return Recorded


def apply_preset(args: argparse.Namespace) -> None:
    """Set the preset's fields on ``args`` that the command line did not give (a value given
    explicitly wins, also when it equals the parser's default)."""
    given = getattr(args, "_given", frozenset())
    for k, v in PRESETS.get(getattr(args, "preset", None) or "", {}).items():
        if k not in given:
            setattr(args, k, v)


def add_cli(sub: Any) -> None:
    p = sub.add_parser("train", help="train TP-Net in PyTorch (train extra) and export weights")
    tsub = p.add_subparsers(dest="train_command", metavar="TRAIN_COMMAND")
    tsub.required = True

    _add_run(tsub)
    _add_export(tsub)
    _add_average(tsub)
    _add_bench(tsub)
    _add_score(tsub)
    _add_baselines(tsub)
    _add_pack(tsub)


def _add_run(tsub: Any) -> None:
    d = Recipe()
    q = tsub.add_parser("run", help="train (or --resume) a run on a `tpnet data generate` file")
    q.add_argument("data", help="HDF5 dataset from `tpnet data generate`")
    q.add_argument("-o", "--run-dir", required=True,
                   help="run directory: checkpoint.pt, checkpoint.json, log.jsonl")
    q.add_argument("--resume", action="store_true",
                   help="continue the run in --run-dir (its stored recipe is used)")
    q.add_argument("--recipe", choices=("paper", "curriculum"), default=d.recipe,
                   help="paper: the published 8-step recursive loss from the first step; "
                        "curriculum: --pretrain-epochs of the 1-step loss, then the rollout "
                        "growing from 1 to --rollout over --ramp-epochs")
    q.add_argument("--size", choices=sorted(SIZES), default="full",
                   help="network widths: full (released), half, quarter (every width halved, "
                        "quartered), small, tiny")
    q.add_argument("--lstm-activation", choices=("relu", "tanh"), default="relu",
                   help="the LSTM cell's candidate and output non-linearity (released: relu)")
    q.add_argument("--epochs", type=float, default=None,
                   help=f"epochs over the training windows, may be fractional (default: {d.epochs:g})")
    q.add_argument("--batch", type=int, default=d.batch, help="windows per optimizer step")
    q.add_argument("--lr", type=float, default=d.lr,
                   help="Adam learning rate (the peak one with --schedule cosine)")
    q.add_argument("--beta1", type=float, default=d.beta1,
                   help="Adam's first-moment decay (the released code's)")
    q.add_argument("--beta2", type=float, default=d.beta2,
                   help="Adam's second-moment decay (the released code's)")
    q.add_argument("--adam-eps", type=float, default=d.eps,
                   help="Adam's epsilon (the released code's)")
    q.add_argument("--schedule", choices=("constant", "cosine"), default=d.schedule,
                   help="learning rate after the warm-up: constant --lr, or cosine decay "
                        "from --lr to --lr-min at the last step")
    q.add_argument("--lr-min", type=float, default=d.lr_min,
                   help="learning rate the cosine schedule ends at")
    q.add_argument("--warmup-steps", type=int, default=d.warmup_steps,
                   help="steps of linear learning-rate warm-up from 0 (0: none)")
    q.add_argument("--clip", type=float, default=d.clip, help="max grad norm (0: off)")
    q.add_argument("--noise", type=float, default=d.noise,
                   help="std of Gaussian noise on input coordinates (normalised units)")
    q.add_argument("--noise-kind", choices=NOISE_KINDS, default=d.noise_kind,
                   help="iid: independent noise on every input frame; walk: a random walk over "
                        "the m input frames (increments of std --noise/sqrt(m), the last frame's "
                        "std is --noise), so velocities are perturbed consistently")
    q.add_argument("--shape-weight", type=float, default=d.shape_weight,
                   help="λ: add λ × the same weighted sum of shape Chamfer distances (sets centred "
                        "on their centroids; the released shape error E_s); 0 = published loss")
    q.add_argument("--match-weight", type=float, default=d.match_weight,
                   help="μ: add μ × the same weighted sum of matched (earth mover's) distances, "
                        "optimal one-to-one pairs (scipy); stops predicted points from "
                        "clumping on one target; 0 = published loss")
    q.add_argument("--pretrain-epochs", type=float, default=d.pretrain_epochs,
                   help="curriculum: epochs of the 1-step (teacher-forced) loss first")
    q.add_argument("--ramp-epochs", type=float, default=d.ramp_epochs,
                   help="curriculum: epochs over which the rollout grows from 1 to --rollout")
    q.add_argument("--rollout", type=int, default=d.rollout,
                   help=f"longest recursive loss (1..{N_ROLLOUT_MAX}; published {N_STEPS_MAX}; "
                        f"longer: only windows with that many frames after their inputs)")
    q.add_argument("--grad-steps", type=int, default=d.grad_steps, metavar="G",
                   help="pushforward trick, 0 < G < K: the first K-G of the --rollout K "
                        "predictions are made without gradient, the loss (weight 1 each) is over "
                        "the last G alone; 0 = all K")
    q.add_argument("--head-init", choices=("default", "template"), default=d.head_init,
                   help="template: the untrained head outputs a ring of the body's size")
    q.add_argument("--init", choices=("torch", "keras"), default=d.init,
                   help="initialisation of a new run: torch (nn.Linear defaults) or keras (the "
                        "released code's: glorot-uniform kernels, zero biases, orthogonal "
                        "recurrent kernels, forget-gate bias 1) (default: %(default)s)")
    q.add_argument("--windows", choices=("model", "released"), default=d.windows,
                   help="training windows: model (starts at model frames) or released (the "
                        "authors' preprocessing: starts at any simulator row; needs a file "
                        "from `tpnet data generate --windows released`) (default: %(default)s)")
    q.add_argument("--preset", choices=sorted(PRESETS), default=None,
                   help="released: the authors' recipe as released (the published 8-step "
                        "loss from scratch, Keras initialisation, released windows, Adam at a "
                        "constant 1e-3, batch 128, no warm-up, no clipping, no extra terms); "
                        "options given explicitly still win")
    q.add_argument("--init-from", default=d.init_from, metavar="RUN_DIR|WEIGHTS.h5",
                   help="fine-tune: start from this run's weights or a native weights file "
                        "(fresh optimizer and schedule; its network is used, --size is ignored)")
    q.add_argument("--init-optimizer", action="store_true",
                   help="with --init-from RUN_DIR: also take that run's Adam state (moments, "
                        "step counts), so a branch with another recipe starts without the jolt "
                        "of a fresh Adam; this recipe's learning rate and constants apply")
    q.add_argument("--quantize-aware", choices=SCHEMES, default=None,
                   help="quantization-aware fine-tune (with --init-from): every BiLSTM matrix "
                        "on that scheme's grid (one plane, rounded to nearest, as `tpnet "
                        "quantize` rounds) in the forward pass, the gradient passed through "
                        "the rounding; the exported files and snapshots hold the rounded "
                        "weights (docs/deployment.md)")
    q.add_argument("--val-windows", type=int, default=d.val_windows,
                   help="validate on this many evenly spaced validation windows (0: all)")
    q.add_argument("--val-fraction", type=float, default=d.val_fraction,
                   help="fraction of training-grid trajectories held out for validation")
    q.add_argument("--split-seed", type=int, default=d.split_seed,
                   help="seed of the validation split (kept apart from --seed)")
    q.add_argument("--seed", type=int, default=d.seed, help="initialisation, order and noise")
    q.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto",
                   help="where torch trains: auto is cuda when a GPU is visible, else cpu")
    q.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    q.add_argument("--compile", choices=COMPILE_MODES, default="off", help=_COMPILE_HELP)
    q.add_argument("--precision", choices=PRECISIONS, default="float32", help=_PRECISION_HELP)
    q.add_argument("--max-steps", type=int, default=None, help="stop (with a checkpoint) at this step")
    q.add_argument("--max-minutes", type=float, default=None,
                   help="stop (with a checkpoint) after this many minutes")
    q.add_argument("--budget-minutes", type=float, default=None,
                   help="new runs: time a few steps here, then set --epochs so the run (and its "
                        "cosine schedule) fits 90%% of this many minutes; also the hard stop")
    q.add_argument("--checkpoint-minutes", type=float, default=5.0,
                   help="write a checkpoint at least this often (and at every stop)")
    q.add_argument("--checkpoint-part-mib", type=float, default=None, metavar="MIB",
                   help="write the checkpoint as checkpoint.pt.000, .001, ... of at most MIB MiB "
                        "each (e.g. 16, for machines whose files travel in 16 MiB pieces); kept "
                        "on --resume, which reads parts or one file alike; 0: one file again")
    q.add_argument("--checkpoint-optimizer", choices=OPTIMIZER_MODES, default=None,
                   help="Adam state in the checkpoint: full (exact resume; the default), bf16 (moments "
                        "in bfloat16, 2/3 of the size) or none (model only, 1/3; resume starts a "
                        "fresh Adam); kept on --resume unless given")
    q.add_argument("--allow-other-scene", action="store_true",
                   help="train on a dataset made with another scene convention than the "
                        "simulator's default (refused otherwise)")
    q.add_argument("--log-every", type=int, default=50, help="steps between train-loss log lines")
    q.add_argument("--val-every", type=int, default=None,
                   help="also validate every N steps (default: at epoch ends only)")
    q.add_argument("--snapshots", action="store_true", default=None,
                   help="after every validation also write RUN_DIR/snapshots/step-NNNNNNN.h5 "
                        "(native weights, for learning curves: tpnet train score; kept on "
                        "--resume)")
    q.add_argument("--export", default=None, metavar="OUT.h5",
                   help="when the run completes, write the native weights file")
    q.add_argument("--quiet", action="store_true", help="no progress bar")
    preset_fields = {k for fields in PRESETS.values() for k in fields}
    for a in q._actions:                 # a preset must see which of its fields were given
        if a.dest in preset_fields:
            a.__class__ = _recorded(type(a))
    q.set_defaults(func=_cli_run)


def _add_export(tsub: Any) -> None:
    e = tsub.add_parser("export", help="native weights file from a checkpoint (with provenance)")
    e.add_argument("checkpoint", help="run directory or checkpoint.pt")
    e.add_argument("output", help="native HDF5 weights file to write")
    e.add_argument("--dtype", choices=("float32", "float64"), default="float32",
                   help="dtype of the parameters in the written file")
    e.add_argument("--best", action="store_true",
                   help="the run's snapshot with the lowest --monitor instead of its last "
                        "weights (needs a --snapshots run)")
    e.add_argument("--monitor", choices=sorted(MONITORS), default="val_loss",
                   help="with --best: val_loss (the 8-step validation loss in log.jsonl: the "
                        "released train.py's choice) or ep80 (validation E_p@80, squared "
                        "reading: the test protocol on --data's validation trajectories, "
                        "cached in RUN/snapshots/scores.json)")
    e.add_argument("--data", default=None,
                   help="with --monitor ep80: the grid whose validation trajectories score "
                        "the snapshots (never the test cases)")
    e.set_defaults(func=_cli_export)


def _add_average(tsub: Any) -> None:
    a = tsub.add_parser("average", help="one weights file from the weighted mean of fine-tunes "
                                        "of one network (a model soup; NumPy only)")
    a.add_argument("weights", nargs="+", help="native weights files of one network in one basis")
    a.add_argument("-o", "--output", required=True, help="native weights file to write")
    a.add_argument("--mix", type=float, nargs="+", default=None,
                   help="each file's weight, in order, summing to 1 (default: equal)")
    a.set_defaults(func=_cli_average)


def _add_bench(tsub: Any) -> None:
    b = tsub.add_parser("bench", help="training throughput (windows/s) at a batch size")
    b.add_argument("--size", choices=sorted(SIZES), default="full",
                   help="network widths, as `tpnet train run --size`")
    b.add_argument("--batch", type=int, default=128, help="windows per timed step")
    b.add_argument("--rollouts", type=int, nargs="+", default=[1, 8],
                   help="recursive-loss lengths to time, one line each")
    b.add_argument("--iters", type=int, default=5,
                   help="timed steps per line, after a warm-up step")
    b.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto",
                   help="where torch runs: auto is cuda when a GPU is visible, else cpu")
    b.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    b.add_argument("--compile", choices=COMPILE_MODES, default="off", help=_COMPILE_HELP)
    b.add_argument("--precisions", choices=PRECISIONS[1:], nargs="+",
                   default=list(PRECISIONS[1:]),
                   help="time each of these (default: both); the line marked (default) is "
                        "the one `tpnet train run` takes (float32), (auto) the one "
                        "`--precision auto` takes on this machine")
    b.add_argument("--shape-weight", type=float, default=0.0, help="λ of the timed loss")
    b.add_argument("--match-weight", type=float, default=0.0, help="μ of the timed loss")
    b.set_defaults(func=_cli_bench)


def _add_score(tsub: Any) -> None:
    d = Recipe()
    s = tsub.add_parser("score", help="model selection on validation trajectories (the test "
                                      "protocol, never the test cases): E_p/E_s at 40/80")
    s.add_argument("data", help="HDF5 dataset from `tpnet data generate` (its validation "
                               "trajectories are scored)")
    s.add_argument("weights", nargs="+", help="native weights files to compare")
    s.add_argument("--horizon", type=int, default=80,
                   help="recursive predictions per validation window")
    s.add_argument("--reading", choices=("released", "squared"), default="released",
                   help="the metrics' reading: released (the authors' code) or squared (the "
                        "paper comparison's and `tpnet eval`'s; docs/evaluation.md)")
    s.add_argument("--spacing", action="store_true",
                   help="also how evenly the one-step predictions cover the ring (world units: "
                        "nearest-neighbour distance, smallest one per set, radius spread)")
    s.add_argument("--val-fraction", type=float, default=d.val_fraction,
                   help="fraction of training-grid trajectories held out for validation "
                        "(as the run's)")
    s.add_argument("--split-seed", type=int, default=d.split_seed,
                   help="seed of the validation split (as the run's)")
    s.add_argument("--allow-other-scene", action="store_true",
                   help="score on a dataset made with another scene convention")
    s.set_defaults(func=_cli_score)


def _add_baselines(tsub: Any) -> None:
    d = Recipe()
    c = tsub.add_parser("baselines", help="copy-last-frame and constant-velocity scores on the "
                                          "validation windows")
    c.add_argument("data", help="HDF5 dataset from `tpnet data generate` (its validation "
                               "trajectories are scored)")
    c.add_argument("--val-fraction", type=float, default=d.val_fraction,
                   help="fraction of training-grid trajectories held out for validation "
                        "(as the run's)")
    c.add_argument("--split-seed", type=int, default=d.split_seed,
                   help="seed of the validation split (as the run's)")
    c.add_argument("--allow-other-scene", action="store_true",
                   help="score on a dataset made with another scene convention")
    c.set_defaults(func=_cli_baselines)


def _add_pack(tsub: Any) -> None:
    k = tsub.add_parser("pack", help="one .tar.gz of a run's state, to keep it or move it to "
                                     "another machine: checkpoint, log, snapshot scores")
    k.add_argument("run_dir", help="the run directory (`tpnet train run -o`)")
    k.add_argument("output", help="the .tar.gz to write; it unpacks into a folder named as "
                                  "the run directory")
    k.add_argument("--optimizer", choices=OPTIMIZER_MODES, default="bf16",
                   help="Adam's state in the packed checkpoint: bf16 (the default: moments in "
                        "bfloat16, the run resumes with that rounding; the full network's state "
                        "57 MB instead of 85), full (exact) or none (the model only)")
    k.set_defaults(func=_cli_pack)


def _cli_pack(args: argparse.Namespace) -> int:
    import shutil
    import tarfile
    import tempfile

    from ..training.checkpoint import repack_checkpoint

    run = Path(args.run_dir)
    if not (run / "checkpoint.json").is_file():
        raise FileNotFoundError(f"{run}: no checkpoint.json (not a training run directory)")
    with tempfile.TemporaryDirectory() as tmp:
        dst = Path(tmp) / run.resolve().name
        repack_checkpoint(run, dst, optimizer=args.optimizer)
        for extra in ("log.jsonl", "snapshots/scores.json"):
            if (run / extra).is_file():
                (dst / extra).parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(run / extra, dst / extra)
        with tarfile.open(args.output, "w:gz") as tar:
            tar.add(dst, arcname=dst.name)
    size = Path(args.output).stat().st_size
    print(f"wrote {args.output}: {size / 1e6:.1f} MB ({run.resolve().name}/: checkpoint with Adam's "
          f"state {args.optimizer}, log, snapshot scores); restore: mkdir -p DIR && tar xzf "
          f"{args.output} -C DIR")
    return 0


def _cli_run(args: argparse.Namespace) -> int:
    import h5py

    from ..training.checkpoint import load_parent
    from ..training.loop import train
    from ..sim.dataset import file_dim
    from ..training.recipe import Recipe, size_config

    recipe = None
    apply_preset(args)
    if args.quantize_aware and not args.init_from and not args.resume:
        raise ValueError("--quantize-aware fine-tunes a trained network: give --init-from "
                         "RUN_DIR|WEIGHTS.h5")
    if not args.resume:
        if not Path(args.data).is_file():
            raise FileNotFoundError(f"dataset not found: {args.data}")
        with h5py.File(args.data, "r") as h:
            m, dim = int(h.attrs["m"]), file_dim(h)
            n_points = int(h["train/normalized"].shape[2]) if "train/normalized" in h else 30
        # the file's dimension and body (30 points in 2-D, 42 in 3-D) give the network's
        cfg = size_config(args.size, m=m, dim=dim, n_out=n_points,
                          lstm_activation=args.lstm_activation)
        if args.init_from:   # the parent's network, for this dataset's window length m
            cfg = dataclasses.replace(load_parent(args.init_from)[2], m=m)
        recipe = Recipe(recipe=args.recipe, epochs=args.epochs or Recipe.epochs,
                        batch=args.batch, lr=args.lr, beta1=args.beta1, beta2=args.beta2,
                        eps=args.adam_eps, schedule=args.schedule, lr_min=args.lr_min,
                        warmup_steps=args.warmup_steps, clip=args.clip, noise=args.noise,
                        noise_kind=args.noise_kind, grad_steps=args.grad_steps,
                        shape_weight=args.shape_weight, match_weight=args.match_weight,
                        pretrain_epochs=args.pretrain_epochs, ramp_epochs=args.ramp_epochs,
                        rollout=args.rollout, head_init=args.head_init, init=args.init,
                        windows=args.windows, init_from=args.init_from,
                        init_optimizer=args.init_optimizer,
                        quantize_aware=args.quantize_aware or "",
                        val_windows=args.val_windows, val_fraction=args.val_fraction, split_seed=args.split_seed,
                        seed=args.seed, config=cfg.to_dict())
    st = train(args.data, args.run_dir, recipe, resume=args.resume, epochs=args.epochs,
               device=args.device, threads=args.threads, max_steps=args.max_steps,
               max_minutes=args.max_minutes, checkpoint_minutes=args.checkpoint_minutes,
               log_every=args.log_every, val_every=args.val_every, progress=not args.quiet,
               export_path=args.export, budget_minutes=args.budget_minutes,
               checkpoint_part_mib=args.checkpoint_part_mib,
               checkpoint_optimizer=args.checkpoint_optimizer,
               allow_other_scene=args.allow_other_scene, compile=args.compile,
               precision=args.precision, snapshots=args.snapshots)
    print(f"{args.run_dir}: step {st['step']}/{st['total_steps']} ({st['stopped']}), "
          f"{st['windows_seen']} windows seen, {st['wall_s']:.0f} s, last validation "
          + json.dumps(st.get("last_val", {})))
    return 0


def _cli_export(args: argparse.Namespace) -> int:
    if args.best:
        import shutil

        from ..training.score import best_snapshot

        if args.dtype != "float32":
            raise ValueError("--best copies a float32 snapshot: leave --dtype out")
        key = MONITORS[args.monitor]
        data = None
        if args.monitor != "val_loss":
            if not args.data:
                raise ValueError(f"--monitor {args.monitor} scores rollouts: give --data GRID.h5")
            from ..training.recipe import Recipe, WindowData
            d = Recipe()                 # the validation split of the runs and of train score
            data = WindowData(args.data, d.val_fraction, d.split_seed, dim=None)
        elif args.data:
            raise ValueError("--data is for a rollout --monitor (ep80); val_loss is in the log")
        path, rec = best_snapshot(args.checkpoint, key=key, data=data)
        shutil.copyfile(path, args.output)
        print(f"wrote {args.output}: {path.name}, {key} {rec[key]:.4g} (the lowest of the run's "
              f"snapshots), {rec.get('windows_seen', '?')} windows seen")
        return 0
    from ..training.native_export import export

    model = export(args.checkpoint, args.output, dtype=args.dtype)
    print(f"wrote {args.output}: {model!r}")
    return 0


def _cli_average(args: argparse.Namespace) -> int:
    from ..training.average import average

    average(args.weights, args.output, args.mix)
    mix = args.mix or [1.0 / len(args.weights)] * len(args.weights)
    print(f"wrote {args.output}: " + " + ".join(f"{w:.3g} x {p}" for w, p in zip(mix, args.weights)))
    return 0


def _cli_bench(args: argparse.Namespace) -> int:
    from ..training.throughput import bench, choose_precision
    from ..training.step import hardware, resolve_device
    from ..training.precision import preferred_precision, resolve_compile
    from ..training.recipe import size_config

    cfg = size_config(args.size)
    dev = resolve_device(args.device)
    res = {p: bench(cfg, batch=args.batch, rollouts=tuple(args.rollouts), iters=args.iters,
                    device=args.device, threads=args.threads, compile=args.compile,
                    shape_weight=args.shape_weight, match_weight=args.match_weight,
                    precision=p)
           for p in args.precisions}
    longest = max(args.rollouts)
    if dev == "cpu" and len(res) == 2:    # what auto would take, from these same timings
        auto = preferred_precision({p: r[longest] for p, r in res.items()})
    else:
        auto = choose_precision("auto", dev, cfg, args.batch, longest, args.threads)[0]
    print(f"train step throughput, size {args.size}, batch {args.batch}, "
          f"compile {resolve_compile(args.compile, dev)}, λ {args.shape_weight:g}, "
          f"μ {args.match_weight:g}, {hardware(dev)}:")
    for k in args.rollouts:
        for p, r in res.items():
            mark = "".join(f"  ({w})" for w, q in (("default", "float32"), ("auto", auto))
                           if p == q and k == longest)
            ratio = (f"  {r[k] / res['float32'][k]:.2f}x float32"
                     if p != "float32" and "float32" in res else "")
            print(f"  {k}-step loss, {p:7s}: {r[k]:8.1f} windows/s{ratio}{mark}")
    return 0


def _cli_score(args: argparse.Namespace) -> int:
    from ..training.recipe import WindowData
    from ..training.score import score_rollouts, spacing_report

    data = WindowData(args.data, args.val_fraction, args.split_seed,
                      allow_other_scene=args.allow_other_scene, dim=None)   # 2-D or 3-D: the file's
    print(f"{data.describe()}\nvalidation trajectories from frame 0, {args.horizon} recursive "
          f"predictions, {args.reading} reading, mean over {len(data.val_traj)} trajectories:")
    at = tuple(h for h in (1, 10, 40, 80) if h <= args.horizon)
    res = score_rollouts(data, args.weights, args.horizon, at, readings=(args.reading,))
    suffix = "" if args.reading == "released" else " " + args.reading
    res = {name: {k.removesuffix(suffix): v for k, v in row.items()} for name, row in res.items()}
    cols = [f"{k}@{h}" for h in at for k in ("Ep", "Es")]
    print(f"  {'':40s}" + "".join(f"{c:>9s}" for c in cols))
    for name, row in res.items():
        print(f"  {name:40s}" + "".join(f"{row[c]:9.3f}" for c in cols))
    if args.spacing:
        sp = spacing_report(data, args.weights)
        print("one-step predictions on every 8th validation window, world units:")
        print(f"  {'':40s}{'nn_mean':>11s}{'nn_min':>11s}{'radius_std':>11s}")
        for name, row in sp.items():
            print(f"  {name:40s}" + "".join(f"{row[k]:11.3f}" for k in
                                            ("nn_mean", "nn_min", "radius_std")))
    return 0


def _cli_baselines(args: argparse.Namespace) -> int:
    from ..training.recipe import WindowData
    from ..training.score import baselines

    data = WindowData(args.data, args.val_fraction, args.split_seed,
                      allow_other_scene=args.allow_other_scene, dim=None)   # 2-D or 3-D: the file's
    print(data.describe())
    for name, ev in baselines(data).items():
        print(f"  {name:15s} " + " ".join(f"{k} {v:.4f}" for k, v in ev.items()))
    return 0

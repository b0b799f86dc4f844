"""Probe: does a long-horizon shape loss fine-tune the shipped model towards beating copy-last
on E_s at 40/80 frames? (model card, issue 6; a negative result, kept so it can be rerun)

    PYTHONPATH=. python bench/probes/long_rollout_probe.py [--steps 200] [--data data/grid-m4.h5]

Starts from ``weights/tpnet-m4.h5`` and trains (PyTorch, ``train`` extra) on segments of the
training grid's *training* trajectories (the same validation split as ``tpnet train run``):
each step rolls ``--horizon`` recursive predictions from ``m`` true frames (a quarter of the
segments start at frame 0 like the test protocol, the rest anywhere), backpropagating through
``--tbptt`` predictions at a time. Loss per prediction ``k``: ``w_k·CD + λ·CD(centred)`` with
``w = 9, 1, ..., 1`` on the first ``--position-steps`` predictions and 0 after (the published
loss up to 8 steps, shape alone beyond), averaged over the horizon. Adam, gradient norm 1.

Every ``--val-every`` steps it prints E_p/E_s (released) at 1, 10, 40, 80 frames on evenly
chosen validation trajectories under the test protocol, after the copy-last baseline on them.
CPU, 2 threads: about 2 s per step at batch 32 and horizon 40, plus 40 s per validation.
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

import tpnet_ref
from tpnet_ref import evaluation as ev
from tpnet_ref.training.recipe import WindowData

HS = (1, 10, 40, 80)


def main(argv: list[str] | None = None) -> int:
    import torch

    from tpnet_ref.training.torch_model import TorchTPNet, chamfer_released, chamfer_shape

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default="data/grid-m4.h5")
    ap.add_argument("--weights", default=None, help="starting weights (default: shipped m=4)")
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--horizon", type=int, default=40)
    ap.add_argument("--tbptt", type=int, default=8)
    ap.add_argument("--position-steps", type=int, default=8)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--lr", type=float, default=5e-5)
    ap.add_argument("--shape-weight", type=float, default=8.0)
    ap.add_argument("--start0", type=float, default=0.25,
                    help="share of segments that start at frame 0")
    ap.add_argument("--val-every", type=int, default=100)
    ap.add_argument("--val-trajectories", type=int, default=120)
    ap.add_argument("--save", default=None, metavar="OUT.h5", help="write the final weights")
    args = ap.parse_args(argv)

    torch.set_num_threads(2)
    torch.manual_seed(0)
    data = WindowData(args.data, 0.05, 0)
    frames, m = data.frames, data.m
    train_traj = np.setdiff1d(np.arange(len(frames)), data.val_traj)
    pick = np.linspace(0, len(data.val_traj) - 1, args.val_trajectories).round().astype(int)
    val = data.val_traj[pick]
    vin, vtruth = frames[val, :m], frames[val, m:m + max(HS)]
    net = TorchTPNet.from_numpy(tpnet_ref.load(args.weights, dtype="float32")).float()
    opt = torch.optim.Adam(net.parameters(), lr=args.lr, betas=(0.9, 0.999), eps=1e-7)
    rng = np.random.default_rng(1)

    def report(step: int, pred: np.ndarray) -> None:
        err = ev.errors(vtruth, pred)
        r = {"step": step}
        for h in HS:
            r[f"Ep@{h}"] = round(float(err["Ep_released"][:, h - 1].mean()), 3)
            r[f"Es@{h}"] = round(float(err["Es_released"][:, h - 1].mean()), 3)
        print(json.dumps(r), flush=True)

    report(-1, ev.copy_last(vin, max(HS)))                      # copy-last, printed as step -1
    report(0, ev.batched_rollout(net.to_numpy("float32"), vin, max(HS)))
    t0 = time.perf_counter()
    h, b = args.horizon, args.batch
    for step in range(1, args.steps + 1):
        tr = rng.choice(train_traj, b)
        start = np.where(rng.random(b) < args.start0, 0,
                         rng.integers(0, frames.shape[1] - m - h + 1, b))
        seq = torch.from_numpy(frames[tr[:, None], start[:, None] + np.arange(m + h)[None]])
        y = seq[:, m:]
        feats = list(net.frame_features(seq[:, :m].reshape(b * m, -1, 2)).view(b, m, -1).unbind(1))
        opt.zero_grad()
        total = 0.0
        for k0 in range(0, h, args.tbptt):
            loss = 0.0
            for k in range(k0, min(h, k0 + args.tbptt)):
                p = net.sequence_head(torch.stack(feats[-m:], 1))
                wp = (9.0 if k == 0 else 1.0) if k < args.position_steps else 0.0
                loss = loss + wp * chamfer_released(p, y[:, k]) \
                    + args.shape_weight * chamfer_shape(p, y[:, k])
                feats.append(net.frame_features(p))
            loss = loss / h
            loss.backward()
            total += float(loss.detach())
            feats = [f.detach() for f in feats[-m:]]
        torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
        opt.step()
        if step % args.val_every == 0 or step == args.steps:
            print(f"step {step}: loss {total:.3f}, {time.perf_counter() - t0:.0f} s", flush=True)
            report(step, ev.batched_rollout(net.to_numpy("float32"), vin, max(HS)))
    if args.save:
        net.to_numpy("float32").save(args.save, source="bench/long_rollout_probe.py")
    return 0


if __name__ == "__main__":
    sys.exit(main())

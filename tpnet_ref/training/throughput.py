"""Training throughput: :func:`bench` times full steps on random windows, and
:func:`choose_precision` takes the faster precision for ``auto`` by such a timing."""
from __future__ import annotations

import time

import numpy as np

from ..config import TPNetConfig
from ..extras import require
from .precision import PRECISIONS, preferred_precision, resolve_compile, step_loss
from .recipe import N_STEPS_MAX, Recipe
from .step import make_optimizer, resolve_device
from .torch_model import TorchTPNet

torch = require("torch", "train")


def choose_precision(precision: str, device: str, config: TPNetConfig, batch: int,
                     rollout: int, threads: int | None, shape_weight: float = 0.0,
                     match_weight: float = 0.0, compile: str = "off",
                     grad_steps: int = 0) -> tuple[str, dict]:
    """``(precision, timings)``: ``float32`` or ``bf16`` as asked, or for ``auto`` the faster
    on this machine. On a GPU: bf16 where ``torch.cuda.is_bf16_supported()``. On the CPU: a
    short timing of the recipe's longest step (``rollout`` predictions at ``batch``, with its
    extra terms and graded steps) in each precision; bf16 when it is at least
    :data:`BF16_MIN_GAIN` times float32's rate (a CPU without fast bfloat16 units, AVX512_BF16
    or AMX, emulates it and keeps float32). ``timings`` maps each timed precision to its
    windows per second."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
    if precision != "auto":
        return precision, {}
    if device == "cuda":
        return ("bf16" if torch.cuda.is_bf16_supported() else "float32"), {}
    timings = {p: bench(config, batch=batch, rollouts=(rollout,), iters=3, warmup=2,
                        device=device, threads=threads, shape_weight=shape_weight,
                        match_weight=match_weight, compile=compile, precision=p,
                        grad_steps=grad_steps)[rollout]
               for p in ("float32", "bf16")}
    return preferred_precision(timings), timings


def bench(config: TPNetConfig | None = None, batch: int = 128, rollouts: tuple[int, ...] = (1, 8),
          iters: int = 5, warmup: int = 1, device: str = "auto", threads: int | None = 2,
          seed: int = 0, shape_weight: float = 0.0, match_weight: float = 0.0,
          compile: str = "off", precision: str = "float32",
          grad_steps: int = 0) -> dict[int, float]:
    """Training throughput, windows per second, of a full step (loss, backward, clip, Adam) for
    each rollout length, on random windows; ``compile``, ``precision`` (``float32`` or
    ``bf16``) and ``grad_steps`` as in :func:`train` (the compile itself falls in the
    ``warmup`` steps, which are not timed)."""
    if threads:
        torch.set_num_threads(int(threads))
    dev = resolve_device(device)
    cfg = config or TPNetConfig()
    torch.manual_seed(seed)
    net = TorchTPNet(cfg).to(dev)
    mode = resolve_compile(compile, dev)
    step_fn = step_loss(net, mode, precision)
    if mode != "off":        # compiling, then (CUDA graphs) a warm-up run and the recording
        warmup = max(warmup, 3)
    opt = make_optimizer(net, Recipe(config=cfg.to_dict()))
    rng = np.random.default_rng(seed)
    x = torch.from_numpy(rng.uniform(0.2, 0.8, (batch, cfg.m, cfg.n_out, cfg.dim))
                         .astype(np.float32)).to(dev)
    y = torch.from_numpy(rng.uniform(0.2, 0.8, (batch, max(N_STEPS_MAX, *rollouts), cfg.n_out,
                                                cfg.dim))
                         .astype(np.float32)).to(dev)
    out = {}
    for k in rollouts:
        for i in range(warmup + iters):
            if i == warmup:
                if dev == "cuda":
                    torch.cuda.synchronize()
                t0 = time.perf_counter()
            opt.zero_grad(set_to_none=True)
            loss = step_fn(x, y, k, 9.0, shape_weight, match_weight, grad_steps)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), 10.0)
            opt.step()
        if dev == "cuda":
            torch.cuda.synchronize()
        out[k] = batch * iters / (time.perf_counter() - t0)
    return out


__all__ = ["bench", "choose_precision"]

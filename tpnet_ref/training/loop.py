"""The training loop: train (and resume) a run, validate it, checkpoint it.

``train(DATA.h5, RUN_DIR, Recipe(...))`` trains :class:`~tpnet_ref.training.torch_model.TorchTPNet`
on the windows of a ``tpnet data generate`` file (:class:`~tpnet_ref.training.recipe.WindowData`);
a step's pieces are in :mod:`~tpnet_ref.training.step`, how it is compiled and in which
precision in :mod:`~tpnet_ref.training.precision`, the timing of steps in
:mod:`~tpnet_ref.training.throughput`; :func:`~tpnet_ref.training.native_export.export` writes
the native HDF5 weights with provenance. Recipe: ``docs/training.md``.

Validation is always scored with the recipe's ``rollout``-step loss and the Chamfer distances of
its first and last predictions; the 60 test cases are never read. ``init_from`` starts a new run
(fresh Adam and schedule) from another run's weights or a native file and carries its provenance;
the parent may have another window length ``m`` (no weight depends on m).

Determinism: the epoch's window order comes from ``default_rng([seed, epoch])`` and the noise of
step ``s`` from a torch generator seeded with ``(seed, s)``, so a run resumed from a full
checkpoint (model + Adam state + position, :mod:`~tpnet_ref.training.checkpoint`) computes
exactly what the uninterrupted run computes (on the same device and thread count).
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from ..extras import require
from ..weights.provenance import file_sha256
from .checkpoint import (OPTIMIZER_MODES, SIDECAR_NAME, load_checkpoint, load_parent,
                         load_parent_optimizer,
                         save_checkpoint)
from .lineage import inherited
from .native_export import export
from .precision import resolve_compile, step_loss
from .recipe import N_STEPS_MAX, Recipe, WindowData
from .step import input_noise, make_optimizer, resolve_device, hardware
from .throughput import bench, choose_precision
from .torch_model import TorchTPNet, chamfer_released, chamfer_shape, init_keras

torch = require("torch", "train")

LOG_NAME = "log.jsonl"


def init_head_template(net: Any, data: "WindowData", weight_scale: float = 0.1) -> None:
    """Data-dependent initialisation of the sigmoid head (``--head-init template``).

    The head's bias becomes the logit of a ring (a sphere in 3-D) of the body's rest radius (measured on the
    first frame of the training trajectories) around the mean training position, and its
    weights are scaled by ``weight_scale``: the untrained network then outputs a ring of the
    right size near the middle of the data instead of 30 points scattered around 0.5, so the
    first steps learn motion instead of first collapsing the point cloud into a shape. Output
    order is free (the loss is a Chamfer distance), so ring index ``i`` is only a slot."""
    train_traj = np.setdiff1d(np.arange(data.frames.shape[0]), data.val_traj)
    n_out, dim = net.config.n_out, net.config.dim
    f0 = data.frames[train_traj, 0].astype(np.float64)                  # (T, N, dim)
    radius = float(np.linalg.norm(f0 - f0.mean(1, keepdims=True), axis=-1).mean())
    centre = data.frames[train_traj].astype(np.float64).reshape(-1, dim).mean(0)
    if dim == 2:
        a = 2 * np.pi * np.arange(n_out) / n_out
        unit = np.stack([np.sin(a), np.cos(a)], axis=1)
    else:                       # a Fibonacci sphere: n_out points spread evenly
        z = 1 - (2 * np.arange(n_out) + 1) / n_out
        a = np.pi * (3 - np.sqrt(5)) * np.arange(n_out)
        r = np.sqrt(1 - z * z)
        unit = np.stack([r * np.cos(a), r * np.sin(a), z], axis=1)
    ring = centre + radius * unit
    ring = np.clip(ring, 1e-4, 1 - 1e-4)
    with torch.no_grad():
        net.head.bias.copy_(torch.from_numpy(np.log(ring / (1 - ring)).reshape(-1)))
        net.head.weight.mul_(weight_scale)


# ------------------------------------------------------------------------------------- eval
def dead_units(net: Any, x: Any) -> dict[str, int]:
    """Units that are zero on every input of ``x`` (``(B, m, N, dim)`` windows): per ReLU
    layer of the feature extractor (a per-point unit counts as dead when it is <= 0 at every
    point of every frame; such a unit gets no gradient) and per BiLSTM (both directions'
    outputs; with the ReLU cell a unit whose cell state never turns positive), each
    ``{layer: dead}`` with ``{layer + "/of": units}`` beside it. The network's own forward
    pass runs; hooks read each layer's output (a ReLU's input: positive where its output is)."""
    out: dict[str, int] = {}

    def counter(name: str) -> Any:
        def hook(_mod: Any, _inp: Any, a: Any) -> None:
            alive = (a.reshape(-1, a.shape[-1]) > 0).any(dim=0)
            out[name] = int((~alive).sum())
            out[name + "/of"] = int(alive.numel())
        return hook

    layers = {**{f"mlp1.{i}": lin for i, lin in enumerate(net.mlp1)},
              **{f"mlp2.{i}": lin for i, lin in enumerate(net.mlp2)}, "global": net.global_fc,
              **{f"lstm{i}": getattr(net, f"lstm{i}")
                 for i in range(1, len(net.config.lstm_units) + 1)}}
    handles = [mod.register_forward_hook(counter(name)) for name, mod in layers.items()]
    was = net.training
    net.eval()
    try:
        with torch.no_grad():
            net(x)
    finally:
        for h in handles:
            h.remove()
        net.train(was)
    return out


def evaluate(net: Any, data: WindowData, wins: np.ndarray, r: Recipe, device: str,
             batch: int = 256) -> dict[str, float]:
    """Validation: the recipe's ``r.rollout``-step loss (weights ``first_weight``, 1, ...; with
    its shape term when ``r.shape_weight`` > 0), the released Chamfer distance of the first and
    last predictions (``val_cd1``, ``val_cdK``) and their shape errors (``val_es1``,
    ``val_esK``), averaged over ``wins``."""
    if len(wins) == 0:
        return {}
    steps = r.rollout
    tot = np.zeros(steps)
    tot_s = np.zeros(steps)
    was = net.training
    net.eval()
    with torch.no_grad():
        for i in range(0, len(wins), batch):
            x, y = data.gather(wins[i:i + batch])
            x = torch.from_numpy(x).to(device)
            y = torch.from_numpy(y[:, :steps]).to(device)
            pred = net.rollout(x, steps)
            tot += chamfer_released(pred, y).double().cpu().numpy() * len(x)
            tot_s += chamfer_shape(pred, y).double().cpu().numpy() * len(x)
    net.train(was)
    cd, es = tot / len(wins), tot_s / len(wins)
    w = np.ones(steps)
    w[0] = r.first_weight
    return {"val_loss": float((cd * w).sum() + r.shape_weight * (es * w).sum()),
            "val_cd1": float(cd[0]), f"val_cd{steps}": float(cd[-1]),
            "val_es1": float(es[0]), f"val_es{steps}": float(es[-1])}


# ------------------------------------------------------------------------------------- train
def _log(run_dir: Path, rec: dict) -> None:
    with open(run_dir / LOG_NAME, "a") as f:
        f.write(json.dumps(rec, sort_keys=True) + "\n")


def _trim_log(run_dir: Path, step: int) -> None:
    """Drop log records past ``step`` (written after the checkpoint a resumed run restarts
    from): the resumed run redoes those steps with the same batches and logs them again."""
    path = run_dir / LOG_NAME
    if path.exists():
        keep = [s for s in path.read_text().splitlines(keepends=True)
                if s.strip() and json.loads(s).get("step", 0) <= step]
        path.write_text("".join(keep))


@dataclasses.dataclass
class TrainSettings:
    """How one call of :func:`train` runs (the ``tpnet train run`` flags other than the recipe's).

    Not the recipe: these belong to the process, not the run; only ``val_every``,
    ``snapshots``, the checkpoint's ``part_mib``/``optimizer``, ``compile`` and a budget's
    outcome are written to ``checkpoint.json`` (and the first four are kept on resume unless
    given again).

    - ``resume``: continue the run in ``run_dir`` with its stored recipe.
    - ``epochs``: the run's length (on resume: extends or shortens it; the cosine schedule
      follows the new length from there).
    - ``device`` (``auto``, ``cpu``, ``cuda``), ``threads`` (torch CPU threads; None: torch's).
    - ``max_steps`` (a global step count), ``max_minutes``: stop early with a checkpoint, so a
      long run can be done in pieces (as do SIGINT/SIGTERM, after the current step).
    - ``checkpoint_minutes``: a checkpoint every that many minutes (also at every validation
      and when stopping).
    - ``log_every``: steps between train-loss records of ``log.jsonl``; ``val_every``: also
      validate every that many steps (None: at epoch ends only; on resume: the run's).
    - ``limit_windows``: use only that many windows of the dataset; ``progress``: a tqdm bar.
    - ``snapshots``: after every validation's checkpoint, also export the native weights file
      ``snapshots/step-NNNNNNN.h5`` (learning curves scored later with ``tpnet train score``);
      a run that completes between validations is validated (and snapshotted) at its last step.
      None: False for a new run, the run's own on resume.
    - ``export_path``: when the run completes, write the native weights file (:func:`export`).
    - ``budget_minutes`` (new runs only): fit the run to a wall-clock budget on this device: a
      few steps of the longest loss (``r.rollout`` predictions, batch ``r.batch``) are timed on
      random windows and the run's length (hence its learning-rate schedule) is set to 90 % of
      what that rate allows; ``max_minutes`` defaults to the budget as a hard stop.
    - ``checkpoint_part_mib`` writes the checkpoint as parts of at most that many MiB and
      ``checkpoint_optimizer`` (``full``, ``bf16``, ``none``) how much of Adam's state it keeps
      (:mod:`~tpnet_ref.training.checkpoint`). A run resumed from a checkpoint without optimizer
      state starts a fresh Adam at its step (recorded in ``optimizer_resets``).
    - ``allow_other_scene``: train on a dataset made with another scene convention than the
      simulator's default.
    - ``compile`` (:data:`COMPILE_MODES`) captures the step's loss with ``torch.compile``
      (:func:`step_loss`); recorded per call in ``compile`` of ``checkpoint.json``.
    - ``precision`` (:data:`PRECISIONS`): the step's arithmetic (``tpnet train run`` defaults
      to ``auto``, chosen per call by a short timing, :func:`choose_precision`); recorded per call in ``precision`` of
      ``checkpoint.json`` with the timing, and in the exported file's provenance.
    """
    resume: bool = False
    epochs: float | None = None
    device: str = "auto"
    threads: int | None = 2
    max_steps: int | None = None
    max_minutes: float | None = None
    checkpoint_minutes: float = 5.0
    log_every: int = 50
    val_every: int | None = None
    limit_windows: int | None = None
    progress: bool = True
    export_path: str | os.PathLike | None = None
    budget_minutes: float | None = None
    checkpoint_part_mib: float | None = None
    checkpoint_optimizer: str | None = None
    allow_other_scene: bool = False
    compile: str = "off"
    precision: str = "float32"
    snapshots: bool | None = None


def train(data_path: str | os.PathLike, run_dir: str | os.PathLike, recipe: Recipe | None = None,
          settings: TrainSettings | None = None, **changes: Any) -> dict:
    """Train (or, with ``resume``, continue) the run in ``run_dir``; returns the final state
    (what ``checkpoint.json`` holds).

    ``settings`` (:class:`TrainSettings`) with ``changes`` applied to it: ``train(data, run,
    recipe, threads=1, max_steps=100)`` and ``train(data, run, recipe, TrainSettings(...))``
    alike. The run: set up (:class:`_Run`: state, data, network, optimizer, budget), the first
    validation, then steps (:meth:`_Run.step`) with validation and checkpoints at epoch ends,
    until the run's length, ``max_steps``, ``max_minutes`` or a stop signal; a last checkpoint,
    and the export when the run is complete."""
    s = dataclasses.replace(settings or TrainSettings(), **changes)
    run = _Run(data_path, Path(run_dir), recipe, s)
    run.state["stopped"] = run.fit()
    if run.state["stopped"] == "done":
        run.finish()
    run.checkpoint()
    if s.export_path is not None and run.state["step"] >= run.total:
        export(run.run_dir, s.export_path)
    return run.state


def _start_state(run_dir: Path, recipe: Recipe | None,
                 s: TrainSettings) -> tuple[dict | None, dict, Recipe, int | None]:
    """``(payload, state, recipe, val_every)`` a call starts from: the checkpoint's on resume
    (log records past it dropped), else a new state at step 0 (refused where a run exists)."""
    payload: dict | None = None
    val_every = s.val_every
    if s.resume:
        payload, state = load_checkpoint(run_dir)
        _trim_log(run_dir, int(state["step"]))
        r = Recipe.from_dict(state["recipe"])
        if val_every is None:                 # keep the run's validation cadence
            val_every = state.get("val_every")
        if s.snapshots is None:               # and its snapshots
            s.snapshots = bool(state.get("snapshots", False))
    else:
        if (run_dir / SIDECAR_NAME).exists():
            raise ValueError(f"{run_dir} already holds a run; pass --resume or another directory")
        r = recipe or Recipe()
        state = {"step": 0, "windows_seen": 0, "wall_s": 0.0, "nonfinite_skipped": 0,
                 "epoch_loss_sum": 0.0, "epoch_loss_n": 0}
    if s.epochs is not None:
        r.epochs = float(s.epochs)
    return payload, state, r, val_every


def _load_data(data_path: str | os.PathLike, r: Recipe, s: TrainSettings) -> WindowData:
    data = WindowData(data_path, r.val_fraction, r.split_seed, s.limit_windows,
                      s.allow_other_scene, horizon=max(N_STEPS_MAX, r.rollout),
                      windows=r.windows, dim=r.tpnet_config.dim)
    if data.m != r.tpnet_config.m:
        raise ValueError(f"dataset has m={data.m}, the recipe's network m={r.tpnet_config.m}")
    if len(data.train_win) == 0:
        raise ValueError(f"{data_path}: no training windows")
    return data


def _build_network(r: Recipe, dev: str, data: WindowData, payload: dict | None,
                   state: dict) -> tuple[Any, Any]:
    """``(net, optimizer)``: seeded initialisation, then the checkpoint's weights and Adam state
    (resume), the parent's weights (``init_from``; with ``init_optimizer`` also its Adam state)
    or the template head."""
    cfg = r.tpnet_config
    torch.manual_seed(r.seed)
    net = TorchTPNet(cfg)
    net.set_fake_quant(r.quantize_aware)
    if payload is None and not r.init_from and r.init == "keras":
        init_keras(net)
    net = net.to(dev)
    if payload is None and r.init_from:
        parent, pstate, pcfg = load_parent(r.init_from)
        # the weights do not depend on m (the LSTMs run over any number of frames), so a
        # model for another window length may start from them
        if dataclasses.replace(pcfg, m=cfg.m) != cfg:
            raise ValueError(f"--init-from {r.init_from}: its network {pcfg} differs from the "
                             f"recipe's {cfg}")
        if pcfg.m != cfg.m:              # the stored config names the parent's m
            parent = {**parent, "_extra_state": net.get_extra_state()}
        net.load_state_dict(parent)
        state["inherited"] = inherited(r.init_from, pstate)
    elif payload is None and r.head_init == "template":
        init_head_template(net, data)
    opt = make_optimizer(net, r)
    if payload is None and r.init_optimizer:
        opt.load_state_dict(load_parent_optimizer(r.init_from))
        for grp in opt.param_groups:        # the moments are the parent's, the constants ours
            grp.update(lr=r.lr, betas=(r.beta1, r.beta2), eps=r.eps)
    if payload is not None:
        net.load_state_dict(payload["model"])
        if "optimizer" in payload:
            opt.load_state_dict(payload["optimizer"])
        else:                       # saved with checkpoint_optimizer="none": a fresh Adam here
            state.setdefault("optimizer_resets", []).append(int(state["step"]))
    return net, opt


def _checkpoint_settings(state: dict, s: TrainSettings) -> dict:
    """The run's ``checkpoint_settings`` (kept in ``state``), updated by those given."""
    ck = state.setdefault("checkpoint_settings", {"part_mib": None, "optimizer": "full"})
    if s.checkpoint_part_mib is not None:
        ck["part_mib"] = float(s.checkpoint_part_mib) if s.checkpoint_part_mib > 0 else None
    if s.checkpoint_optimizer is not None:
        if s.checkpoint_optimizer not in OPTIMIZER_MODES:
            raise ValueError(f"checkpoint_optimizer must be one of {OPTIMIZER_MODES}, "
                             f"got {s.checkpoint_optimizer!r}")
        ck["optimizer"] = s.checkpoint_optimizer
    return ck


def _validation_windows(data: WindowData, r: Recipe) -> np.ndarray:
    """The validation windows used: all, or ``r.val_windows`` evenly spaced ones."""
    val_win = data.val_win
    if r.val_windows and len(val_win) > r.val_windows:
        val_win = val_win[np.linspace(0, len(val_win) - 1, r.val_windows).round().astype(int)]
    return val_win


def _progress_bar(s: TrainSettings, r: Recipe, start: int, stop: int) -> Any:
    if not s.progress:
        return None
    try:
        from tqdm import tqdm
    except ImportError:  # tqdm is optional
        return None
    return tqdm(total=stop, initial=min(start, stop), unit="step", desc=f"train {r.recipe}",
                dynamic_ncols=True)


class _Run:
    """One call of :func:`train`: the recipe ``r``, data, network, optimizer and ``state`` (what
    ``checkpoint.json`` holds), set up on construction."""

    def __init__(self, data_path: str | os.PathLike, run_dir: Path, recipe: Recipe | None,
                 s: TrainSettings) -> None:
        self.run_dir, self.s = run_dir, s
        self.t_start = time.perf_counter()
        if s.threads:
            torch.set_num_threads(int(s.threads))
        self.dev = resolve_device(s.device)
        self.compile_mode = resolve_compile(s.compile, self.dev)
        payload, self.state, self.r, self.val_every = _start_state(run_dir, recipe, s)
        r, state = self.r, self.state
        self.data = _load_data(data_path, r, s)
        self.net, self.opt = _build_network(r, self.dev, self.data, payload, state)
        self.ck = _checkpoint_settings(state, s)
        self.precision, self.precision_timing = choose_precision(
            s.precision, self.dev, r.tpnet_config, r.batch, r.rollout, s.threads,
            r.shape_weight, r.match_weight, self.compile_mode, r.grad_steps)
        run_dir.mkdir(parents=True, exist_ok=True)

        self.n_train = len(self.data.train_win)
        # full batches only: every step has batch r.batch
        self.spe = spe = max(1, self.n_train // r.batch)
        max_minutes = s.max_minutes
        if s.budget_minutes is not None and not s.resume:
            self._fit_budget(s.budget_minutes)
            if max_minutes is None:
                max_minutes = float(s.budget_minutes)
        self.total = max(1, int(round(r.epochs * spe)))
        state.update({"recipe": asdict(r), "data": str(data_path),
                      "data_sha256": file_sha256(data_path), "steps_per_epoch": spe,
                      "total_steps": self.total, "train_windows": self.n_train,
                      "val_windows": len(self.data.val_win), "device": self.dev,
                      "hardware": hardware(self.dev), "torch": torch.__version__,
                      "val_every": self.val_every, "snapshots": bool(self.s.snapshots)})
        state.setdefault("compile", []).append({"step": int(state["step"]),
                                                "mode": self.compile_mode})
        state.setdefault("precision", []).append({"step": int(state["step"]),
                                                  "mode": self.precision,
                                                  "timing_windows_per_s": self.precision_timing})
        self.val_win = _validation_windows(self.data, r)
        state["val_windows_used"] = len(self.val_win)
        if state["step"] == 0 and not s.resume:
            ev = evaluate(self.net, self.data, self.val_win, r, self.dev)
            _log(run_dir, {"kind": "val", "step": 0, "epoch": 0.0, "windows_seen": 0,
                           "wall_s": 0.0, **ev, "dead": self.dead()})
            state["last_val"] = ev
        self.stop_step = self.total if s.max_steps is None else min(self.total, int(s.max_steps))
        self.deadline = None if max_minutes is None else self.t_start + 60.0 * max_minutes
        self.wall0 = state["wall_s"]
        self.last_ckpt = time.perf_counter()
        self._last_step_info: tuple[int, float] | None = None    # (rollout, lr) of the last step

    def dead(self) -> dict[str, int]:
        """:func:`dead_units` over the inputs of (at most 1,024 of) the validation windows."""
        wins = self.val_win[:: max(1, len(self.val_win) // 1024)][:1024]
        if len(wins) == 0:
            return {}
        x, _ = self.data.gather(wins)
        return dead_units(self.net, torch.from_numpy(x).to(self.dev))

    def _fit_budget(self, minutes: float) -> None:
        """Set the run's epochs to 90 % of what ``minutes`` allow at the benchmarked rate."""
        if not minutes > 0:
            raise ValueError(f"budget_minutes must be > 0, got {minutes}")
        r = self.r
        wps = bench(r.tpnet_config, batch=r.batch, rollouts=(r.rollout,), iters=5, warmup=2,
                    device=self.dev, threads=self.s.threads, seed=r.seed,
                    shape_weight=r.shape_weight, match_weight=r.match_weight,
                    compile=self.compile_mode, precision=self.precision,
                    grad_steps=r.grad_steps)[r.rollout]
        r.epochs = max(1.0 / self.spe, 0.9 * 60.0 * minutes * wps / (self.spe * r.batch))
        self.state["budget"] = {"minutes": float(minutes), "bench_windows_per_s": float(wps),
                                "epochs": r.epochs}

    def wall(self) -> float:
        """The run's wall time so far (earlier calls included)."""
        return self.wall0 + (time.perf_counter() - self.t_start)

    def checkpoint(self) -> None:
        self.state["wall_s"] = self.wall()
        save_checkpoint(self.run_dir, self.net, self.opt, self.state, self.ck["part_mib"],
                        self.ck["optimizer"])
        self.last_ckpt = time.perf_counter()

    def fit(self) -> str:
        """Steps until the end or a stop; returns why it stopped (``done``, ``max_steps``,
        ``max_minutes``, ``interrupted``)."""
        bar = _progress_bar(self.s, self.r, self.state["step"], self.stop_step)
        if self.s.progress:
            print(self.data.describe(), file=sys.stderr)
        self.net.train()
        step_fn = step_loss(self.net, self.compile_mode, self.precision)
        stop_signal: list[int] = []
        restore = _install_stop_handlers(stop_signal)
        self._perm_epoch, self._perm = -1, np.empty(0, dtype=np.int64)
        self._consecutive_bad = 0
        reason = "done"
        try:
            while self.state["step"] < self.stop_step:
                lv, n_steps, lr = self.step(step_fn)
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix(loss=f"{lv:.4g}", k=n_steps, lr=f"{lr:.2g}")
                self.after_step(lv, n_steps, lr, bar)
                if self.deadline is not None and time.perf_counter() > self.deadline:
                    reason = "max_minutes"
                    break
                if stop_signal:
                    reason = "interrupted"
                    break
            else:
                reason = "done" if self.state["step"] >= self.total else "max_steps"
        finally:
            restore()
        if bar is not None:
            bar.close()
        return reason

    def batch(self, step: int) -> tuple[Any, Any, int]:
        """``(x, y, windows)`` of ``step``: the epoch's permutation from ``(seed, epoch)``, the
        input noise (:func:`input_noise`) from a generator seeded with ``(seed, step)``."""
        r = self.r
        epoch, b = divmod(step, self.spe)
        if epoch != self._perm_epoch:
            self._perm = np.random.default_rng([r.seed, epoch]).permutation(self.n_train)
            self._perm_epoch = epoch
        idx = self._perm[b * r.batch:(b + 1) * r.batch]
        x, y = self.data.gather(self.data.train_win[np.sort(idx)])
        x = input_noise(torch.from_numpy(x), r.noise, r.noise_kind, r.seed, step)
        return x.to(self.dev), torch.from_numpy(y).to(self.dev), len(idx)

    def step(self, step_fn: Any) -> tuple[float, int, float]:
        """One optimisation step (a non-finite loss is skipped; 10 in a row stop the run);
        returns ``(loss, rollout length, learning rate)``."""
        r, state = self.r, self.state
        step = state["step"]
        x, y, n_win = self.batch(step)
        n_steps = r.steps_at(step / self.spe)
        lr = r.lr_at(step, self.total)
        for grp in self.opt.param_groups:
            grp["lr"] = lr
        self.opt.zero_grad(set_to_none=True)
        loss = step_fn(x, y, n_steps, r.first_weight, r.shape_weight, r.match_weight,
                       r.grad_steps)
        lv = float(loss.detach())
        if not math.isfinite(lv):
            state["nonfinite_skipped"] += 1
            self._consecutive_bad += 1
            if self._consecutive_bad >= 10:
                self.checkpoint()
                raise FloatingPointError(f"loss not finite for 10 steps in a row at step {step}")
        else:
            self._consecutive_bad = 0
            loss.backward()
            if r.clip > 0:
                torch.nn.utils.clip_grad_norm_(self.net.parameters(), r.clip)
            self.opt.step()
            state["epoch_loss_sum"] += lv
            state["epoch_loss_n"] += 1
        state["step"] = step + 1
        state["windows_seen"] += n_win
        return lv, n_steps, lr

    def after_step(self, lv: float, n_steps: int, lr: float, bar: Any) -> None:
        """The train-loss record every ``log_every`` steps; validation and a checkpoint at every
        epoch end (and every ``val_every`` steps), else a checkpoint when one is due."""
        state, step = self.state, self.state["step"]
        if self.s.log_every and step % self.s.log_every == 0:
            _log(self.run_dir, {"kind": "train", "step": step, "epoch": step / self.spe,
                                "loss": lv, "rollout": n_steps, "lr": lr,
                                "windows_seen": state["windows_seen"], "wall_s": self.wall()})
        self._last_step_info = (n_steps, lr)
        if self.validation_due(step):
            self.validate_and_snapshot(n_steps, lr, step % self.spe == 0, bar)
        elif time.perf_counter() - self.last_ckpt > 60.0 * self.s.checkpoint_minutes:
            self.checkpoint()

    def validation_due(self, step: int) -> bool:
        """Whether ``step`` is validated: every epoch end and every ``val_every`` steps."""
        return step % self.spe == 0 or bool(self.val_every and step % self.val_every == 0)

    def validate_and_snapshot(self, n_steps: int, lr: float, epoch_end: bool, bar: Any) -> None:
        """Validation, a checkpoint, and with ``snapshots`` the step's weights file."""
        step = self.state["step"]
        self.validate(n_steps, lr, epoch_end, bar)
        self.checkpoint()
        if self.s.snapshots:
            (self.run_dir / "snapshots").mkdir(exist_ok=True)
            export(self.run_dir, self.run_dir / "snapshots" / f"step-{step:07d}.h5")

    def finish(self) -> None:
        """At the run's last step: its validation (and snapshot) unless that step had one, so
        the end of a schedule, the file a run ships, is on its learning curve."""
        if self._last_step_info is not None and not self.validation_due(self.state["step"]):
            self.validate_and_snapshot(*self._last_step_info, False, None)

    def validate(self, n_steps: int, lr: float, epoch_end: bool, bar: Any) -> None:
        """Score the validation windows and log them with the epoch's mean training loss (reset
        at an epoch end)."""
        state = self.state
        ev = evaluate(self.net, self.data, self.val_win, self.r, self.dev)
        n = max(1, state["epoch_loss_n"])
        rec = {"kind": "val", "step": state["step"], "epoch": state["step"] / self.spe,
               "train_loss": state["epoch_loss_sum"] / n, "rollout": n_steps, "lr": lr,
               "windows_seen": state["windows_seen"], "wall_s": self.wall(), **ev,
               "dead": self.dead()}
        _log(self.run_dir, rec)
        state["last_val"] = ev
        if epoch_end:
            state["epoch_loss_sum"], state["epoch_loss_n"] = 0.0, 0
        if bar is not None:
            bar.write(f"epoch {rec['epoch']:.2f}: train {rec['train_loss']:.4g} "
                      + " ".join(f"{k} {v:.4g}" for k, v in ev.items()))


def _install_stop_handlers(flag: list[int]):
    """SIGINT / SIGTERM set ``flag``; the loop stops after the current step with a checkpoint
    (a second signal acts as usual). Only in the main thread; returns a function that restores
    the previous handlers."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    old = {}

    def handler(signum: int, frame: Any) -> None:
        flag.append(signum)
        for sig, h in old.items():
            signal.signal(sig, h)

    for sig in (signal.SIGINT, signal.SIGTERM):
        old[sig] = signal.getsignal(sig)
        signal.signal(sig, handler)

    def restore() -> None:
        for sig, h in old.items():
            signal.signal(sig, h)
    return restore


__all__ = ["train", "TrainSettings", "evaluate", "dead_units", "init_head_template", "LOG_NAME"]

"""Training TP-Net in PyTorch (optional ``train`` extra) and export to the native weights file.

``tpnet train run DATA.h5 -o RUN_DIR ...`` trains :class:`~tpnet_ref.torch_model.TorchTPNet` on
the windows of a ``tpnet data generate`` file; ``tpnet train export RUN_DIR|CKPT OUT.h5`` writes
the native HDF5 weights through :func:`tpnet_ref.weights.import_torch` with provenance.
``tpnet train bench`` measures throughput. Everything about the recipe is in ``docs/training.md``.

Recipes (``--recipe``):

* ``paper``: every step is the published loss, ``9·CD(P_{t+1}) + Σ_{i=2..8} CD(P_{t+i})`` over 8
  recursive predictions (released-code Chamfer: Euclidean, not squared, both directions summed);
  ``--rollout K`` shortens it to K predictions (same weights).
* ``curriculum`` (default): ``--pretrain-epochs`` of the 1-step loss (teacher forced, the first
  term alone), then the recursive loss with the rollout length growing linearly from 1 to 8 over
  ``--ramp-epochs``, then the ``--rollout``-step loss (8, the published one, by default). Same
  weights 9, 1, 1, ...

Both: Adam with the released code's constants (lr 1e-3, beta_1 0.99, beta_2 0.999, eps 1e-7),
optional linear warm-up and cosine decay, gradient-norm clipping, optional Gaussian noise on the
input coordinates (never on the targets). Validation is a held-out set of whole training-grid
*trajectories* (``--val-fraction``), always scored with the recipe's ``--rollout``-step loss and the
Chamfer distances of its first and last predictions; the 60 test cases are never read.
``--init-from RUN`` starts a new run (fresh Adam and schedule) from another run's weights and
carries its provenance. The parent may have another window length ``m``: no weight depends on m
(the LSTMs run over any number of frames), so the m = 3 and m = 5 models start from m = 4's.

Determinism: the epoch's window order comes from ``default_rng([seed, epoch])`` and the noise of
step ``s`` from a torch generator seeded with ``(seed, s)``, so a run resumed from a checkpoint
(model + Adam state + position, see :func:`save_checkpoint`) computes exactly what the
uninterrupted run computes (on the same device and thread count).

torch is imported inside the functions only; ``import tpnet_ref.train`` is cheap.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import platform
import sys
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from .config import TPNetConfig

CKPT_NAME = "checkpoint.pt"
SIDECAR_NAME = "checkpoint.json"
LOG_NAME = "log.jsonl"
N_STEPS_MAX = 8


@dataclass
class Recipe:
    """Everything that decides what a run computes (stored with every checkpoint)."""

    recipe: str = "curriculum"          # "paper" or "curriculum"
    epochs: float = 100                 # may be fractional: the run is round(epochs * steps/epoch)
    batch: int = 128
    lr: float = 1e-3
    beta1: float = 0.99
    beta2: float = 0.999
    eps: float = 1e-7
    schedule: str = "cosine"            # "constant" or "cosine" (to lr_min at the last step)
    lr_min: float = 1e-5
    warmup_steps: int = 200
    clip: float = 10.0                  # max gradient norm; 0 = no clipping
    noise: float = 0.0                  # std of Gaussian input noise, normalised units
    first_weight: float = 9.0
    shape_weight: float = 0.0           # λ of the added shape term λ·Σ w_i·CD(centred sets)
    match_weight: float = 0.0           # μ of the added term μ·Σ w_i·EMD (optimal bijection)
    rollout: int = N_STEPS_MAX          # length of the recursive loss (8 published)
    pretrain_epochs: float = 2.0        # curriculum: 1-step epochs
    ramp_epochs: float = 4.0            # curriculum: epochs to grow the rollout 1 -> rollout
    head_init: str = "default"          # "default" or "template" (output bias = a ring, see below)
    init_from: str = ""                 # fine-tune: start from this run's (or .h5 file's) weights
    val_windows: int = 0                # validate on this many evenly spaced windows (0: all)
    val_fraction: float = 0.05
    split_seed: int = 0                 # which trajectories are validation (independent of seed)
    seed: int = 0
    config: dict = field(default_factory=lambda: TPNetConfig().to_dict())

    def __post_init__(self) -> None:
        if self.recipe not in ("paper", "curriculum"):
            raise ValueError(f"recipe must be 'paper' or 'curriculum', got {self.recipe!r}")
        if self.schedule not in ("constant", "cosine"):
            raise ValueError(f"schedule must be 'constant' or 'cosine', got {self.schedule!r}")
        if not self.epochs > 0 or self.batch < 1:
            raise ValueError("epochs must be > 0 and batch >= 1")
        if self.head_init not in ("default", "template"):
            raise ValueError(f"head_init must be 'default' or 'template', got {self.head_init!r}")
        if self.val_windows < 0:
            raise ValueError("val_windows must be >= 0")
        if not 1 <= self.rollout <= N_STEPS_MAX:
            raise ValueError(f"rollout must be in 1..{N_STEPS_MAX}, got {self.rollout}")
        if not 0 <= self.val_fraction < 1:
            raise ValueError(f"val_fraction must be in [0, 1), got {self.val_fraction}")
        if self.noise < 0 or self.clip < 0 or self.shape_weight < 0 or self.match_weight < 0:
            raise ValueError("noise, clip, shape_weight and match_weight must be >= 0")
        if isinstance(self.config, TPNetConfig):
            self.config = self.config.to_dict()
        self.config = {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.config.items()}

    @property
    def tpnet_config(self) -> TPNetConfig:
        return TPNetConfig.from_dict(dict(self.config))

    def steps_at(self, epoch_pos: float) -> int:
        """Rollout length of the loss at fractional epoch ``epoch_pos``."""
        if self.recipe == "paper":
            return self.rollout
        if epoch_pos < self.pretrain_epochs:
            return 1
        if self.ramp_epochs <= 0:
            return self.rollout
        t = (epoch_pos - self.pretrain_epochs) / self.ramp_epochs
        return int(min(self.rollout, 1 + math.floor(t * self.rollout)))

    def lr_at(self, step: int, total: int) -> float:
        warm = min(1.0, (step + 1) / self.warmup_steps) if self.warmup_steps > 0 else 1.0
        if self.schedule == "constant":
            return self.lr * warm
        frac = min(1.0, step / max(1, total - 1))
        return warm * (self.lr_min + 0.5 * (self.lr - self.lr_min) * (1 + math.cos(math.pi * frac)))

    @classmethod
    def from_dict(cls, d: dict) -> "Recipe":
        names = {f.name for f in fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"unknown recipe fields: {sorted(unknown)}")
        return cls(**d)


# ------------------------------------------------------------------------------------- data
class WindowData:
    """The windows of a ``tpnet data generate`` file, gathered on demand from the trajectories
    (no copy of each window is held): ``batch(idx)`` -> inputs ``(B, m, N, 2)`` and targets
    ``(B, 8, N, 2)``, float32, normalised. Train/validation split by trajectory."""

    def __init__(self, path: str | os.PathLike, val_fraction: float, seed: int,
                 limit_windows: int | None = None) -> None:
        import h5py

        if not Path(path).is_file():
            raise FileNotFoundError(f"dataset not found: {path}")
        with h5py.File(path, "r") as h:
            self.m = int(h.attrs["m"])
            self.n_targets = int(h.attrs["n_targets"])
            g = h["train"]
            if "windows" not in g:
                raise KeyError(f"{path}: /train has no windows")
            if not g["done"][...].all():
                raise ValueError(f"{path}: /train is incomplete; run generate again to finish it")
            self.frames = g["normalized"][...]
            win = g["windows"][...]
        self.path = str(path)
        n_traj = self.frames.shape[0]
        n_val = int(round(val_fraction * n_traj))
        if val_fraction > 0:
            n_val = max(1, n_val)
        if n_val >= n_traj and val_fraction > 0:
            raise ValueError(f"{path}: {n_traj} trajectories are too few for a validation split")
        perm = np.random.default_rng([seed, 12345]).permutation(n_traj)
        self.val_traj = np.sort(perm[:n_val])
        is_val = np.isin(win[:, 0], self.val_traj)
        self.train_win = win[~is_val]
        self.val_win = win[is_val]
        if limit_windows is not None:
            self.train_win = self.train_win[:limit_windows]
            self.val_win = self.val_win[:limit_windows]
        self._offs = np.arange(self.m + self.n_targets)

    def gather(self, win: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        f = self.frames[win[:, 0:1], win[:, 1:2] + self._offs[None, :]]
        return f[:, :self.m], f[:, self.m:]

    def describe(self) -> str:
        return (f"{self.path}: {self.frames.shape[0]} trajectories, {len(self.train_win)} train "
                f"windows, {len(self.val_win)} validation windows ({len(self.val_traj)} "
                f"trajectories), m={self.m}")


# ------------------------------------------------------------------------------------- torch
def _torch():
    import torch
    return torch


def resolve_device(device: str) -> str:
    torch = _torch()
    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device not in ("cpu", "cuda"):
        raise ValueError(f"device must be auto, cpu or cuda, got {device!r}")
    if device == "cuda" and not torch.cuda.is_available():
        raise ValueError("device cuda asked for but torch.cuda.is_available() is False")
    return device


def hardware(device: str) -> str:
    torch = _torch()
    if device == "cuda":
        return f"cuda:{torch.cuda.get_device_name(0)}"
    return (f"cpu:{platform.processor() or platform.machine()} "
            f"({os.cpu_count()} cores, {torch.get_num_threads()} torch threads)")


def make_optimizer(net: Any, r: Recipe) -> Any:
    torch = _torch()
    return torch.optim.Adam(net.parameters(), lr=r.lr, betas=(r.beta1, r.beta2), eps=r.eps)


def loss_fn(net: Any, x: Any, y: Any, steps: int, first_weight: float,
            shape_weight: float = 0.0, match_weight: float = 0.0) -> Any:
    """The recursive loss over the first ``steps`` targets (``steps=1``: 1-step teacher forced),
    plus ``shape_weight`` times the same sum of shape Chamfer distances (centred sets) and
    ``match_weight`` times the same sum of matched (earth mover's) distances."""
    return net.recursive_loss(x, y[:, :steps], first_weight=first_weight,
                              shape_weight=shape_weight, match_weight=match_weight)


def save_checkpoint(run_dir: str | os.PathLike, net: Any, opt: Any, state: dict) -> Path:
    """``checkpoint.pt`` (tensors and plain containers only: model and Adam state dicts,
    readable with ``torch.load(weights_only=True)``) and ``checkpoint.json`` (recipe, position,
    counters). Both written atomically; the JSON last, so it never points at a missing file."""
    torch = _torch()
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    tmp = run_dir / (CKPT_NAME + ".tmp")
    torch.save({"model": net.state_dict(), "optimizer": opt.state_dict()}, tmp)
    os.replace(tmp, run_dir / CKPT_NAME)
    tmpj = run_dir / (SIDECAR_NAME + ".tmp")
    tmpj.write_text(json.dumps(state, indent=1, sort_keys=True))
    os.replace(tmpj, run_dir / SIDECAR_NAME)
    return run_dir / CKPT_NAME


def load_checkpoint(path: str | os.PathLike) -> tuple[dict, dict]:
    """``(torch payload, sidecar state)`` from a run directory or a ``checkpoint.pt``."""
    torch = _torch()
    p = Path(path)
    ckpt = p / CKPT_NAME if p.is_dir() else p
    side = ckpt.with_name(SIDECAR_NAME)
    if not ckpt.is_file():
        raise FileNotFoundError(f"checkpoint not found: {ckpt}")
    payload = torch.load(ckpt, map_location="cpu", weights_only=True)
    state = json.loads(side.read_text()) if side.is_file() else {}
    return payload, state


# ------------------------------------------------------------------------------------- sizes
#: named network sizes: the released one and reduced widths for CPU experiments and tests
SIZES: dict[str, dict[str, Any]] = {
    "full": {},
    "small": dict(mlp1=(32, 32), mlp2=(64, 128, 256), global_features=64,
                  lstm_units=(64, 32, 32)),
    "tiny": dict(mlp1=(8, 8), mlp2=(8, 16, 16), global_features=8, lstm_units=(8, 8, 8)),
}


def size_config(size: str = "full", m: int = 4, **kw: Any) -> TPNetConfig:
    if size not in SIZES:
        raise ValueError(f"size must be one of {sorted(SIZES)}, got {size!r}")
    return TPNetConfig(m=m, **{**SIZES[size], **kw})


def init_head_template(net: Any, data: "WindowData", weight_scale: float = 0.1) -> None:
    """Data-dependent initialisation of the sigmoid head (``--head-init template``).

    The head's bias becomes the logit of a ring of the body's rest radius (measured on the
    first frame of the training trajectories) around the mean training position, and its
    weights are scaled by ``weight_scale``: the untrained network then outputs a ring of the
    right size near the middle of the data instead of 30 points scattered around 0.5, so the
    first steps learn motion instead of first collapsing the point cloud into a shape. Output
    order is free (the loss is a Chamfer distance), so ring index ``i`` is only a slot."""
    torch = _torch()
    train_traj = np.setdiff1d(np.arange(data.frames.shape[0]), data.val_traj)
    f0 = data.frames[train_traj, 0].astype(np.float64)                  # (T, N, 2)
    radius = float(np.linalg.norm(f0 - f0.mean(1, keepdims=True), axis=-1).mean())
    centre = data.frames[train_traj].astype(np.float64).reshape(-1, 2).mean(0)
    n_out, dim = net.config.n_out, net.config.dim
    if dim != 2:
        raise ValueError("template head initialisation is defined for 2-D points")
    a = 2 * np.pi * np.arange(n_out) / n_out
    ring = centre + radius * np.stack([np.sin(a), np.cos(a)], axis=1)
    ring = np.clip(ring, 1e-4, 1 - 1e-4)
    with torch.no_grad():
        net.head.bias.copy_(torch.from_numpy(np.log(ring / (1 - ring)).reshape(-1)))
        net.head.weight.mul_(weight_scale)


# ------------------------------------------------------------------------------------- eval
def evaluate(net: Any, data: WindowData, wins: np.ndarray, r: Recipe, device: str,
             batch: int = 256) -> dict[str, float]:
    """Validation: the recipe's ``r.rollout``-step loss (weights ``first_weight``, 1, ...; with
    its shape term when ``r.shape_weight`` > 0), the released Chamfer distance of the first and
    last predictions (``val_cd1``, ``val_cdK``) and their shape errors (``val_es1``,
    ``val_esK``), averaged over ``wins``."""
    torch = _torch()
    from .training.torch_model import chamfer_released, chamfer_shape

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


def baselines(data: WindowData, wins: np.ndarray | None = None, steps: int = N_STEPS_MAX,
              first_weight: float = 9.0) -> dict[str, dict[str, float]]:
    """Two model-free references on ``wins`` (default: the validation windows), scored like
    :func:`evaluate`: ``copy_last`` (the last input frame, repeated) and ``const_velocity``
    (points matched by index, the last two frames' displacement continued)."""
    from .protocol import constant_velocity, copy_last
    from .metrics import position_error

    wins = data.val_win if wins is None else wins
    x, y = data.gather(wins)
    y = y[:, :steps].astype(np.float64)
    x = x.astype(np.float64)
    preds = {"copy_last": copy_last(x, steps), "const_velocity": constant_velocity(x, steps)}
    w = np.ones(steps)
    w[0] = first_weight
    out = {}
    for name, p in preds.items():
        cd = np.asarray(position_error(y, p, variant="released")).mean(0)   # (S,) batch mean
        out[name] = {"val_loss": float((cd * w).sum()), "val_cd1": float(cd[0]),
                     f"val_cd{steps}": float(cd[-1])}
    return out


def score_rollouts(data: WindowData, weights: list[str | os.PathLike], horizon: int = 80,
                   at: tuple[int, ...] = (40, 80)) -> dict[str, dict[str, float]]:
    """Model selection without the test cases: the test protocol (frames 0..m-1 in, ``horizon``
    recursive predictions, released E_p / E_s averaged over trajectories) on the *validation*
    trajectories of the training grid, for each weights file and the two baselines.
    Returns ``{name: {"Ep@40": ..., "Es@40": ..., ...}}``."""
    from . import evaluation as E
    from . import load

    frames = data.frames[data.val_traj].astype(np.float64)
    windows, truth = E.split_protocol(frames, data.m, horizon)
    preds = {"copy last": E.copy_last(windows, horizon),
             "constant velocity": E.constant_velocity(windows, horizon)}
    for w in weights:
        model = load(w)
        if model.config.m != data.m:
            raise ValueError(f"{w}: m={model.config.m}, the dataset has m={data.m}")
        preds[str(w)] = E.batched_rollout(model, windows, horizon)
    out = {}
    for name, p in preds.items():
        err = E.errors(truth, p)
        out[name] = {f"{k}@{h}": float(err[f"{k}_released"][:, h - 1].mean())
                     for h in at for k in ("Ep", "Es")}
    return out


def spacing_report(data: WindowData, weights: list[str | os.PathLike],
                   every: int = 8) -> dict[str, dict[str, float]]:
    """:func:`~tpnet_ref.evaluation.spacing_stats` of the one-step predictions of each weights
    file on every ``every``-th validation window, and of the true next frames (``"truth"``)."""
    from . import load
    from .evaluation import spacing_stats

    x, y = data.gather(data.val_win[::every])
    out = {"truth": spacing_stats(y[:, 0])}
    for w in weights:
        out[str(w)] = spacing_stats(load(w).predict_batch(x.astype(np.float64), normalized=True))
    return out


# ------------------------------------------------------------------------------------- train
def _inherited(source: str | os.PathLike, pstate: dict) -> dict:
    """Provenance carried into a fine-tuning run: the training that made its starting weights
    (summed over the whole chain of runs, each listed)."""
    prev = pstate.get("inherited", {"runs": [], "windows_seen": 0, "wall_s": 0.0, "steps": 0,
                                    "epochs": 0.0})
    me = {"run": str(source), "data": pstate.get("data", ""), "steps": int(pstate.get("step", 0)),
          "epochs": float(pstate["epochs"]) if "epochs" in pstate else
          float(pstate.get("step", 0)) / (pstate.get("steps_per_epoch", 0) or 1),
          "windows_seen": int(pstate.get("windows_seen", 0)),
          "wall_s": float(pstate.get("wall_s", 0.0)), "recipe": pstate.get("recipe", {})}
    return {"runs": prev["runs"] + [me],
            "windows_seen": prev["windows_seen"] + me["windows_seen"],
            "wall_s": prev["wall_s"] + me["wall_s"], "steps": prev["steps"] + me["steps"],
            "epochs": prev["epochs"] + me["epochs"]}


def load_parent(source: str | os.PathLike) -> tuple[dict, dict, TPNetConfig]:
    """Starting weights of a fine-tuning run: ``(torch state dict, provenance state, config)``
    from a run directory / ``checkpoint.pt`` or from a native weights file (``.h5``, e.g. a
    shipped model; its stored provenance becomes the inherited chain)."""
    p = Path(source)
    if p.suffix in (".h5", ".hdf5") and p.is_file():
        from . import load
        from .training.torch_model import TorchTPNet
        model = load(p, dtype="float32")
        meta = model.meta
        cfg = model.config
        # the file's counters already total the chain that made it: one inherited entry
        state = {"data": str(meta.get("data", "")), "step": int(meta.get("training_steps", 0)),
                 "epochs": float(meta.get("epochs", 0.0)),
                 "windows_seen": int(meta.get("windows_seen", 0)),
                 "wall_s": float(meta.get("wall_time_s", 0.0)),
                 "recipe": {"weights_file": str(p), "source": str(meta.get("source", "")),
                            "recipe": json.loads(meta.get("recipe", "{}") or "{}"),
                            "parent_runs": json.loads(meta.get("parent_runs", "[]") or "[]")}}
        net = TorchTPNet.from_numpy(model)
        return net.state_dict(), state, cfg
    parent, pstate = load_checkpoint(source)
    if "recipe" not in pstate:
        raise ValueError(f"--init-from {source}: checkpoint has no checkpoint.json recipe")
    return parent["model"], pstate, Recipe.from_dict(pstate["recipe"]).tpnet_config


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


def train(data_path: str | os.PathLike, run_dir: str | os.PathLike, recipe: Recipe | None = None,
          *, resume: bool = False, epochs: int | None = None, device: str = "auto",
          threads: int | None = 2, max_steps: int | None = None,
          max_minutes: float | None = None, checkpoint_minutes: float = 5.0,
          log_every: int = 50, val_every: int | None = None, limit_windows: int | None = None, progress: bool = True,
          export_path: str | os.PathLike | None = None,
          budget_minutes: float | None = None) -> dict:
    """Train (or, with ``resume``, continue) the run in ``run_dir``; returns the final state.

    ``max_steps`` (a global step count), ``max_minutes`` and SIGINT/SIGTERM (after the current
    step) stop early with a checkpoint, so a
    long run can be done in pieces; ``epochs`` on resume extends or shortens the run (the cosine
    schedule follows the new length from there). A checkpoint is written every
    ``checkpoint_minutes``, at every epoch end and when stopping.

    ``budget_minutes`` (new runs only) fits the run to a wall-clock budget on this device: a
    few steps of the longest loss (``r.rollout`` predictions, batch ``r.batch``) are timed on
    random windows and the run's length (hence its learning-rate schedule) is set to 90 % of
    what that rate allows; ``max_minutes`` defaults to the budget as a hard stop."""
    torch = _torch()
    from .training.torch_model import TorchTPNet

    run_dir = Path(run_dir)
    t_start = time.perf_counter()
    if threads:
        torch.set_num_threads(int(threads))
    dev = resolve_device(device)
    payload: dict | None = None
    if resume:
        payload, state = load_checkpoint(run_dir)
        _trim_log(run_dir, int(state["step"]))
        r = Recipe.from_dict(state["recipe"])
        if epochs is not None:
            r.epochs = float(epochs)
        if val_every is None:                 # keep the run's validation cadence
            val_every = state.get("val_every")
    else:
        if (run_dir / SIDECAR_NAME).exists():
            raise ValueError(f"{run_dir} already holds a run; pass --resume or another directory")
        r = recipe or Recipe()
        if epochs is not None:
            r.epochs = float(epochs)
        state = {"step": 0, "windows_seen": 0, "wall_s": 0.0, "nonfinite_skipped": 0,
                 "epoch_loss_sum": 0.0, "epoch_loss_n": 0}
    cfg = r.tpnet_config
    data = WindowData(data_path, r.val_fraction, r.split_seed, limit_windows)
    if data.m != cfg.m:
        raise ValueError(f"dataset has m={data.m}, the recipe's network m={cfg.m}")
    if len(data.train_win) == 0:
        raise ValueError(f"{data_path}: no training windows")
    torch.manual_seed(r.seed)
    net = TorchTPNet(cfg).to(dev)
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
        state["inherited"] = _inherited(r.init_from, pstate)
    elif payload is None and r.head_init == "template":
        init_head_template(net, data)
    opt = make_optimizer(net, r)
    if payload is not None:
        net.load_state_dict(payload["model"])
        opt.load_state_dict(payload["optimizer"])
    run_dir.mkdir(parents=True, exist_ok=True)

    n_train = len(data.train_win)
    spe = max(1, n_train // r.batch)          # full batches only: every step has batch r.batch
    if budget_minutes is not None and not resume:
        if not budget_minutes > 0:
            raise ValueError(f"budget_minutes must be > 0, got {budget_minutes}")
        wps = bench(cfg, batch=r.batch, rollouts=(r.rollout,), iters=5, warmup=2, device=dev,
                    threads=threads, seed=r.seed, shape_weight=r.shape_weight,
                    match_weight=r.match_weight)[r.rollout]
        r.epochs = max(1.0 / spe, 0.9 * 60.0 * budget_minutes * wps / (spe * r.batch))
        state["budget"] = {"minutes": float(budget_minutes), "bench_windows_per_s": float(wps),
                           "epochs": r.epochs}
        if max_minutes is None:
            max_minutes = float(budget_minutes)
    total = max(1, int(round(r.epochs * spe)))
    state.update({"recipe": asdict(r), "data": str(data_path), "steps_per_epoch": spe,
                  "total_steps": total, "train_windows": n_train,
                  "val_windows": len(data.val_win), "device": dev, "hardware": hardware(dev),
                  "torch": torch.__version__, "val_every": val_every})
    val_win = data.val_win
    if r.val_windows and len(val_win) > r.val_windows:
        val_win = val_win[np.linspace(0, len(val_win) - 1, r.val_windows).round().astype(int)]
    state["val_windows_used"] = len(val_win)
    if state["step"] == 0 and not resume:
        ev = evaluate(net, data, val_win, r, dev)
        _log(run_dir, {"kind": "val", "step": 0, "epoch": 0.0, "windows_seen": 0, "wall_s": 0.0,
                       **ev})
        state["last_val"] = ev
    stop_step = total if max_steps is None else min(total, int(max_steps))
    deadline = None if max_minutes is None else t_start + 60.0 * max_minutes
    wall0 = state["wall_s"]
    last_ckpt = time.perf_counter()

    def checkpoint() -> None:
        nonlocal last_ckpt
        state["wall_s"] = wall0 + (time.perf_counter() - t_start)
        save_checkpoint(run_dir, net, opt, state)
        last_ckpt = time.perf_counter()

    bar = None
    if progress:
        try:
            from tqdm import tqdm
            bar = tqdm(total=stop_step, initial=min(state["step"], stop_step), unit="step",
                       desc=f"train {r.recipe}", dynamic_ncols=True)
        except ImportError:  # tqdm is optional
            bar = None
    if progress:
        print(data.describe(), file=sys.stderr)
    net.train()
    stop_signal: list[int] = []
    restore = _install_stop_handlers(stop_signal)
    perm_epoch, perm = -1, None
    consecutive_bad = 0
    reason = "done"
    try:
        while state["step"] < stop_step:
            step = state["step"]
            epoch, b = divmod(step, spe)
            if epoch != perm_epoch:
                perm = np.random.default_rng([r.seed, epoch]).permutation(n_train)
                perm_epoch = epoch
            idx = perm[b * r.batch:(b + 1) * r.batch]
            x, y = data.gather(data.train_win[np.sort(idx)])
            x = torch.from_numpy(x)
            if r.noise > 0:
                g = torch.Generator().manual_seed(r.seed * 1_000_003 + step)
                x = x + r.noise * torch.randn(x.shape, generator=g, dtype=x.dtype)
            x, y = x.to(dev), torch.from_numpy(y).to(dev)
            n_steps = r.steps_at(step / spe)
            lr = r.lr_at(step, total)
            for grp in opt.param_groups:
                grp["lr"] = lr
            opt.zero_grad(set_to_none=True)
            loss = loss_fn(net, x, y, n_steps, r.first_weight, r.shape_weight, r.match_weight)
            lv = float(loss.detach())
            if not math.isfinite(lv):
                state["nonfinite_skipped"] += 1
                consecutive_bad += 1
                if consecutive_bad >= 10:
                    checkpoint()
                    raise FloatingPointError(f"loss not finite for 10 steps in a row at step {step}")
            else:
                consecutive_bad = 0
                loss.backward()
                if r.clip > 0:
                    torch.nn.utils.clip_grad_norm_(net.parameters(), r.clip)
                opt.step()
                state["epoch_loss_sum"] += lv
                state["epoch_loss_n"] += 1
            state["step"] = step + 1
            state["windows_seen"] += len(idx)
            if bar is not None:
                bar.update(1)
                bar.set_postfix(loss=f"{lv:.4g}", k=n_steps, lr=f"{lr:.2g}")
            if log_every and state["step"] % log_every == 0:
                _log(run_dir, {"kind": "train", "step": state["step"], "epoch": state["step"] / spe,
                               "loss": lv, "rollout": n_steps, "lr": lr,
                               "windows_seen": state["windows_seen"],
                               "wall_s": wall0 + time.perf_counter() - t_start})
            epoch_end = state["step"] % spe == 0
            if epoch_end or (val_every and state["step"] % val_every == 0):
                # validate and log at every epoch end (and every val_every steps); checkpoint
                ev = evaluate(net, data, val_win, r, dev)
                n = max(1, state["epoch_loss_n"])
                rec = {"kind": "val", "step": state["step"], "epoch": state["step"] / spe,
                       "train_loss": state["epoch_loss_sum"] / n, "rollout": n_steps, "lr": lr,
                       "windows_seen": state["windows_seen"],
                       "wall_s": wall0 + time.perf_counter() - t_start, **ev}
                _log(run_dir, rec)
                state["last_val"] = ev
                if epoch_end:
                    state["epoch_loss_sum"], state["epoch_loss_n"] = 0.0, 0
                if bar is not None:
                    bar.write(f"epoch {rec['epoch']:.2f}: train {rec['train_loss']:.4g} "
                              + " ".join(f"{k} {v:.4g}" for k, v in ev.items()))
                checkpoint()
            elif time.perf_counter() - last_ckpt > 60.0 * checkpoint_minutes:
                checkpoint()
            if deadline is not None and time.perf_counter() > deadline:
                reason = "max_minutes"
                break
            if stop_signal:
                reason = "interrupted"
                break
        else:
            reason = "done" if state["step"] >= total else "max_steps"
    finally:
        restore()
    if bar is not None:
        bar.close()
    state["stopped"] = reason
    checkpoint()
    if export_path is not None and state["step"] >= total:
        export(run_dir, export_path)
    return state


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


# ------------------------------------------------------------------------------------- export
def export(source: str | os.PathLike, out: str | os.PathLike, dtype: str = "float32",
           check_bound: float = 1e-5) -> Any:
    """Native weights file from a training checkpoint (run directory or ``checkpoint.pt``),
    through :func:`tpnet_ref.weights.import_torch`, with provenance. Checks before writing that
    the NumPy model's forward pass equals the torch module's (max abs difference <= check_bound
    on random windows) and records the difference."""
    torch = _torch()
    from .training.torch_model import TorchTPNet
    from .weights.torch import import_torch

    payload, state = load_checkpoint(source)
    model = import_torch(payload["model"], dtype=dtype)
    net = TorchTPNet(model.config)
    net.load_state_dict(payload["model"])
    net.eval()
    cfg = model.config
    w = np.random.default_rng(0).uniform(0.1, 0.9, (8, cfg.m, cfg.n_out, cfg.dim)).astype(np.float32)
    with torch.no_grad():
        yt = net(torch.from_numpy(w)).numpy()
    diff = float(np.abs(model.predict_batch(w, normalized=True) - yt).max())
    if not diff <= check_bound:
        raise ValueError(f"export check failed: NumPy vs torch max abs diff {diff:.3g} > "
                         f"{check_bound:g}")
    spe = state.get("steps_per_epoch", 0) or 1
    inh = state.get("inherited", {"runs": [], "windows_seen": 0, "wall_s": 0.0, "steps": 0,
                                  "epochs": 0.0})
    prov = {"source": str(source), "producer": "tpnet_ref.train",
            "recipe": json.dumps(state.get("recipe", {}), sort_keys=True),
            "training_steps": int(state.get("step", 0)) + int(inh["steps"]),
            "epochs": float(state.get("step", 0)) / spe + float(inh["epochs"]),
            "windows_seen": int(state.get("windows_seen", 0)) + int(inh["windows_seen"]),
            "wall_time_s": float(state.get("wall_s", 0.0)) + float(inh["wall_s"]),
            "parent_runs": json.dumps(inh["runs"], sort_keys=True),
            "hardware": str(state.get("hardware", "unknown")),
            "torch": str(state.get("torch", torch.__version__)),
            "data": str(state.get("data", "")),
            "val": json.dumps(state.get("last_val", {}), sort_keys=True),
            "export_max_abs_diff": diff}
    model.save(str(out), **prov)
    return model


# ------------------------------------------------------------------------------------- bench
def bench(config: TPNetConfig | None = None, batch: int = 128, rollouts: tuple[int, ...] = (1, 8),
          iters: int = 5, warmup: int = 1, device: str = "auto", threads: int | None = 2,
          seed: int = 0, shape_weight: float = 0.0, match_weight: float = 0.0) -> dict[int, float]:
    """Training throughput, windows per second, of a full step (loss, backward, clip, Adam) for
    each rollout length, on random windows."""
    torch = _torch()
    from .training.torch_model import TorchTPNet

    if threads:
        torch.set_num_threads(int(threads))
    dev = resolve_device(device)
    cfg = config or TPNetConfig()
    torch.manual_seed(seed)
    net = TorchTPNet(cfg).to(dev)
    opt = make_optimizer(net, Recipe(config=cfg.to_dict()))
    rng = np.random.default_rng(seed)
    x = torch.from_numpy(rng.uniform(0.2, 0.8, (batch, cfg.m, cfg.n_out, cfg.dim))
                         .astype(np.float32)).to(dev)
    y = torch.from_numpy(rng.uniform(0.2, 0.8, (batch, N_STEPS_MAX, cfg.n_out, cfg.dim))
                         .astype(np.float32)).to(dev)
    out = {}
    for k in rollouts:
        for i in range(warmup + iters):
            if i == warmup:
                if dev == "cuda":
                    torch.cuda.synchronize()
                t0 = time.perf_counter()
            opt.zero_grad(set_to_none=True)
            loss = loss_fn(net, x, y, k, 9.0, shape_weight, match_weight)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), 10.0)
            opt.step()
        if dev == "cuda":
            torch.cuda.synchronize()
        out[k] = batch * iters / (time.perf_counter() - t0)
    return out


# ------------------------------------------------------------------------------------- CLI
def add_cli(sub: Any) -> None:
    p = sub.add_parser("train", help="train TP-Net in PyTorch (train extra) and export weights")
    tsub = p.add_subparsers(dest="train_command", metavar="TRAIN_COMMAND")
    tsub.required = True

    q = tsub.add_parser("run", help="train (or --resume) a run on a `tpnet data generate` file")
    q.add_argument("data", help="HDF5 dataset from `tpnet data generate`")
    q.add_argument("-o", "--run-dir", required=True,
                   help="run directory: checkpoint.pt, checkpoint.json, log.jsonl")
    q.add_argument("--resume", action="store_true",
                   help="continue the run in --run-dir (its stored recipe is used)")
    d = Recipe()
    q.add_argument("--recipe", choices=("paper", "curriculum"), default=d.recipe)
    q.add_argument("--size", choices=sorted(SIZES), default="full",
                   help="network widths: full (released), small, tiny")
    q.add_argument("--lstm-activation", choices=("relu", "tanh"), default="relu")
    q.add_argument("--epochs", type=float, default=None,
                   help=f"default {d.epochs}; may be fractional")
    q.add_argument("--batch", type=int, default=d.batch)
    q.add_argument("--lr", type=float, default=d.lr)
    q.add_argument("--beta1", type=float, default=d.beta1)
    q.add_argument("--beta2", type=float, default=d.beta2)
    q.add_argument("--adam-eps", type=float, default=d.eps)
    q.add_argument("--schedule", choices=("constant", "cosine"), default=d.schedule)
    q.add_argument("--lr-min", type=float, default=d.lr_min)
    q.add_argument("--warmup-steps", type=int, default=d.warmup_steps)
    q.add_argument("--clip", type=float, default=d.clip, help="max grad norm (0: off)")
    q.add_argument("--noise", type=float, default=d.noise,
                   help="std of Gaussian noise on input coordinates (normalised units)")
    q.add_argument("--shape-weight", type=float, default=d.shape_weight,
                   help="λ: add λ × the same weighted sum of shape Chamfer distances (sets centred "
                        "on their centroids; the released shape error E_s); 0 = published loss")
    q.add_argument("--match-weight", type=float, default=d.match_weight,
                   help="μ: add μ × the same weighted sum of matched (earth mover's) distances, "
                        "optimal one-to-one pairs (scipy); stops predicted points from "
                        "clumping on one target; 0 = published loss")
    q.add_argument("--pretrain-epochs", type=float, default=d.pretrain_epochs)
    q.add_argument("--ramp-epochs", type=float, default=d.ramp_epochs)
    q.add_argument("--rollout", type=int, default=d.rollout,
                   help=f"longest recursive loss (1..{N_STEPS_MAX}; published {N_STEPS_MAX})")
    q.add_argument("--head-init", choices=("default", "template"), default=d.head_init,
                   help="template: the untrained head outputs a ring of the body's size")
    q.add_argument("--init-from", default=d.init_from, metavar="RUN_DIR|WEIGHTS.h5",
                   help="fine-tune: start from this run's weights or a native weights file "
                        "(fresh optimizer and schedule; its network is used, --size is ignored)")
    q.add_argument("--val-windows", type=int, default=d.val_windows,
                   help="validate on this many evenly spaced validation windows (0: all)")
    q.add_argument("--val-fraction", type=float, default=d.val_fraction,
                   help="fraction of training-grid trajectories held out for validation")
    q.add_argument("--split-seed", type=int, default=d.split_seed,
                   help="seed of the validation split (kept apart from --seed)")
    q.add_argument("--seed", type=int, default=d.seed, help="initialisation, order and noise")
    q.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    q.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    q.add_argument("--max-steps", type=int, default=None, help="stop (with a checkpoint) at this step")
    q.add_argument("--max-minutes", type=float, default=None,
                   help="stop (with a checkpoint) after this many minutes")
    q.add_argument("--budget-minutes", type=float, default=None,
                   help="new runs: time a few steps here, then set --epochs so the run (and its "
                        "cosine schedule) fits 90%% of this many minutes; also the hard stop")
    q.add_argument("--checkpoint-minutes", type=float, default=5.0)
    q.add_argument("--log-every", type=int, default=50, help="steps between train-loss log lines")
    q.add_argument("--val-every", type=int, default=None,
                   help="also validate every N steps (default: at epoch ends only)")
    q.add_argument("--export", default=None, metavar="OUT.h5",
                   help="when the run completes, write the native weights file")
    q.add_argument("--quiet", action="store_true", help="no progress bar")
    q.set_defaults(func=_cli_run)

    e = tsub.add_parser("export", help="native weights file from a checkpoint (with provenance)")
    e.add_argument("checkpoint", help="run directory or checkpoint.pt")
    e.add_argument("output", help="native HDF5 weights file to write")
    e.add_argument("--dtype", choices=("float32", "float64"), default="float32")
    e.set_defaults(func=_cli_export)

    b = tsub.add_parser("bench", help="training throughput (windows/s) at a batch size")
    b.add_argument("--size", choices=sorted(SIZES), default="full")
    b.add_argument("--batch", type=int, default=128)
    b.add_argument("--rollouts", type=int, nargs="+", default=[1, 8])
    b.add_argument("--iters", type=int, default=5)
    b.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    b.add_argument("--threads", type=int, default=2)
    b.set_defaults(func=_cli_bench)

    s = tsub.add_parser("score", help="model selection on validation trajectories (the test "
                                      "protocol, never the test cases): E_p/E_s at 40/80")
    s.add_argument("data")
    s.add_argument("weights", nargs="+", help="native weights files to compare")
    s.add_argument("--horizon", type=int, default=80)
    s.add_argument("--spacing", action="store_true",
                   help="also how evenly the one-step predictions cover the ring (world units: "
                        "nearest-neighbour distance, smallest one per set, radius spread)")
    s.add_argument("--val-fraction", type=float, default=d.val_fraction)
    s.add_argument("--split-seed", type=int, default=d.split_seed)
    s.set_defaults(func=_cli_score)

    c = tsub.add_parser("baselines", help="copy-last-frame and constant-velocity scores on the "
                                          "validation windows")
    c.add_argument("data")
    c.add_argument("--val-fraction", type=float, default=d.val_fraction)
    c.add_argument("--split-seed", type=int, default=d.split_seed)
    c.set_defaults(func=_cli_baselines)


def _cli_run(args: Any) -> int:
    recipe = None
    if not args.resume:
        import h5py
        with h5py.File(args.data, "r") as h:
            m = int(h.attrs["m"])
        cfg = size_config(args.size, m=m, lstm_activation=args.lstm_activation)
        if args.init_from:   # the parent's network, for this dataset's window length m
            cfg = dataclasses.replace(load_parent(args.init_from)[2], m=m)
        recipe = Recipe(recipe=args.recipe, epochs=args.epochs or Recipe.epochs,
                        batch=args.batch, lr=args.lr, beta1=args.beta1, beta2=args.beta2,
                        eps=args.adam_eps, schedule=args.schedule, lr_min=args.lr_min,
                        warmup_steps=args.warmup_steps, clip=args.clip, noise=args.noise,
                        shape_weight=args.shape_weight, match_weight=args.match_weight,
                        pretrain_epochs=args.pretrain_epochs, ramp_epochs=args.ramp_epochs,
                        rollout=args.rollout, head_init=args.head_init, init_from=args.init_from,
                        val_windows=args.val_windows, val_fraction=args.val_fraction, split_seed=args.split_seed,
                        seed=args.seed, config=cfg.to_dict())
    st = train(args.data, args.run_dir, recipe, resume=args.resume, epochs=args.epochs,
               device=args.device, threads=args.threads, max_steps=args.max_steps,
               max_minutes=args.max_minutes, checkpoint_minutes=args.checkpoint_minutes,
               log_every=args.log_every, val_every=args.val_every, progress=not args.quiet,
               export_path=args.export, budget_minutes=args.budget_minutes)
    print(f"{args.run_dir}: step {st['step']}/{st['total_steps']} ({st['stopped']}), "
          f"{st['windows_seen']} windows seen, {st['wall_s']:.0f} s, last validation "
          + json.dumps(st.get("last_val", {})))
    return 0


def _cli_export(args: Any) -> int:
    model = export(args.checkpoint, args.output, dtype=args.dtype)
    print(f"wrote {args.output}: {model!r}")
    return 0


def _cli_bench(args: Any) -> int:
    cfg = size_config(args.size)
    res = bench(cfg, batch=args.batch, rollouts=tuple(args.rollouts), iters=args.iters,
                device=args.device, threads=args.threads)
    dev = resolve_device(args.device)
    print(f"train step throughput, size {args.size}, batch {args.batch}, {hardware(dev)}:")
    for k, v in res.items():
        print(f"  {k}-step loss: {v:8.1f} windows/s")
    return 0


def _cli_score(args: Any) -> int:
    data = WindowData(args.data, args.val_fraction, args.split_seed)
    print(f"{data.describe()}\nvalidation trajectories from frame 0, {args.horizon} recursive "
          f"predictions, released metric, mean over {len(data.val_traj)} trajectories:")
    at = tuple(h for h in (1, 10, 40, 80) if h <= args.horizon)
    res = score_rollouts(data, args.weights, args.horizon, at)
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


def _cli_baselines(args: Any) -> int:
    data = WindowData(args.data, args.val_fraction, args.split_seed)
    print(data.describe())
    for name, ev in baselines(data).items():
        print(f"  {name:15s} " + " ".join(f"{k} {v:.4f}" for k, v in ev.items()))
    return 0


__all__ = ["Recipe", "WindowData", "train", "export", "bench", "baselines", "evaluate",
           "score_rollouts", "spacing_report", "load_parent",
           "save_checkpoint", "load_checkpoint", "size_config", "SIZES"]

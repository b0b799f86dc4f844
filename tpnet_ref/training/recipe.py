"""What a training run computes: the :class:`Recipe`, the network sizes, the training windows.

Recipes (``Recipe.recipe``):

* ``paper``: every step is the published loss, ``9·CD(P_{t+1}) + Σ_{i=2..8} CD(P_{t+i})`` over 8
  recursive predictions (released-code Chamfer: Euclidean, not squared, both directions summed);
  ``rollout = K`` shortens it to K predictions, or lengthens it up to :data:`N_ROLLOUT_MAX`
  (same weights, 1 for every step after the first; the windows are then those with K frames
  after their inputs, gathered from the whole trajectories).
* ``curriculum`` (default): ``pretrain_epochs`` of the 1-step loss (teacher forced, the first
  term alone), then the recursive loss with the rollout length growing linearly from 1 to 8 over
  ``ramp_epochs``, then the ``rollout``-step loss (8, the published one, by default). Same
  weights 9, 1, 1, ...

Both: Adam with the released code's constants (lr 1e-3, beta_1 0.99, beta_2 0.999, eps 1e-7),
optional linear warm-up and cosine decay, gradient-norm clipping, optional Gaussian noise on the
input coordinates (never on the targets; i.i.d. or a random walk over the input frames,
``noise_kind``), optionally the pushforward trick (``grad_steps = G``: of a K-step loss, the
first K − G predictions without gradient, the loss over the last G alone). Validation is a
held-out set of whole training-grid *trajectories* (``val_fraction``), always scored over all
``rollout`` predictions; the 60 test cases are never read. Everything here is NumPy and h5py:
torch is needed by the loop and its step only (:mod:`~tpnet_ref.training.loop`).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from ..config import TPNetConfig
from ..sim.dataset import N_TARGETS, check_scene, file_dim
from ..sim.protocol import FRAME_EVERY
from ..weights.quantize import SCHEMES

#: the published recursive loss: 8 predictions (the dataset's targets per window)
N_STEPS_MAX = N_TARGETS
#: the longest recursive loss a recipe may ask for (the long-horizon experiments)
N_ROLLOUT_MAX = 32
#: how much of Adam's state a checkpoint keeps (:mod:`~tpnet_ref.training.checkpoint`)
OPTIMIZER_MODES = ("full", "bf16", "none")
#: input noise: independent per frame, or a random walk over the input frames
NOISE_KINDS = ("iid", "walk")


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
    noise_kind: str = "iid"             # "iid" or "walk" (the last input frame's std is noise)
    first_weight: float = 9.0
    shape_weight: float = 0.0           # λ of the added shape term λ·Σ w_i·CD(centred sets)
    match_weight: float = 0.0           # μ of the added term μ·Σ w_i·EMD (optimal bijection)
    rollout: int = N_STEPS_MAX          # length of the recursive loss (8 published; up to 32)
    grad_steps: int = 0                 # pushforward: loss and gradient on the last G steps; 0: all
    pretrain_epochs: float = 2.0        # curriculum: 1-step epochs
    ramp_epochs: float = 4.0            # curriculum: epochs to grow the rollout 1 -> rollout
    head_init: str = "default"          # "default" or "template" (output bias = a ring, see below)
    init: str = "torch"                 # "torch" (nn.Linear defaults) or "keras" (released)
    windows: str = "model"              # "model" or "released" (tpnet_ref.sim.dataset.released_windows)
    init_from: str = ""                 # fine-tune: start from this run's (or .h5 file's) weights
    init_optimizer: bool = False        # ... and from its Adam state (a branch, not a fresh Adam)
    quantize_aware: str = ""            # "", "int8" or "bf16": BiLSTM matrices on that grid
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
        if self.init not in ("torch", "keras"):
            raise ValueError(f"init must be 'torch' or 'keras', got {self.init!r}")
        if self.windows not in ("model", "released"):
            raise ValueError(f"windows must be 'model' or 'released', got {self.windows!r}")
        if self.val_windows < 0:
            raise ValueError("val_windows must be >= 0")
        if not 1 <= self.rollout <= N_ROLLOUT_MAX:
            raise ValueError(f"rollout must be in 1..{N_ROLLOUT_MAX}, got {self.rollout}")
        if not 0 <= self.grad_steps <= self.rollout:
            raise ValueError(f"grad_steps must be in 0..rollout ({self.rollout}), "
                             f"got {self.grad_steps}")
        if self.noise_kind not in NOISE_KINDS:
            raise ValueError(f"noise_kind must be 'iid' or 'walk', got {self.noise_kind!r}")
        if self.quantize_aware not in ("",) + SCHEMES:
            raise ValueError(f"quantize_aware must be '' or one of {', '.join(SCHEMES)}, "
                             f"got {self.quantize_aware!r}")
        if self.init_optimizer and not self.init_from:
            raise ValueError("init_optimizer needs init_from (the run whose Adam state to take)")
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



#: named network sizes: the released one and reduced widths for CPU experiments and tests
SIZES: dict[str, dict[str, Any]] = {
    "full": {},
    # the same architecture at half and a quarter of every width (the error-against-run-time sizes)
    "half": dict(mlp1=(32, 32), mlp2=(64, 128, 256), global_features=64,
                 lstm_units=(256, 128, 128)),
    "quarter": dict(mlp1=(16, 16), mlp2=(32, 64, 128), global_features=32,
                    lstm_units=(128, 64, 64)),
    "small": dict(mlp1=(32, 32), mlp2=(64, 128, 256), global_features=64,
                  lstm_units=(64, 32, 32)),
    "tiny": dict(mlp1=(8, 8), mlp2=(8, 16, 16), global_features=8, lstm_units=(8, 8, 8)),
}


def size_config(size: str = "full", m: int = 4, **kw: Any) -> TPNetConfig:
    """The :class:`TPNetConfig` of a named size (``full``: the released widths) for ``m`` frames;
    ``kw`` overrides fields (e.g. ``lstm_activation``)."""
    if size not in SIZES:
        raise ValueError(f"size must be one of {sorted(SIZES)}, got {size!r}")
    return TPNetConfig(m=m, **{**SIZES[size], **kw})


# ------------------------------------------------------------------------------------- data
class WindowData:
    """The windows of a ``tpnet data generate`` file, gathered on demand from the trajectories
    (no copy of each window is held): :meth:`gather` -> inputs ``(B, m, N, 2)`` and targets
    ``(B, H, N, 2)``, float32, normalised, ``H = max(8, horizon)``. With ``horizon`` > 8 (a
    longer recursive loss) only the windows with ``horizon`` frames after their inputs are kept
    (the file's windows stop 8 frames before a trajectory's end). Train/validation split by
    trajectory, the same for every ``horizon``. A file made with another scene convention than
    the simulator's default is refused unless ``allow_other_scene``
    (:func:`tpnet_ref.sim.dataset.check_scene`), and a file of another dimension than ``dim`` (2, or 3
    for the 3-D scene's; None: the file's own) always.

    ``windows="released"`` trains on the released preprocessing's windows
    (``/train/windows_released``: starts at any simulator row, frames ``FRAME_EVERY`` rows
    apart) of a file made with ``tpnet data generate --windows released``; the validation
    windows stay the model-frame windows of the validation trajectories, so runs of both modes
    are scored on the same windows. Internally every window is then ``(trajectory, first
    row, kind)``."""

    def __init__(self, path: str | os.PathLike, val_fraction: float, seed: int,
                 limit_windows: int | None = None, allow_other_scene: bool = False,
                 horizon: int = N_STEPS_MAX, windows: str = "model", dim: int | None = 2) -> None:
        import h5py

        if not Path(path).is_file():
            raise FileNotFoundError(f"dataset not found: {path}")
        with h5py.File(path, "r") as h:
            # a file made with another scene convention trains another physics
            dim = file_dim(h) if dim is None else dim
            check_scene(h, str(path), allow_other_scene=allow_other_scene, dim=dim)
            self.dim = int(dim)
            self.m = int(h.attrs["m"])
            self.n_targets = int(h.attrs["n_targets"])
            g = h["train"]
            if "windows" not in g:
                raise KeyError(f"{path}: /train has no windows")
            if not g["done"][...].all():
                raise ValueError(f"{path}: /train is incomplete; run generate again to finish it")
            self.frames = g["normalized"][...]
            win = g["windows"][...]
            self.rows = None
            if windows == "released":
                if "windows_released" not in g or "rows" not in g:
                    raise ValueError(f"{path}: has no released windows; make it with "
                                     "`tpnet data generate --windows released`")
                self.rows = g["rows"][...]
                released = g["windows_released"][...]
            elif windows != "model":
                raise ValueError(f"windows must be 'model' or 'released', got {windows!r}")
        self.path = str(path)
        n_traj = self.frames.shape[0]
        n_val = int(round(val_fraction * n_traj))
        if val_fraction > 0:
            n_val = max(1, n_val)
        if n_val >= n_traj and val_fraction > 0:
            raise ValueError(f"{path}: {n_traj} trajectories are too few for a validation split")
        perm = np.random.default_rng([seed, 12345]).permutation(n_traj)
        self.val_traj = np.sort(perm[:n_val])
        if not 1 <= horizon <= N_ROLLOUT_MAX:
            raise ValueError(f"horizon must be in 1..{N_ROLLOUT_MAX}, got {horizon}")
        if horizon > self.n_targets:
            win = win[win[:, 1] + self.m + horizon <= self.frames.shape[1]]
            if self.rows is not None:
                span = (self.m + horizon - 1) * FRAME_EVERY
                released = released[released[:, 1] + span < self.rows.shape[1]]
            self.n_targets = int(horizon)
        is_val = np.isin(win[:, 0], self.val_traj)
        self.train_win = win[~is_val]
        self.val_win = win[is_val]
        if self.rows is not None:       # every window as (trajectory, first row, kind)
            self.train_win = released[~np.isin(released[:, 0], self.val_traj)]
            self.val_win = self.val_win * np.array([1, FRAME_EVERY, 1])
        if limit_windows is not None:
            self.train_win = self.train_win[:limit_windows]
            self.val_win = self.val_win[:limit_windows]
        # a window's frames: rows FRAME_EVERY apart, or consecutive model frames
        self._src = self.frames if self.rows is None else self.rows
        self._offs = np.arange(self.m + self.n_targets) * (1 if self.rows is None else FRAME_EVERY)

    def gather(self, win: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        f = self._src[win[:, 0:1], win[:, 1:2] + self._offs[None, :]]
        return f[:, :self.m], f[:, self.m:]

    def describe(self) -> str:
        return (f"{self.path}: {self.frames.shape[0]} trajectories, {len(self.train_win)} "
                f"{'released ' if self.rows is not None else ''}train "
                f"windows, {len(self.val_win)} validation windows ({len(self.val_traj)} "
                f"trajectories), m={self.m}")


__all__ = ["Recipe", "WindowData", "SIZES", "size_config", "N_STEPS_MAX", "N_ROLLOUT_MAX",
           "OPTIMIZER_MODES", "NOISE_KINDS"]

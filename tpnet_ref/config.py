"""What fixes TP-Net's shapes and coordinates: the config, the parameter list, the normalisation.

:class:`TPNetConfig` holds every width and switch of the network (defaults: the authors' released
model, docs/spec.md §2); :func:`param_shapes` is the one list of parameter names and shapes, in
forward order, from which the model, the native weights file, the importers and the PyTorch
training model all derive theirs; :func:`normalize` / :func:`denormalize` are the one mapping
between world units and model coordinates (docs/spec.md §5).
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

#: world-unit range of the particle centres used for normalisation (docs/spec.md §5)
NORM_LO = 1.1438
NORM_HI = 43.8562


def normalize(x: Any, lo: float = NORM_LO, hi: float = NORM_HI) -> np.ndarray:
    """World units -> model coordinates, ``(x - lo) / (hi - lo)``; keeps a float32/float64 dtype
    (anything else becomes float64)."""
    x = np.asarray(x)
    dt = x.dtype if x.dtype in (np.float32, np.float64) else np.dtype(np.float64)
    x = x.astype(dt, copy=False)
    return (x - dt.type(lo)) / dt.type(hi - lo)


def denormalize(x: Any, lo: float = NORM_LO, hi: float = NORM_HI) -> np.ndarray:
    """Model coordinates -> world units, ``x * (hi - lo) + lo`` (dtype as :func:`normalize`)."""
    x = np.asarray(x)
    dt = x.dtype if x.dtype in (np.float32, np.float64) else np.dtype(np.float64)
    x = x.astype(dt, copy=False)
    return x * dt.type(hi - lo) + dt.type(lo)


@dataclass(frozen=True)
class TPNetConfig:
    """Everything that fixes the network's shapes and semantics (defaults: the released model)."""

    m: int = 4                                    # input frames per window
    n_out: int = 30                               # points in the predicted set
    dim: int = 2                                  # coordinates per point
    input_tnet_mlp: tuple[int, ...] = (64, 128, 512)
    input_tnet_fc: tuple[int, ...] = (256, 128)
    mlp1: tuple[int, ...] = (64, 64)
    feature_tnet_mlp: tuple[int, ...] = (64, 128, 512)
    feature_tnet_fc: tuple[int, ...] = (256, 128)
    mlp2: tuple[int, ...] = (128, 256, 512)
    global_features: int = 128                    # k, the size of G_t
    lstm_units: tuple[int, ...] = (512, 256, 256)
    lstm_activation: str = "relu"                 # "relu" (released code) or "tanh"
    layer_norm_eps: float = 1e-3                  # Keras default; PyTorch's is 1e-5
    input_transform_trained: bool = False         # False: the 2x2 transform is the identity
    feature_transform_trained: bool = False       # False: the 64x64 transform is the identity
    norm_lo: float = NORM_LO                      # world units -> (x - lo) / (hi - lo)
    norm_hi: float = NORM_HI

    def __post_init__(self) -> None:
        def integral(x: Any, what: str) -> int:
            if isinstance(x, (bool, np.bool_)) or not isinstance(x, (int, np.integer)):
                raise TypeError(f"TPNetConfig.{what} must be an integer, got {x!r}")
            return int(x)

        for name in ("m", "n_out", "dim", "global_features"):
            if integral(getattr(self, name), name) < 1:
                raise ValueError(f"TPNetConfig.{name} must be >= 1, got {getattr(self, name)}")
            object.__setattr__(self, name, int(getattr(self, name)))
        for name in ("input_tnet_mlp", "input_tnet_fc", "mlp1", "feature_tnet_mlp",
                     "feature_tnet_fc", "mlp2", "lstm_units"):
            raw = getattr(self, name)
            if isinstance(raw, (str, bytes)) or not hasattr(raw, "__iter__"):
                raise TypeError(f"TPNetConfig.{name} must be a sequence of widths, got {raw!r}")
            v = tuple(integral(x, name) for x in raw)
            if not v or min(v) < 1:
                raise ValueError(f"TPNetConfig.{name} must be non-empty positive widths, got {v}")
            object.__setattr__(self, name, v)
        if self.lstm_activation not in ("relu", "tanh"):
            raise ValueError(f"TPNetConfig.lstm_activation must be 'relu' or 'tanh', "
                             f"got {self.lstm_activation!r}")
        if not (self.layer_norm_eps > 0 and math.isfinite(self.layer_norm_eps)):
            raise ValueError(f"TPNetConfig.layer_norm_eps must be > 0, got {self.layer_norm_eps}")
        if not (math.isfinite(self.norm_lo) and math.isfinite(self.norm_hi)
                and self.norm_hi > self.norm_lo):
            raise ValueError(f"TPNetConfig: need norm_lo < norm_hi, got {self.norm_lo}, {self.norm_hi}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "TPNetConfig":
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown TPNetConfig field(s): {sorted(unknown)}")
        return cls(**d)


def param_shapes(cfg: TPNetConfig) -> dict[str, tuple[int, ...]]:
    """The name and shape of every parameter the config needs, in forward order.

    Names: ``<block>.<layer>.w|b`` for dense/point-wise layers, ``lstmI.fwd|bwd.kernel|recurrent|bias``
    (Keras layout and gate order i, f, c, o), ``lnI.gamma|beta``. Identity transform nets have no
    parameters at all.
    """
    shapes: dict[str, tuple[int, ...]] = {}

    def stack(prefix: str, cin: int, widths: Sequence[int]) -> int:
        for i, cout in enumerate(widths):
            shapes[f"{prefix}.{i}.w"] = (cin, cout)
            shapes[f"{prefix}.{i}.b"] = (cout,)
            cin = cout
        return cin

    def tnet(prefix: str, k: int, mlp: Sequence[int], fc: Sequence[int]) -> None:
        stack(f"{prefix}.fc", stack(f"{prefix}.mlp", k, mlp), fc)
        shapes[f"{prefix}.out.w"] = (fc[-1], k * k)
        shapes[f"{prefix}.out.b"] = (k * k,)

    if cfg.input_transform_trained:
        tnet("input_tnet", cfg.dim, cfg.input_tnet_mlp, cfg.input_tnet_fc)
    c = stack("mlp1", cfg.dim, cfg.mlp1)
    if cfg.feature_transform_trained:
        tnet("feature_tnet", c, cfg.feature_tnet_mlp, cfg.feature_tnet_fc)
    c = stack("mlp2", c, cfg.mlp2)
    shapes["global.w"] = (c, cfg.global_features)
    shapes["global.b"] = (cfg.global_features,)
    c = cfg.global_features
    for i, u in enumerate(cfg.lstm_units, start=1):
        for d in ("fwd", "bwd"):
            shapes[f"lstm{i}.{d}.kernel"] = (c, 4 * u)
            shapes[f"lstm{i}.{d}.recurrent"] = (u, 4 * u)
            shapes[f"lstm{i}.{d}.bias"] = (4 * u,)
        c = 2 * u
        shapes[f"ln{i}.gamma"] = (c,)
        shapes[f"ln{i}.beta"] = (c,)
    shapes["head.w"] = (c, cfg.n_out * cfg.dim)
    shapes["head.b"] = (cfg.n_out * cfg.dim,)
    return shapes


def random_params(config: TPNetConfig, seed: int = 0,
                  transform_scale: float = 0.1) -> dict[str, np.ndarray]:
    """Random float64 parameters of ``config`` (Glorot-uniform kernels, small random biases, LSTM
    forget bias 1, non-trivial transform nets when the config asks for trained ones), for tests
    and benchmarks. Deterministic in ``seed``."""
    cfg = config
    rng = np.random.default_rng(seed)
    params: dict[str, np.ndarray] = {}
    for name, shape in param_shapes(cfg).items():
        if len(shape) == 2:
            limit = math.sqrt(6.0 / (shape[0] + shape[1]))
            if name.endswith(".out.w"):
                limit = transform_scale / math.sqrt(shape[0])
            params[name] = rng.uniform(-limit, limit, size=shape)
        elif name.endswith(".out.b"):
            k = int(round(math.sqrt(shape[0])))
            params[name] = np.eye(k).ravel() + rng.uniform(-transform_scale, transform_scale, shape)
        elif name.endswith("gamma"):
            params[name] = 1.0 + rng.uniform(-0.2, 0.2, size=shape)
        elif name.endswith(".bias") and name.startswith("lstm"):
            u = shape[0] // 4
            b = rng.uniform(-0.1, 0.1, size=shape)
            b[u:2 * u] += 1.0  # Keras unit_forget_bias
            params[name] = b
        else:
            params[name] = rng.uniform(-0.1, 0.1, size=shape)
    return params


__all__ = ["TPNetConfig", "param_shapes", "random_params", "normalize", "denormalize", "NORM_LO",
           "NORM_HI"]

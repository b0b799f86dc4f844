"""TP-Net in PyTorch, with the Keras semantics of the released code (optional ``train`` extra).

Exactly the network of docs/spec.md §2 and :mod:`tpnet_ref.model`: per-point MLPs as
``nn.Linear``, identity or trained transform nets per :class:`~tpnet_ref.config.TPNetConfig`,
bidirectional LSTMs with a hand-written cell (``relu`` or ``tanh``; ``nn.LSTM`` is tanh-only),
LayerNorm with the config's eps (Keras: 1e-3), a sigmoid head. No canonical point sort
(max-pooling is permutation invariant up to rounding). Every layer's size is read from
:func:`~tpnet_ref.config.param_shapes`, the one list of the network's parameters.

Parameter names follow PyTorch conventions (:func:`tpnet_ref.weights.torch.torch_name` maps
them to the native ones), so a state dict reads like a PyTorch model's; the bidirectional LSTM's
parameters have exactly ``nn.LSTM(bidirectional=True)``'s names and layout. ``state_dict()``
carries the config (hence the LayerNorm eps) as ``_extra_state``, so
``torch.save(net.state_dict(), path)`` is a checkpoint that
:func:`tpnet_ref.weights.torch.import_torch` reads without further arguments.

This module is never imported by ``predict``.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..config import TPNetConfig, param_shapes
from ..extras import require
from ..model import TPNet
from ..weights.torch import TORCH_FORMAT, native_to_torch_state, torch_state_to_native
from .fake_quant import straight_through

torch = require("torch", "train")
nn = torch.nn
F = torch.nn.functional


def _act(name: str):
    return torch.relu if name == "relu" else torch.tanh


class BiLSTM(nn.Module):
    """Keras ``Bidirectional(LSTM(units, activation=act))``, merge ``concat``.

    Parameters are named and laid out like ``nn.LSTM(cin, units, bidirectional=True)``:
    ``weight_ih_l0 (4u, cin)``, ``weight_hh_l0 (4u, u)``, ``bias_ih_l0``, ``bias_hh_l0 (4u,)``,
    the same with ``_reverse`` for the backward direction; gate order i, f, g, o.
    """

    def __init__(self, cin: int, units: int, activation: str = "relu",
                 return_sequences: bool = True) -> None:
        super().__init__()
        self.units = units
        self.activation = activation
        self.return_sequences = return_sequences
        #: "" or a scheme whose grid the matrices are rounded to in the forward pass
        #: (:mod:`~tpnet_ref.training.fake_quant`: quantization-aware fine-tuning)
        self.fake_quant = ""
        for sfx in ("_l0", "_l0_reverse"):
            self.register_parameter("weight_ih" + sfx, nn.Parameter(torch.empty(4 * units, cin)))
            self.register_parameter("weight_hh" + sfx, nn.Parameter(torch.empty(4 * units, units)))
            self.register_parameter("bias_ih" + sfx, nn.Parameter(torch.zeros(4 * units)))
            self.register_parameter("bias_hh" + sfx, nn.Parameter(torch.zeros(4 * units)))
        self.reset_parameters()

    def reset_parameters(self) -> None:
        u = self.units
        for sfx in ("_l0", "_l0_reverse"):
            nn.init.xavier_uniform_(getattr(self, "weight_ih" + sfx))
            for k in range(4):  # Keras: orthogonal recurrent kernel per gate
                nn.init.orthogonal_(getattr(self, "weight_hh" + sfx).data[k * u:(k + 1) * u])
            b = getattr(self, "bias_ih" + sfx)
            nn.init.zeros_(b)
            b.data[u:2 * u] = 1.0  # unit_forget_bias
            nn.init.zeros_(getattr(self, "bias_hh" + sfx))

    def _direction(self, x: torch.Tensor, sfx: str, reverse: bool) -> torch.Tensor:
        """``x (B, T, C)`` -> ``(B, T, u)`` (row t: state after consuming step t)."""
        u = self.units
        act = _act(self.activation)
        bsz, steps, _ = x.shape
        # input projection of every step in one matmul, both biases folded in
        fq = self.fake_quant
        xp = F.linear(x, straight_through(getattr(self, "weight_ih" + sfx), fq),
                      getattr(self, "bias_ih" + sfx) + getattr(self, "bias_hh" + sfx))
        w_hh_t = straight_through(getattr(self, "weight_hh" + sfx), fq).t()
        h = x.new_zeros(bsz, u)
        c = x.new_zeros(bsz, u)
        outs: list[torch.Tensor] = [h] * steps
        order = range(steps - 1, -1, -1) if reverse else range(steps)
        for t in order:
            z = xp[:, t] + h @ w_hh_t
            i, f, g, o = z.split(u, dim=1)
            c = torch.sigmoid(f) * c + torch.sigmoid(i) * act(g)
            h = torch.sigmoid(o) * act(c)
            outs[t] = h
        return torch.stack(outs, dim=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``(B, T, C)`` -> ``(B, T, 2u)`` or, without sequences, ``(B, 2u)``."""
        hf = self._direction(x, "_l0", reverse=False)
        hb = self._direction(x, "_l0_reverse", reverse=True)
        if self.return_sequences:
            return torch.cat([hf, hb], dim=-1)
        return torch.cat([hf[:, -1], hb[:, 0]], dim=-1)


def full_precision(lin: nn.Module, x: torch.Tensor) -> torch.Tensor:
    """``lin(x)`` in float32 even inside a bfloat16 autocast region (mixed-precision training):
    the layers that read or write coordinates (the first per-point layer, the head) keep
    float32, so a predicted point is not rounded to bfloat16's 8 significant bits (≈ 0.1 world
    units near the box's far side) before the loss or the next frame's features see it."""
    dev = x.device.type
    if torch.is_autocast_enabled(dev):
        with torch.autocast(dev, enabled=False):
            return lin(x.float())
    return lin(x)


def _linear_stack(shapes: dict[str, tuple[int, ...]], prefix: str) -> nn.ModuleList:
    """``nn.Linear`` layers for the native stack ``prefix.0``, ``prefix.1``, ... of ``shapes``."""
    layers = nn.ModuleList()
    while f"{prefix}.{len(layers)}.w" in shapes:
        cin, cout = shapes[f"{prefix}.{len(layers)}.w"]
        layers.append(nn.Linear(cin, cout))
    return layers


class TNet(nn.Module):
    """PointNet transform net: per-point MLP, max over points, FC stack, linear FC to K*K.
    Initialised as the released code does: output weights zero, bias the flattened identity."""

    def __init__(self, shapes: dict[str, tuple[int, ...]], prefix: str) -> None:
        super().__init__()
        self.mlp = _linear_stack(shapes, f"{prefix}.mlp")
        self.fc = _linear_stack(shapes, f"{prefix}.fc")
        cin, kk = shapes[f"{prefix}.out.w"]
        self.k = self.mlp[0].in_features
        self.out = nn.Linear(cin, kk)
        nn.init.zeros_(self.out.weight)
        with torch.no_grad():
            self.out.bias.copy_(torch.eye(self.k).flatten())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``(F, N, K)`` -> ``(F, K, K)``."""
        for lin in self.mlp:
            x = torch.relu(lin(x))
        g = x.amax(dim=1)
        for lin in self.fc:
            g = torch.relu(lin(g))
        return self.out(g).view(-1, self.k, self.k)


def _glorot_(weight: torch.Tensor, fan_in: int, fan_out: int) -> None:
    """Keras' glorot-uniform: U(-a, a), a = sqrt(6 / (fan_in + fan_out))."""
    a = math.sqrt(6.0 / (fan_in + fan_out))
    with torch.no_grad():
        weight.uniform_(-a, a)


def init_keras(net: "TorchTPNet") -> None:
    """Re-initialise ``net`` as the released Keras code does (docs/spec.md §2): every per-point
    (Conv2D), global and head (Dense) kernel glorot-uniform with a zero bias; each LSTM's
    kernel glorot-uniform over its fused ``(in, 4u)`` shape, its recurrent kernel orthogonal
    over the whole ``(u, 4u)`` matrix (rows orthonormal: ``weight_hh`` ``(4u, u)`` has
    orthonormal columns), its bias zero but the forget gate's 1 (``unit_forget_bias``);
    LayerNorm gamma 1, beta 0. Keras computes a Conv2D kernel ``(kh, kw, in, out)``'s fans with
    its receptive field ``kh * kw``: the first per-point layer is a ``(1, dim)`` convolution
    over a ``(N, dim, 1)`` image, so its fans are ``dim`` and ``out * dim``. The transform
    nets' last layers stay as built (zero weights, identity bias: the released code's
    untracked variables). Draws from torch's global generator (seed it first)."""
    dim = net.config.dim
    firsts = {id(net.mlp1[0])}
    if net.input_tnet is not None:
        firsts.add(id(net.input_tnet.mlp[0]))
    keep = {id(t.out) for t in net.modules() if isinstance(t, TNet)}
    for mod in net.modules():
        if isinstance(mod, nn.Linear) and id(mod) not in keep:
            fan_in, fan_out = mod.in_features, mod.out_features
            if id(mod) in firsts:
                fan_out *= dim
            _glorot_(mod.weight, fan_in, fan_out)
            nn.init.zeros_(mod.bias)
        elif isinstance(mod, BiLSTM):
            u = mod.units
            for sfx in ("_l0", "_l0_reverse"):
                w_ih = getattr(mod, "weight_ih" + sfx)
                _glorot_(w_ih, w_ih.shape[1], 4 * u)
                nn.init.orthogonal_(getattr(mod, "weight_hh" + sfx))
                with torch.no_grad():
                    getattr(mod, "bias_ih" + sfx).zero_()
                    getattr(mod, "bias_ih" + sfx)[u:2 * u] = 1.0
                    getattr(mod, "bias_hh" + sfx).zero_()
        elif isinstance(mod, nn.LayerNorm):
            nn.init.ones_(mod.weight)
            nn.init.zeros_(mod.bias)


class TorchTPNet(nn.Module):
    """TP-Net (docs/spec.md §2) built from a :class:`TPNetConfig`; forward ``(B, m, N, dim)`` normalised
    windows -> ``(B, n_out, dim)``.

    It takes **normalised** coordinates (model coordinates) and returns them, unlike
    :func:`tpnet_ref.predict`, which takes world units: normalise a world-unit window first,
    ``(x - norm_lo) / (norm_hi - norm_lo)`` with the config's bounds (``(x - 1.1438) / 42.7124``
    for the shipped models; ``model.normalize(x)`` of the :class:`~tpnet_ref.model.TPNet`, or
    :func:`tpnet_ref.config.normalize`), and map the output back with
    ``y * (norm_hi - norm_lo) + norm_lo`` (``model.denormalize(y)``). It has no canonical sort of
    its own: its output is permutation invariant up to rounding."""

    def __init__(self, config: TPNetConfig | None = None) -> None:
        super().__init__()
        cfg = config or TPNetConfig()
        self.config = cfg
        shapes = param_shapes(cfg)
        self.input_tnet = TNet(shapes, "input_tnet") if cfg.input_transform_trained else None
        self.mlp1 = _linear_stack(shapes, "mlp1")
        self.feature_tnet = (TNet(shapes, "feature_tnet") if cfg.feature_transform_trained
                             else None)
        self.mlp2 = _linear_stack(shapes, "mlp2")
        self.global_fc = nn.Linear(*shapes["global.w"])
        n = len(cfg.lstm_units)
        for i in range(1, n + 1):
            cin, u4 = shapes[f"lstm{i}.fwd.kernel"]
            self.add_module(f"lstm{i}", BiLSTM(cin, u4 // 4, cfg.lstm_activation,
                                               return_sequences=i < n))
            self.add_module(f"ln{i}", nn.LayerNorm(shapes[f"ln{i}.gamma"][0],
                                                   eps=cfg.layer_norm_eps))
        self.head = nn.Linear(*shapes["head.w"])

    def set_fake_quant(self, scheme: str) -> None:
        """Round every BiLSTM matrix to ``scheme``'s grid in the forward pass ("" for none;
        :mod:`~tpnet_ref.training.fake_quant`)."""
        for i in range(1, len(self.config.lstm_units) + 1):
            getattr(self, f"lstm{i}").fake_quant = scheme

    # ---------------------------------------------------------------- config in the state dict
    def get_extra_state(self) -> dict[str, Any]:
        return {"format": TORCH_FORMAT, "config": self.config.to_dict()}

    def set_extra_state(self, state: Any) -> None:
        if not isinstance(state, dict) or state.get("format") != TORCH_FORMAT:
            raise ValueError("state dict's _extra_state is not a tpnet_ref-torch config")
        cfg = TPNetConfig.from_dict(state["config"])
        if cfg != self.config:
            raise ValueError(f"state dict was saved for {cfg}, this module has {self.config}")

    # ---------------------------------------------------------------- forward
    def frame_features(self, points: torch.Tensor) -> torch.Tensor:
        """Global feature of each frame: ``(F, N, dim)`` -> ``(F, global_features)``."""
        x = points
        if self.input_tnet is not None:
            x = torch.bmm(x, self.input_tnet(x))
        for i, lin in enumerate(self.mlp1):
            x = torch.relu(full_precision(lin, x) if i == 0 else lin(x))
        if self.feature_tnet is not None:
            x = torch.bmm(x, self.feature_tnet(x))
        for lin in self.mlp2:
            x = torch.relu(lin(x))
        return torch.relu(self.global_fc(x.amax(dim=1)))

    def sequence_head(self, feats: torch.Tensor) -> torch.Tensor:
        """``(B, m, global_features)`` -> ``(B, n_out, dim)`` in [0, 1]."""
        h = feats
        for i in range(1, len(self.config.lstm_units) + 1):
            h = getattr(self, f"ln{i}")(getattr(self, f"lstm{i}")(h))
        return torch.sigmoid(full_precision(self.head, h)).view(-1, self.config.n_out,
                                                                self.config.dim)

    def forward(self, windows: torch.Tensor) -> torch.Tensor:
        """``(B, m, N, dim)`` normalised windows -> next point sets ``(B, n_out, dim)``."""
        b, m, n, d = windows.shape
        g = self.frame_features(windows.reshape(b * m, n, d))
        return self.sequence_head(g.view(b, m, -1))

    def rollout(self, windows: torch.Tensor, steps: int, grad_from: int = 0) -> torch.Tensor:
        """Recursive prediction (window slides by one, prediction appended), each frame's
        features computed once: ``(B, m, N, dim)`` -> ``(B, steps, n_out, dim)``.
        Differentiable, for the 8-step training loss.

        ``grad_from`` j in 1..steps-1 (the pushforward trick): the first j predictions are made
        under ``torch.no_grad()``; the window they end in is then taken as data (its frames'
        features computed again, with gradient, as an input window's) and the last
        ``steps - j`` predictions are made from it with gradient, so none flows through the
        first j."""
        if grad_from:
            if not 0 < grad_from < steps:
                raise ValueError(f"grad_from must be in 0..{steps - 1}, got {grad_from}")
            with torch.no_grad():
                early = self.rollout(windows, grad_from)
            window = torch.cat([windows, early], dim=1)[:, -windows.shape[1]:]
            return torch.cat([early, self.rollout(window, steps - grad_from)], dim=1)
        b, m, n, d = windows.shape
        feats = list(self.frame_features(windows.reshape(b * m, n, d)).view(b, m, -1).unbind(1))
        outs = []
        for s in range(int(steps)):
            y = self.sequence_head(torch.stack(feats[-m:], dim=1))
            outs.append(y)
            if s + 1 < steps:  # the last prediction's features would never be used
                feats.append(self.frame_features(y))
        return torch.stack(outs, dim=1)

    def recursive_loss(self, windows: torch.Tensor, targets: torch.Tensor,
                       first_weight: float = 9.0, shape_weight: float = 0.0,
                       match_weight: float = 0.0, grad_steps: int = 0) -> torch.Tensor:
        """The published loss ``9·CD(P_{t+1}) + Σ_{i=2..S} CD(P_{t+i})`` (released-code Chamfer:
        Euclidean, both directions summed, batch mean). ``targets (B, S, N, dim)``, S = 8.

        ``shape_weight`` λ > 0 adds ``λ·Σ_i w_i·CD(P_i − c_P, Q_i − c_Q)``: the same Chamfer on
        the sets centred on their own centroids, i.e. the released-code shape error E_s.
        ``match_weight`` μ > 0 adds ``μ·Σ_i w_i·EMD(P_i, Q_i)`` (:func:`matched_distance`).

        ``grad_steps`` G in 1..S-1 (the pushforward trick): the first S − G predictions are
        made without gradient (:meth:`rollout`'s ``grad_from``) and every term is summed over
        the last G alone, each with weight 1. G = 0 or G >= S: all S, the loss above."""
        steps = targets.shape[1]
        skip = steps - grad_steps if 0 < grad_steps < steps else 0
        pred = self.rollout(windows, steps, grad_from=skip)[:, skip:]
        targets = targets[:, skip:]
        if skip:
            first_weight = 1.0
        dev = pred.device.type
        if torch.is_autocast_enabled(dev):     # the loss in float32 (mixed-precision training)
            with torch.autocast(dev, enabled=False):
                return self._loss(pred.float(), targets.float(), first_weight, shape_weight,
                                  match_weight)
        return self._loss(pred, targets, first_weight, shape_weight, match_weight)

    @staticmethod
    def _loss(pred: torch.Tensor, targets: torch.Tensor, first_weight: float,
              shape_weight: float, match_weight: float) -> torch.Tensor:
        w = torch.ones(targets.shape[1], dtype=pred.dtype, device=pred.device)
        w[0] = first_weight
        loss = (chamfer_released(pred, targets) * w).sum()
        if shape_weight:
            loss = loss + shape_weight * (chamfer_shape(pred, targets) * w).sum()
        if match_weight:
            loss = loss + match_weight * (matched_distance(pred, targets) * w).sum()
        return loss

    # ---------------------------------------------------------------- conversion
    def native_state(self) -> dict[str, np.ndarray]:
        """Parameters under their native names and Keras layout (float64 NumPy arrays)."""
        sd = {k: v.detach().cpu().double().numpy() for k, v in self.state_dict().items()
              if k != "_extra_state"}
        return torch_state_to_native(sd, self.config)

    def to_numpy(self, dtype: Any = "float32") -> TPNet:
        """The same network as a NumPy :class:`TPNet`."""
        return TPNet(self.config, self.native_state(), dtype, {"producer": "tpnet_ref.torch_model"})

    @classmethod
    def from_numpy(cls, model: TPNet) -> "TorchTPNet":
        """A module with ``model``'s config and parameters (in ``model``'s dtype)."""
        dt = torch.float64 if model.dtype == np.float64 else torch.float32
        net = cls(model.config).to(dt)     # before loading: float32 parameters would round
        sd = {k: torch.from_numpy(np.ascontiguousarray(v))
              for k, v in native_to_torch_state(model.params, model.config).items()}
        sd["_extra_state"] = net.get_extra_state()
        net.load_state_dict(sd)
        return net


def chamfer_released(p: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
    """Released-code Chamfer distance, not squared, both directions summed, no 1/|P|:
    ``p (B, ..., N, d)``, ``q (B, ..., M, d)`` -> ``(...)`` averaged over the batch axis 0."""
    dist = torch.cdist(p, q)
    per = dist.amin(dim=-1).sum(dim=-1) + dist.amin(dim=-2).sum(dim=-1)
    return per.mean(dim=0)


def chamfer_shape(p: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
    """:func:`chamfer_released` of the two sets each centred on its own centroid (the released
    shape error E_s): ``p (B, ..., N, d)``, ``q (B, ..., M, d)`` -> ``(...)``."""
    return chamfer_released(p - p.mean(dim=-2, keepdim=True), q - q.mean(dim=-2, keepdim=True))


@torch.compiler.disable
def _optimal_pairing(pf: torch.Tensor, qf: torch.Tensor) -> torch.Tensor:
    """``(S, N)`` indices σ that pair ``pf[s, i]`` with ``qf[s, σ_s(i)]`` at least total distance
    (scipy on the CPU; outside any ``torch.compile`` graph: a graph break, not a trace)."""
    linear_sum_assignment = require("scipy.optimize", "train").linear_sum_assignment
    cost = torch.cdist(pf, qf).double().cpu().numpy()
    sigma = np.stack([linear_sum_assignment(c)[1] for c in cost])
    return torch.from_numpy(sigma).to(qf.device)


def matched_distance(p: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
    """Earth mover's distance of two equal-size sets on the released scale: ``2·Σ_i ||p_i −
    q_σ(i)||`` under the bijection σ that minimises it (the Chamfer sum if every nearest
    neighbour were mutual), ``p, q (B, ..., N, d)`` -> ``(...)`` averaged over the batch axis 0.

    Unlike the Chamfer distance it is large when several predicted points share one target
    and leave another uncovered, the local minimum a Chamfer-trained head falls into. σ comes
    from ``scipy.optimize.linear_sum_assignment`` on the CPU (no gradient through it); the
    gradient is that of the distances of the matched pairs."""
    if p.shape != q.shape:
        raise ValueError(f"matched_distance needs sets of equal shape, got {tuple(p.shape)} "
                         f"and {tuple(q.shape)}")
    n, d = p.shape[-2:]
    pf, qf = p.reshape(-1, n, d), q.reshape(-1, n, d)
    idx = _optimal_pairing(pf.detach(), qf.detach()).unsqueeze(-1).expand(-1, -1, d)
    diff = pf - torch.gather(qf, 1, idx)
    per = 2.0 * torch.sqrt((diff * diff).sum(-1) + 1e-20).sum(-1)
    return per.view(p.shape[:-2]).mean(dim=0)


__all__ = ["TorchTPNet", "BiLSTM", "TNet", "init_keras", "chamfer_released", "chamfer_shape",
           "matched_distance", "TORCH_FORMAT"]

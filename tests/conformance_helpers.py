"""The seeded port bugs of docs/crosscheck.md ("Seeded bugs"): broken PyTorch ports of a model,
each with one bug, and the layer ``tpnet crosscheck`` must name each at -- shared by
tests/test_conformance.py (2-D) and tests/test_conformance3d.py (3-D)."""
from __future__ import annotations

import dataclasses
import io
import json
from contextlib import redirect_stderr, redirect_stdout

import pytest

from tpnet_ref.cli import main
from tpnet_ref.model import TPNet


def seeded_port(model: TPNet, bug: str):
    """A PyTorch port of ``model`` with one bug (docs/crosscheck.md, "Seeded bugs")."""
    torch = pytest.importorskip("torch")
    from tpnet_ref.training.torch_model import BiLSTM, TorchTPNet

    cfg = model.config
    if bug == "layer_norm_eps":
        cfg = dataclasses.replace(cfg, layer_norm_eps=1e-5)
    if bug == "norm_bounds":
        cfg = dataclasses.replace(cfg, norm_lo=cfg.norm_lo * 1.01, norm_hi=cfg.norm_hi * 1.01)
    net = TorchTPNet.from_numpy(TPNet(cfg, model.params, "float32")).eval()

    class Cell(BiLSTM):
        swap = forget_twice = False

        def _direction(self, x, sfx, reverse):
            u = self.units
            b = getattr(self, "bias_ih" + sfx) + getattr(self, "bias_hh" + sfx)
            if self.forget_twice:
                b = b + torch.cat([torch.zeros(u), b[u:2 * u], torch.zeros(2 * u)]).to(b.dtype)
            xp = torch.nn.functional.linear(x, getattr(self, "weight_ih" + sfx), b)
            w_hh_t = getattr(self, "weight_hh" + sfx).t()
            h = x.new_zeros(x.shape[0], u)
            c = x.new_zeros(x.shape[0], u)
            outs = [h] * x.shape[1]
            for t in (range(x.shape[1] - 1, -1, -1) if reverse else range(x.shape[1])):
                i, f, g, o = (xp[:, t] + h @ w_hh_t).split(u, dim=1)
                if self.swap:
                    i, f = f, i
                c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.relu(g)
                h = torch.sigmoid(o) * torch.relu(c)
                outs[t] = h
            return torch.stack(outs, dim=1)

    class Swapped(Cell):
        swap = True

    class ForgetTwice(Cell):
        forget_twice = True

    class BackwardFirst(BiLSTM):
        def forward(self, x):
            hf = self._direction(x, "_l0", reverse=False)
            hb = self._direction(x, "_l0_reverse", reverse=True)
            return torch.cat([hb[:, 0], hf[:, -1]], dim=-1)

    class MeanPool(TorchTPNet):
        def frame_features(self, points):
            x = points
            for lin in self.mlp1:
                x = torch.relu(lin(x))
            for lin in self.mlp2:
                x = torch.relu(lin(x))
            return torch.relu(self.global_fc(x.mean(dim=1)))

    class NoSigmoid(TorchTPNet):
        def sequence_head(self, feats):
            h = feats
            for i in range(1, 4):
                h = getattr(self, f"ln{i}")(getattr(self, f"lstm{i}")(h))
            return self.head(h).view(-1, self.config.n_out, self.config.dim)

    if bug == "swapped_gates":
        net.lstm2.__class__ = Swapped
    elif bug == "forget_bias_twice":
        for i in (1, 2, 3):
            getattr(net, f"lstm{i}").__class__ = ForgetTwice
    elif bug == "backward_first":
        net.lstm3.__class__ = BackwardFirst
    elif bug == "mean_pool":
        net.__class__ = MeanPool
    elif bug == "no_sigmoid":
        net.__class__ = NoSigmoid
    return net


SEEDED = {  # bug -> (the layer it must be named at, where it must start)
    "swapped_gates": ("lstm2.fwd", {"time_step": 0, "direction": "forward"}),
    "layer_norm_eps": ("ln1", {}),
    "backward_first": ("lstm3.concat", {}),
    "mean_pool": ("pooled", {"frame": 0}),
    "norm_bounds": ("input.normalized", {"frame": 0}),
    "no_sigmoid": ("head.sigmoid", {}),
    # c_{-1} = 0: the doubled forget bias first matters at the second step of the forward pass
    "forget_bias_twice": ("lstm1.fwd", {"time_step": 1, "direction": "forward"}),
}


def run_cli(*argv) -> tuple[int, str, str]:
    """``tpnet ARGV...`` in this process: ``(exit code, stdout, stderr)``."""
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        rc = main([str(a) for a in argv])
    return rc, out.getvalue(), err.getvalue()


def crosscheck_seeded_bug(model: TPNet, bug: str, vectors_dir, tmp_path) -> dict:
    """The seeded port ``bug`` of ``model`` traced on every case of ``vectors_dir`` and checked by
    ``tpnet crosscheck --json``: it must fail, name :data:`SEEDED`'s layer and place as the first
    divergence, and the same first layer in every case. Returns the JSON report (the port's
    trace is ``tmp_path / "port.npz"``)."""
    from tpnet_ref.conformance.traces import torch_trace
    from tpnet_ref.conformance.vectors import read_conformance_vectors, save_trace

    net = seeded_port(model, bug)
    v = read_conformance_vectors(vectors_dir)
    save_trace(tmp_path / "port.npz", {c: torch_trace(net, v.window(c)) for c in v.cases})
    rc, out, err = run_cli("crosscheck", "--vectors", vectors_dir, "--trace",
                           tmp_path / "port.npz", "--json")
    assert rc == 1, out + err
    rep = json.loads(out)
    layer, where = SEEDED[bug]
    fd = rep["first_divergence"]
    assert fd["layer"] == layer, fd
    assert where.items() <= fd["where"].items(), fd
    for case, c in rep["cases"].items():          # every case names the same first layer
        assert c["first_divergence"]["layer"] == layer, (case, c)
    return rep

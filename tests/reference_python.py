"""TP-Net written out with Python floats and explicit loops, one scalar at a time.

An implementation independent of ``tpnet_ref.engines.layers``: no NumPy matrix algebra, every gate
sliced out by hand in Keras order (input, forget, cell, output), the backward LSTM run over the
reversed sequence and re-aligned by hand, LayerNorm with the biased variance and eps inside the
square root. Only meant for tiny networks (widths 1-3) in the tests.
"""
from __future__ import annotations

import math


def _sig(x: float) -> float:
    return 1.0 / (1.0 + math.exp(-x))


def _act(name: str, x: float) -> float:
    return max(x, 0.0) if name == "relu" else math.tanh(x)


def _dense(vec, w, b, relu=False):
    out = []
    for j in range(len(b)):
        s = b[j]
        for i in range(len(vec)):
            s += vec[i] * w[i][j]
        out.append(max(s, 0.0) if relu else s)
    return out


def _matvec_right(vec, mat):
    """Row vector times matrix: (K,) @ (K, K)."""
    return [sum(vec[i] * mat[i][j] for i in range(len(vec))) for j in range(len(mat[0]))]


def _tnet(points, p, prefix, k, n_mlp, n_fc):
    feats = []
    for x in points:
        h = list(x)
        for i in range(n_mlp):
            h = _dense(h, p[f"{prefix}.mlp.{i}.w"], p[f"{prefix}.mlp.{i}.b"], relu=True)
        feats.append(h)
    g = [max(f[c] for f in feats) for c in range(len(feats[0]))]
    for i in range(n_fc):
        g = _dense(g, p[f"{prefix}.fc.{i}.w"], p[f"{prefix}.fc.{i}.b"], relu=True)
    t = _dense(g, p[f"{prefix}.out.w"], p[f"{prefix}.out.b"])
    return [[t[r * k + c] for c in range(k)] for r in range(k)]


def frame_feature(points, p, cfg):
    """One frame (list of (x, y)) -> its global feature G (list of floats)."""
    pts = [list(q) for q in points]
    if cfg.input_transform_trained:
        t = _tnet(pts, p, "input_tnet", cfg.dim, len(cfg.input_tnet_mlp), len(cfg.input_tnet_fc))
        pts = [_matvec_right(q, t) for q in pts]
    feats = []
    for q in pts:
        h = q
        for i in range(len(cfg.mlp1)):
            h = _dense(h, p[f"mlp1.{i}.w"], p[f"mlp1.{i}.b"], relu=True)
        feats.append(h)
    if cfg.feature_transform_trained:
        t = _tnet(feats, p, "feature_tnet", len(feats[0]), len(cfg.feature_tnet_mlp),
                  len(cfg.feature_tnet_fc))
        feats = [_matvec_right(h, t) for h in feats]
    out = []
    for h in feats:
        for i in range(len(cfg.mlp2)):
            h = _dense(h, p[f"mlp2.{i}.w"], p[f"mlp2.{i}.b"], relu=True)
        out.append(h)
    pooled = [max(f[c] for f in out) for c in range(len(out[0]))]
    return _dense(pooled, p["global.w"], p["global.b"], relu=True)


def lstm_direction(seq, kernel, recurrent, bias, act, reverse):
    """Keras LSTM over ``seq`` (list of vectors); returns h after each step, aligned to input time."""
    u = len(recurrent)
    h = [0.0] * u
    c = [0.0] * u
    hs = [None] * len(seq)
    order = range(len(seq) - 1, -1, -1) if reverse else range(len(seq))
    for t in order:
        x = seq[t]
        z = [bias[j] + sum(x[i] * kernel[i][j] for i in range(len(x)))
             + sum(h[i] * recurrent[i][j] for i in range(u)) for j in range(4 * u)]
        gi = [_sig(z[j]) for j in range(0, u)]            # input gate
        gf = [_sig(z[j]) for j in range(u, 2 * u)]        # forget gate
        gc = [_act(act, z[j]) for j in range(2 * u, 3 * u)]  # cell candidate
        go = [_sig(z[j]) for j in range(3 * u, 4 * u)]    # output gate
        c = [gf[j] * c[j] + gi[j] * gc[j] for j in range(u)]
        h = [go[j] * _act(act, c[j]) for j in range(u)]
        hs[t] = h
    return hs


def layer_norm(v, gamma, beta, eps):
    mean = sum(v) / len(v)
    var = sum((x - mean) ** 2 for x in v) / len(v)
    return [(x - mean) / math.sqrt(var + eps) * g + b for x, g, b in zip(v, gamma, beta)]


def predict_normalized(window, p, cfg):
    """A window (list of frames, each a list of (x, y)) in model coordinates -> list of (x, y)."""
    seq = [frame_feature(f, p, cfg) for f in window]
    n_layers = len(cfg.lstm_units)
    for li in range(1, n_layers + 1):
        args = [(p[f"lstm{li}.{d}.kernel"], p[f"lstm{li}.{d}.recurrent"], p[f"lstm{li}.{d}.bias"])
                for d in ("fwd", "bwd")]
        hf = lstm_direction(seq, *args[0], cfg.lstm_activation, reverse=False)
        hb = lstm_direction(seq, *args[1], cfg.lstm_activation, reverse=True)
        g, b = p[f"ln{li}.gamma"], p[f"ln{li}.beta"]
        if li < n_layers:
            seq = [layer_norm(hf[t] + hb[t], g, b, cfg.layer_norm_eps) for t in range(len(seq))]
        else:  # return_sequences=False: forward's last state, backward's state after all steps
            last = layer_norm(hf[-1] + hb[0], g, b, cfg.layer_norm_eps)
    y = [_sig(v) for v in _dense(last, p["head.w"], p["head.b"])]
    return [(y[2 * i], y[2 * i + 1]) for i in range(cfg.n_out)]

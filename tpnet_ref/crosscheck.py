"""Where does a port diverge? Conformance vectors and the layer-by-layer comparison.

:func:`tpnet_ref.engines.reference.forward` records every named intermediate of the forward pass
(``trace=``); this module turns those traces into files another implementation can test
against and compares a port's own trace with them, naming the first layer that disagrees:

- :func:`make_cases` -- the conformance cases (scene windows, shuffled points, ragged N, the
  edges of the trained range, a short rollout), :func:`layer_names` -- the layers in forward
  order, :func:`trace` -- the reference's trace of one window;
- :func:`measure_tolerances` -- each layer's float32 tolerance, measured from rounding
  (docs/crosscheck.md, "Tolerances"); :func:`write_vectors` / :func:`read_vectors` --
  ``DIR/manifest.json`` + ``DIR/vectors.npz`` (``tpnet vectors``);
- :func:`load_trace` -- a port's trace file, checked against the vectors;
  :func:`compare` -- per case, the first layer beyond its tolerance with its largest error and
  where it starts (frame, point, channel; time step, direction, unit; point, coordinate);
  :func:`report_text` / :func:`report_json` -- ``tpnet crosscheck``'s output.

NumPy only; the framework traces (PyTorch hooks, ONNX outputs, Keras) are in
:mod:`tpnet_ref.traces`. Untrusted files: ``.npz`` are read with ``allow_pickle=False``.
"""
from __future__ import annotations

import json
import math
import os
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .engines import reference
from .config import TPNetConfig

FORMAT = "tpnet-conformance-vectors"
VERSION = 1
#: a layer's float32 tolerance: SAFETY x the largest float32 rounding gap measured on the cases
#: + FLOOR x max(1, the layer's largest magnitude) (docs/crosscheck.md, "Tolerances")
SAFETY = 8.0
FLOOR = 2.0 ** -20
#: the float32 runs whose gap to float64 is measured (docs/crosscheck.md)
RUNS = ("float32", "float32, input moved by one ulp", "float32, points reversed")
#: case names: no dots (a key is ``<case>.<layer>``)
MAX_TRACE_KEYS = 100_000


# --------------------------------------------------------------------------- the layers
def layer_names(config: TPNetConfig) -> list[str]:
    """The names :func:`tpnet_ref.engines.reference.forward` records, in forward order."""
    names = ["input", "input.normalized"]
    if config.input_transform_trained:
        names += ["input_tnet.transform", "input.transformed"]
    names += [f"mlp1.{i}" for i in range(len(config.mlp1))]
    if config.feature_transform_trained:
        names += ["feature_tnet.transform", "mlp1.transformed"]
    names += [f"mlp2.{i}" for i in range(len(config.mlp2))] + ["pooled", "global"]
    for i in range(1, len(config.lstm_units) + 1):
        names += [f"lstm{i}.fwd", f"lstm{i}.bwd", f"lstm{i}.concat", f"ln{i}"]
    return names + ["head.logits", "head.sigmoid", "output"]


def layer_shapes(config: TPNetConfig) -> dict[str, list[Any]]:
    """Each layer's shape with ``P`` (the window's points, frame after frame) and ``m``."""
    c = config
    out: dict[str, list[Any]] = {"input": ["P", c.dim], "input.normalized": ["P", c.dim],
                                 "input_tnet.transform": ["m", c.dim, c.dim],
                                 "input.transformed": ["P", c.dim],
                                 "feature_tnet.transform": ["m", c.mlp1[-1], c.mlp1[-1]],
                                 "mlp1.transformed": ["P", c.mlp1[-1]],
                                 "pooled": ["m", c.mlp2[-1]], "global": ["m", c.global_features],
                                 "head.logits": [c.n_out * c.dim],
                                 "head.sigmoid": [c.n_out, c.dim], "output": [c.n_out, c.dim]}
    for stack in ("mlp1", "mlp2"):
        for i, w in enumerate(getattr(c, stack)):
            out[f"{stack}.{i}"] = ["P", w]
    last = len(c.lstm_units)
    for i, u in enumerate(c.lstm_units, start=1):
        out[f"lstm{i}.fwd"] = out[f"lstm{i}.bwd"] = ["m", u]
        out[f"lstm{i}.concat"] = out[f"ln{i}"] = ["m", 2 * u] if i < last else [2 * u]
    return {k: out[k] for k in layer_names(c)}


#: what each layer is, for the manifest and docs/crosscheck.md
MEANINGS = {
    "input": "the window as given, world units",
    "input.normalized": "(x - norm_lo) / (norm_hi - norm_lo), model coordinates",
    "input_tnet.transform": "the input transform net's K x K matrix per frame",
    "input.transformed": "the points times their frame's input transform",
    "feature_tnet.transform": "the feature transform net's 64 x 64 matrix per frame",
    "mlp1.transformed": "MLP 1's output times its frame's feature transform",
    "mlp1": "per-point MLP 1, layer i, after its ReLU",
    "mlp2": "per-point MLP 2, layer i, after its ReLU",
    "pooled": "max over each frame's points of the last MLP 2 layer",
    "global": "FC + ReLU: each frame's global feature G_t",
    "fwd": "BiLSTM i, forward direction: row t its output after consuming steps 0..t",
    "bwd": "BiLSTM i, backward direction: row t its output after consuming steps m-1..t",
    "concat": "BiLSTM i's output: [forward, backward] per step (the last BiLSTM: forward after "
              "step m-1, backward after step 0)",
    "ln": "LayerNorm after BiLSTM i",
    "head.logits": "the head's FC output before its sigmoid",
    "head.sigmoid": "after the sigmoid, reshaped (n_out, dim): model coordinates",
    "output": "the prediction in world units",
}


def meaning(name: str) -> str:
    if name in MEANINGS:
        return MEANINGS[name]
    stem, _, last = name.rpartition(".")
    if stem in ("mlp1", "mlp2"):
        return MEANINGS[stem].replace("layer i", f"layer {last}")
    if name.startswith("ln"):
        return MEANINGS["ln"].replace("BiLSTM i", f"BiLSTM {name[2:]}")
    return MEANINGS[last].replace("BiLSTM i", f"BiLSTM {stem[4:]}")


# --------------------------------------------------------------------------- traces
def _frames(window: Any, dim: int) -> list[np.ndarray]:
    frames = [np.asarray(f, dtype=np.float64) for f in window]
    for t, f in enumerate(frames):
        if f.ndim != 2 or f.shape[1] != dim or len(f) == 0:
            raise ValueError(f"window frame {t}: expected (N, {dim}) points, got {f.shape}")
    return frames


def trace(config: TPNetConfig, params: dict[str, np.ndarray], window: Any,
          dtype: Any = "float64") -> dict[str, np.ndarray]:
    """The reference's trace of one window (world units) in ``dtype``: layer -> array."""
    dt = np.dtype(dtype)
    p = {k: np.asarray(v).astype(dt) for k, v in params.items()}
    out: dict[str, np.ndarray] = {}
    reference.forward(config, p, [f.astype(dt) for f in _frames(window, config.dim)], trace=out)
    return out


def _point_layer(shape: Sequence[Any]) -> bool:
    return bool(shape) and shape[0] == "P"


def measure_gaps(config: TPNetConfig, params: dict[str, np.ndarray], window: Any,
                 expected: dict[str, np.ndarray] | None = None,
                 seed: int = 0) -> dict[str, float]:
    """Per layer, the largest ``|float32 run - float64|`` over :data:`RUNS` on one window."""
    frames = _frames(window, config.dim)
    want = expected if expected is not None else trace(config, params, frames)
    shapes = layer_shapes(config)
    rng = np.random.default_rng(seed)
    f32 = [f.astype(np.float32) for f in frames]
    nudged = [np.where(rng.random(f.shape) < 0.5, np.nextafter(f, np.float32(-np.inf)),
                       np.nextafter(f, np.float32(np.inf))) for f in f32]
    rev = [f[::-1] for f in f32]
    gaps = {k: 0.0 for k in want}
    for run, win in zip(RUNS, (f32, nudged, rev)):
        got = trace(config, params, win, "float32")
        if run.endswith("reversed"):        # put the per-point rows back in the frames' order
            counts = [len(f) for f in frames]
            for k, v in got.items():
                if _point_layer(shapes[k]):
                    parts = np.split(v, np.cumsum(counts)[:-1])
                    got[k] = np.concatenate([x[::-1] for x in parts])
        for k, v in got.items():
            if k == "input" and run != "float32":
                continue                     # the input itself is what was moved
            d = np.abs(v.astype(np.float64) - want[k])
            gaps[k] = max(gaps[k], float(d.max()) if d.size else 0.0)
    return gaps


def tolerances_from(gaps: dict[str, float], magnitudes: dict[str, float]) -> dict[str, float]:
    """``SAFETY * gap + FLOOR * max(1, magnitude)`` per layer."""
    return {k: SAFETY * gaps[k] + FLOOR * max(1.0, magnitudes[k]) for k in gaps}


def measure_tolerances(config: TPNetConfig, params: dict[str, np.ndarray],
                       windows: Sequence[Any],
                       expected: Sequence[dict[str, np.ndarray]] | None = None
                       ) -> tuple[dict[str, float], dict[str, float]]:
    """``(tolerances, gaps)`` per layer over ``windows``: the float32 rounding gap measured
    (:func:`measure_gaps`), its maximum over the windows, then :func:`tolerances_from`."""
    exp = list(expected) if expected is not None else [trace(config, params, w) for w in windows]
    gaps = {k: 0.0 for k in exp[0]}
    mags = {k: 0.0 for k in exp[0]}
    for w, e in zip(windows, exp):
        for k, v in measure_gaps(config, params, w, e).items():
            gaps[k] = max(gaps[k], v)
        for k, v in e.items():
            mags[k] = max(mags[k], float(np.abs(v).max()))
    return tolerances_from(gaps, mags), gaps


# --------------------------------------------------------------------------- the cases
@dataclass
class Case:
    name: str
    description: str
    frames: list[np.ndarray]

    @property
    def counts(self) -> list[int]:
        return [len(f) for f in self.frames]


#: scene parameters of the conformance windows (force, angle in degrees, x, y): off the
#: training grid, inside its ranges (tpnet_ref/sim/cases.py)
SCENES = ((1.22, 58.0, 17.3, 23.9), (1.53, 121.0, 30.6, 18.2))
#: the simulator steps between a window's frames, and where the first window starts
SPACING, START = 4, 60


def make_cases(config: TPNetConfig, params: dict[str, np.ndarray],
               rollout_steps: int = 3, seed: int = 0) -> list[Case]:
    """The conformance cases for a network with ``config.m`` frames (needs the ``sim`` extra):
    two scene windows, one with each frame's points shuffled, one with ragged N, the scene
    pushed against the low and the high edge of the normalisation range (the trained box), and
    ``rollout_steps`` steps of a rollout (each step's window holds the reference's float64
    predictions as its newest frames)."""
    from .extras import require
    require("tpnet_ref.sim", "sim", "tpnet vectors (the scene windows)")
    from .sim import simulate

    m = config.m
    rng = np.random.default_rng(seed)
    span = SPACING * (m - 1) + 1
    wins = []
    for force, angle, x, y in SCENES:
        traj = simulate(force, angle, x, y, steps=START + span + 1)
        wins.append([traj[START + SPACING * t] for t in range(m)])
    a, b = wins
    cases = [Case("scene1", f"simulated scene {SCENES[0]} (force, angle, x, y), frames "
                  f"{START}, {START + SPACING}, ... of the trajectory", a),
             Case("scene2", f"simulated scene {SCENES[1]}", b),
             Case("shuffled", "scene1 with each frame's points in a random order",
                  [f[rng.permutation(len(f))] for f in a])]
    keep = [max(1, len(f) - 4 * t - 3 * (t % 2)) for t, f in enumerate(b)]
    cases.append(Case("ragged", f"scene2 with frames of {keep} points (random subsets)",
                      [f[np.sort(rng.choice(len(f), k, replace=False))]
                       for f, k in zip(b, keep)]))
    lo, hi = config.norm_lo, config.norm_hi
    allpts = np.concatenate(a)
    cases.append(Case("edge_low", "scene1 moved against the low edge of the normalisation "
                      "range (its smallest x and y at norm_lo)",
                      [f - allpts.min(axis=0) + lo for f in a]))
    cases.append(Case("edge_high", "scene1 moved against the high edge (its largest x and y "
                      "at norm_hi)", [f - allpts.max(axis=0) + hi for f in a]))
    frames = list(b)
    for s in range(1, rollout_steps + 1):
        nxt = reference.forward(config, {k: np.asarray(v, np.float64) for k, v in params.items()},
                                frames[-m:])
        frames.append(nxt)
        cases.append(Case(f"rollout{s}", f"step {s} of a rollout from scene2: its newest "
                          f"{min(s, m)} frame(s) the reference's float64 predictions",
                          frames[-m:]))
    return cases


# --------------------------------------------------------------------------- vectors files
def _json_config(config: TPNetConfig) -> dict[str, Any]:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in config.to_dict().items()}


def write_vectors(config: TPNetConfig, params: dict[str, np.ndarray], out_dir: str | os.PathLike,
                  cases: Sequence[Case] | None = None,
                  weights: dict[str, Any] | None = None) -> dict[str, Any]:
    """Write ``out_dir/manifest.json`` and ``out_dir/vectors.npz`` (every case's input, every
    intermediate and the output in float64 under ``<case>.<layer>``); returns the manifest."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ValueError(f"output {out}: exists and is not a directory")
    if not out.parent.is_dir():
        raise FileNotFoundError(f"output {out}: directory {out.parent} does not exist")
    cases = list(cases) if cases is not None else make_cases(config, params)
    expected = [trace(config, params, c.frames) for c in cases]
    tol, gaps = measure_tolerances(config, params, [c.frames for c in cases], expected)
    shapes = layer_shapes(config)
    names = layer_names(config)
    manifest = {
        "format": FORMAT, "version": VERSION, "config": _json_config(config),
        "weights": weights or {},
        "dtype": "float64",
        "key": "<case>.<layer> in vectors.npz (a zip of .npy files)",
        "tolerance_rule": f"tolerance = {SAFETY:g} * gap + 2^{int(math.log2(FLOOR))} * "
                          "max(1, max |layer|); gap = the largest |float32 - float64| of the "
                          "reference over the cases and the runs: " + "; ".join(RUNS),
        "layers": [{"name": n, "shape": shapes[n], "meaning": meaning(n),
                    "tolerance": tol[n], "float32_gap": gaps[n]} for n in names],
        "cases": [{"name": c.name, "description": c.description, "counts": c.counts,
                   "shapes": {n: list(e[n].shape) for n in names}}
                  for c, e in zip(cases, expected)],
    }
    out.mkdir(exist_ok=True)
    arrays = {f"{c.name}.{n}": e[n] for c, e in zip(cases, expected) for n in names}
    with open(out / "vectors.npz", "wb") as fh:
        np.savez(fh, **arrays)
    with open(out / "manifest.json", "w") as fh:
        json.dump(manifest, fh, indent=1)
        fh.write("\n")
    return manifest


@dataclass
class Vectors:
    """A vectors folder: its manifest, config, layers and tolerances, and per case its arrays."""

    path: Path
    manifest: dict[str, Any]
    config: TPNetConfig
    layers: list[str]
    tolerances: dict[str, float]
    cases: dict[str, dict[str, Any]]           # name -> its manifest entry
    arrays: dict[str, dict[str, np.ndarray]]   # case -> layer -> float64 array

    def window(self, case: str) -> list[np.ndarray]:
        """A case's input as ``m`` frames ``(N_t, dim)`` in world units."""
        counts = self.cases[case]["counts"]
        return np.split(self.arrays[case]["input"], np.cumsum(counts)[:-1])


def _load_npz(path: Path, what: str) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise FileNotFoundError(f"{what} not found: {path}")
    if not zipfile.is_zipfile(path):
        raise ValueError(f"{what} {path}: not an .npz archive (a zip of .npy files, "
                         "numpy.savez)")
    try:
        with zipfile.ZipFile(path) as z:
            infos = z.infolist()
        if len(infos) > MAX_TRACE_KEYS or sum(i.file_size for i in infos) > 1 << 31:
            raise ValueError(f"{what} {path}: {len(infos):,} members; refused before reading")
        with np.load(path, allow_pickle=False) as z:
            out = {}
            for k in z.files:
                a = z[k]
                if a.dtype.kind not in "fiu":
                    raise ValueError(f"{what} {path}: key {k!r} holds {a.dtype} values, "
                                     "expected numbers")
                out[k] = a.astype(np.float64)
            return out
    except (zipfile.BadZipFile, EOFError, OSError) as exc:
        raise ValueError(f"{what} {path}: damaged archive ({exc})") from None
    except ValueError as exc:
        if "pickle" in str(exc):
            raise ValueError(f"{what} {path}: holds Python objects, which are never "
                             "unpickled") from None
        raise


def read_vectors(path: str | os.PathLike) -> Vectors:
    """A folder written by :func:`write_vectors` (``tpnet vectors``), checked whole."""
    d = Path(path)
    if not d.is_dir():
        raise FileNotFoundError(f"vectors folder not found: {d}")
    mpath = d / "manifest.json"
    if not mpath.is_file():
        raise FileNotFoundError(f"vectors {d}: no manifest.json (write one with tpnet vectors)")
    try:
        man = json.loads(mpath.read_text())
        if man.get("format") != FORMAT:
            raise ValueError(f"vectors {d}: manifest.json is not a {FORMAT} manifest")
        if man.get("version") != VERSION:
            raise ValueError(f"vectors {d}: manifest version {man.get('version')!r}, this "
                             f"tpnet_ref reads version {VERSION}")
        cfg = TPNetConfig.from_dict(dict(man["config"]))
        layers = [e["name"] for e in man["layers"]]
        tol = {e["name"]: float(e["tolerance"]) for e in man["layers"]}
        cases = {c["name"]: c for c in man["cases"]}
    except (json.JSONDecodeError, KeyError, TypeError, AttributeError) as exc:
        raise ValueError(f"vectors {d}: malformed manifest.json ({type(exc).__name__}: "
                         f"{exc})") from None
    if layers != layer_names(cfg):
        raise ValueError(f"vectors {d}: the manifest's layers are not those of its network "
                         f"(expected {layer_names(cfg)})")
    flat = _load_npz(d / "vectors.npz", f"vectors {d}:")
    arrays: dict[str, dict[str, np.ndarray]] = {c: {} for c in cases}
    for c, entry in cases.items():
        for n in layers:
            key = f"{c}.{n}"
            if key not in flat:
                raise ValueError(f"vectors {d}: vectors.npz lacks {key!r}")
            if list(flat[key].shape) != list(entry["shapes"][n]):
                raise ValueError(f"vectors {d}: {key!r} has shape {flat[key].shape}, the "
                                 f"manifest says {tuple(entry['shapes'][n])}")
            arrays[c][n] = flat[key]
    return Vectors(d, man, cfg, layers, tol, cases, arrays)


def describe_config(cfg: TPNetConfig) -> str:
    return (f"m={cfg.m}, n_out={cfg.n_out}, mlp1={cfg.mlp1}, mlp2={cfg.mlp2}, "
            f"global_features={cfg.global_features}, lstm_units={cfg.lstm_units}")


def check_same_network(vectors: Vectors, config: TPNetConfig, what: str) -> None:
    """A one-line error when ``config``'s shapes are not those the vectors were made for."""
    a, b = vectors.config, config
    fields = ("m", "n_out", "dim", "mlp1", "mlp2", "global_features", "lstm_units",
              "input_transform_trained", "feature_transform_trained")
    diff = [f for f in fields if getattr(a, f) != getattr(b, f)]
    if diff:
        raise ValueError(f"{what} is another network than the one the vectors in "
                         f"{vectors.path} were made for: "
                         + ", ".join(f"{f}={getattr(b, f)} (vectors: {getattr(a, f)})"
                                     for f in diff))


# --------------------------------------------------------------------------- a port's trace
def save_trace(path: str | os.PathLike, traces: dict[str, dict[str, np.ndarray]]) -> None:
    """Write ``{case: {layer: array}}`` as a port's trace file (``<case>.<layer>`` keys)."""
    with open(path, "wb") as fh:
        np.savez(fh, **{f"{c}.{n}": np.asarray(a) for c, t in traces.items()
                        for n, a in t.items()})


def _fit_shape(a: np.ndarray, want: tuple[int, ...], counts: list[int]) -> np.ndarray | None:
    """``a`` in the vectors' shape: as is, without leading batch axes of 1, or a per-point
    layer given as ``(m, N, C)`` where every frame has N points; None if it does not fit."""
    while a.ndim > len(want) and a.shape[0] == 1:
        a = a[0]
    if a.shape == want:
        return a
    if (len(want) == 2 and a.ndim == 3 and len(set(counts)) == 1
            and a.shape == (len(counts), counts[0], want[1])):
        return a.reshape(want)
    return None


def load_trace(path: str | os.PathLike, vectors: Vectors) -> dict[str, dict[str, np.ndarray]]:
    """A port's trace file (``.npz``, keys ``<case>.<layer>`` as in ``vectors.npz``; layers
    may be left out), checked against ``vectors``: ``{case: {layer: float64 array}}``."""
    p = Path(path)
    flat = _load_npz(p, "trace")
    out: dict[str, dict[str, np.ndarray]] = {}
    unknown = []
    for key, a in flat.items():
        case, _, layer = key.partition(".")
        if case not in vectors.cases or layer not in vectors.tolerances:
            unknown.append(key)
            continue
        want = tuple(vectors.arrays[case][layer].shape)
        fit = _fit_shape(a, want, vectors.cases[case]["counts"])
        if fit is None:
            raise ValueError(f"trace {p}: {key!r} has shape {a.shape}, the vectors have {want}")
        out.setdefault(case, {})[layer] = fit
    if unknown:
        raise ValueError(f"trace {p}: unknown key(s) {sorted(unknown)[:5]}"
                         f"{' ...' if len(unknown) > 5 else ''}: keys are <case>.<layer> with "
                         f"cases {list(vectors.cases)} and layers {vectors.layers}")
    if not out:
        raise ValueError(f"trace {p}: holds no layer of any case of the vectors")
    return out


# --------------------------------------------------------------------------- comparison
@dataclass
class LayerResult:
    layer: str
    max_abs: float
    tolerance: float
    where: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.max_abs <= self.tolerance

    def where_text(self) -> str:
        return ", ".join(f"{k.replace('_', ' ')} {v}" if k not in ("direction",) else str(v)
                         for k, v in self.where.items())


@dataclass
class CaseResult:
    case: str
    layers: list[LayerResult]
    missing: list[str]

    @property
    def first(self) -> LayerResult | None:
        return next((r for r in self.layers if not r.ok), None)


def _kind(layer: str) -> str:
    if layer.endswith((".fwd", ".bwd")):
        return "lstm"
    if layer.endswith(".concat"):
        return "concat"
    if layer.startswith("ln"):
        return "ln"
    if layer in ("pooled", "global") or layer.endswith(".transform"):
        return "frame"
    if layer.startswith("head") or layer == "output":
        return "out"
    return "point"


def locate(layer: str, err: np.ndarray, tol: float, counts: Sequence[int],
           config: TPNetConfig) -> dict[str, Any]:
    """Where a layer's error starts: among the entries beyond ``tol`` (all, if none is), the
    earliest frame or time step in the order the network computes them (the backward direction
    from the last step), and in it the entry with the largest error."""
    bad = err > tol
    if not bad.any():
        bad = np.ones_like(bad)
    kind = _kind(layer)
    coord = "xyz"[:config.dim] if config.dim <= 3 else None

    def argmax(a: np.ndarray, mask: np.ndarray) -> tuple[int, ...]:
        return tuple(int(i) for i in np.unravel_index(np.argmax(np.where(mask, a, -1.0)),
                                                      a.shape))

    if kind == "point":
        ends = np.cumsum(counts)
        row0 = int(np.argmax(bad.any(axis=1)))
        f = int(np.searchsorted(ends, row0, side="right"))
        start = int(ends[f - 1]) if f else 0
        r, c = argmax(err[start:ends[f]], bad[start:ends[f]])
        return {"frame": f, "point": r, "channel": c}
    if kind == "frame":
        f = int(np.argmax(bad.reshape(len(bad), -1).any(axis=1)))
        return {"frame": f, "channel": int(argmax(err[f].ravel(), bad[f].ravel())[0])}
    if kind == "lstm":
        steps = range(err.shape[0]) if layer.endswith(".fwd") else range(err.shape[0] - 1, -1, -1)
        t = next(t for t in steps if bad[t].any())
        return {"time_step": t, "direction": "forward" if layer.endswith(".fwd") else "backward",
                "unit": argmax(err[t], bad[t])[0]}
    if kind in ("concat", "ln"):
        u = err.shape[-1] // 2
        where: dict[str, Any] = {}
        if err.ndim == 2:
            t = int(np.argmax(bad.any(axis=1)))
            where["time_step"] = t
            e, b = err[t], bad[t]
        else:
            e, b = err, bad
        j = argmax(e, b)[0]
        if kind == "concat":
            where.update(direction="forward" if j < u else "backward", unit=j % u)
        else:
            where.update(channel=j)
        return where
    j = argmax(err.reshape(-1), bad.reshape(-1))[0]            # the head and the output
    return {"point": j // config.dim,
            "coordinate": coord[j % config.dim] if coord else j % config.dim}


def compare_case(vectors: Vectors, case: str, got: dict[str, np.ndarray],
                 tolerances: dict[str, float] | None = None) -> CaseResult:
    """One case of a port's trace against the vectors, layer by layer in forward order."""
    tol = tolerances or vectors.tolerances
    want = vectors.arrays[case]
    counts = vectors.cases[case]["counts"]
    res, missing = [], []
    for layer in vectors.layers:
        if layer not in got:
            missing.append(layer)
            continue
        err = np.abs(np.asarray(got[layer], np.float64) - want[layer])
        err = np.where(np.isnan(err), np.inf, err)
        mx = float(err.max()) if err.size else 0.0
        res.append(LayerResult(layer, mx, tol[layer],
                               locate(layer, err, tol[layer], counts, vectors.config)))
    return CaseResult(case, res, missing)


def compare(vectors: Vectors, traces: dict[str, dict[str, np.ndarray]]) -> list[CaseResult]:
    """Every case the port's trace holds, in the manifest's order."""
    return [compare_case(vectors, c, traces[c]) for c in vectors.cases if c in traces]


def first_divergence(results: Sequence[CaseResult], layers: Sequence[str]
                     ) -> tuple[CaseResult, LayerResult] | None:
    """The earliest layer in forward order beyond its tolerance in any case (the first case
    on a tie), or None when every case agrees."""
    best = None
    for r in results:
        f = r.first
        if f is not None and (best is None or layers.index(f.layer) < layers.index(best[1].layer)):
            best = (r, f)
    return best


def report_json(results: Sequence[CaseResult], layers: Sequence[str]) -> dict[str, Any]:
    first = first_divergence(results, layers)

    def fd(r: CaseResult, f: LayerResult) -> dict[str, Any]:
        return {"case": r.case, "layer": f.layer, "max_abs": f.max_abs,
                "tolerance": f.tolerance, "where": f.where}

    return {"first_divergence": fd(*first) if first else None,
            "cases": {r.case: {"first_divergence": fd(r, r.first) if r.first else None,
                               "layers_compared": len(r.layers), "layers_missing": r.missing}
                      for r in results}}


def report_text(results: Sequence[CaseResult], layers: Sequence[str], after: int = 6) -> str:
    """Per case: the first layer beyond its tolerance, its largest error and where it starts,
    then the ``after`` layers that follow it (all agree: the closest call)."""
    lines = []
    width = max(len(r.case) for r in results)
    same_missing = all(r.missing == results[0].missing for r in results)
    for r in results:
        head = f"{r.case:<{width}}  "
        f = r.first
        if f is None:
            worst = max(r.layers, key=lambda x: x.max_abs / x.tolerance)
            lines.append(head + f"agrees: {len(r.layers)} layers within tolerance (closest: "
                         f"{worst.layer}, {worst.max_abs:.2g} of {worst.tolerance:.2g})")
        else:
            lines.append(head + f"DIVERGES at {f.layer}: max |diff| {f.max_abs:.3g} > "
                         f"tolerance {f.tolerance:.2g}, from {f.where_text()}")
            i = r.layers.index(f)
            rest = r.layers[i + 1:i + 1 + after]
            if rest:
                lines.append(" " * (width + 2) + "then: " + ", ".join(
                    f"{x.layer} {x.max_abs:.2g}{'' if x.ok else ' (beyond)'}" for x in rest)
                    + (" ..." if len(r.layers) > i + 1 + after else ""))
        if r.missing and not same_missing:
            lines.append(" " * (width + 2) + f"not in the trace: {', '.join(r.missing)}")
    if results and results[0].missing and same_missing:
        lines.append(f"not in the trace (any case): {', '.join(results[0].missing)}")
    first = first_divergence(results, layers)
    n_bad = sum(r.first is not None for r in results)
    if first is None:
        lines.append(f"all {len(results)} case(s) agree with the reference")
    else:
        c, f = first
        lines.append(f"{n_bad} of {len(results)} case(s) diverge; the earliest layer: {f.layer} "
                     f"(case {c.case}, {f.where_text()})")
    return "\n".join(lines)


__all__ = ["layer_names", "layer_shapes", "trace", "measure_gaps", "measure_tolerances",
           "make_cases", "Case", "write_vectors", "read_vectors", "Vectors", "load_trace",
           "save_trace", "compare", "compare_case", "first_divergence", "report_text",
           "report_json", "check_same_network", "FORMAT", "VERSION", "SAFETY", "FLOOR"]

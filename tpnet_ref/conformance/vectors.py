"""The conformance vectors' files: ``DIR/manifest.json`` + ``DIR/vectors.npz``
(:func:`write_conformance_vectors`, ``tpnet vectors``; :func:`read_conformance_vectors`), and a
port's trace file checked against them (:func:`save_trace`, :func:`load_trace`). Untrusted
files: ``.npz`` are read with ``allow_pickle=False``, their size bounded before reading."""
from __future__ import annotations

import json
import math
import os
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..config import TPNetConfig
from .cases import Case, make_cases
from .layer_names import layer_names, layer_shapes, meaning
from .tolerances import FLOOR, RUNS, SAFETY, measure_tolerances, trace

FORMAT = "tpnet-conformance-vectors"
VERSION = 1
#: case names: no dots (a key is ``<case>.<layer>``)
MAX_TRACE_KEYS = 100_000


def _json_config(config: TPNetConfig) -> dict[str, Any]:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in config.to_dict().items()}


def write_conformance_vectors(config: TPNetConfig, params: dict[str, np.ndarray], out_dir: str | os.PathLike,
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


def read_conformance_vectors(path: str | os.PathLike) -> Vectors:
    """A folder written by :func:`write_conformance_vectors` (``tpnet vectors``), checked whole."""
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


__all__ = ["FORMAT", "VERSION", "MAX_TRACE_KEYS", "write_conformance_vectors",
           "read_conformance_vectors", "Vectors", "describe_config", "check_same_network",
           "save_trace", "load_trace"]

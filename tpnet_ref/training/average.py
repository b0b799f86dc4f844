"""Weight averaging ("model soup"): one native weights file from the weighted mean of others.

Fine-tunes of one network that started from the same weights stay in one basin of the loss:
the mean of their parameters is often better than each of them (Wortsman et al. 2022, "Model
soups"). Here the shipped m = 4 file and its fine-tune on a GPU (``docs/history.md``, "Weight
averaging") averaged half and half scored better on the validation trajectories at 40 and 80
predictions than either file alone.

Only files of the same network in the same basis can be averaged: the same configuration, and
parameters that are still close (every tensor's correlation with the first file's at least
``min_correlation``): two networks trained apart have their hidden units in unrelated orders,
and their mean is a broken network. (``tpnet sort-units`` does not change the parameters, only
the engine's layout, so sorted and unsorted files average alike; the result carries no unit
order: sort it.) The check is necessary, not sufficient: fine-tunes that drifted far apart
pass it and still average badly, so score every average. NumPy and h5py only (no torch).
"""
from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..weights.native import DIGEST_ATTR, read_native, write_native
from ..weights.provenance import portable_path
from .lineage import file_state, inherited

#: the smallest correlation, tensor by tensor, of a file's parameters with the first file's
MIN_CORRELATION = 0.9
#: the counters of a chain of training (the largest over the inputs is the average's)
_COUNTERS = ("training_steps", "epochs", "windows_seen", "wall_time_s")


def _correlation(a: np.ndarray, b: np.ndarray) -> float:
    a = a.astype(np.float64).ravel() - a.mean(dtype=np.float64)
    b = b.astype(np.float64).ravel() - b.mean(dtype=np.float64)
    na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    if na == 0.0 or nb == 0.0:
        return 1.0 if na == nb else 0.0
    return float(a @ b) / (na * nb)


def average(paths: Sequence[str | os.PathLike], out: str | os.PathLike,
            weights: Sequence[float] | None = None,
            min_correlation: float = MIN_CORRELATION) -> dict[str, Any]:
    """Write ``out``, a native weights file whose every parameter is ``sum(w_i * p_i)`` over the
    files ``paths`` (computed in float64, stored in the first file's dtype), ``weights`` summing
    to 1 (default: equal). Raises ``ValueError`` naming the problem when fewer than two files are
    given, the weights do not fit, the networks differ, or a file's parameters are not in the
    first file's basis (a tensor's correlation below ``min_correlation``). Returns the
    provenance written: ``average_of`` (each file, its weight and content digest), the inputs'
    chains as ``parent_runs``, and as counters the largest input's (the compute of the longest
    chain: exact when the inputs descend from one another, a lower bound for sibling
    fine-tunes)."""
    paths = list(paths)
    if len(paths) < 2:
        raise ValueError(f"average needs at least two weights files, got {len(paths)}")
    w = np.full(len(paths), 1.0 / len(paths)) if weights is None else np.asarray(weights, float)
    if w.shape != (len(paths),):
        raise ValueError(f"average: {len(w)} weights for {len(paths)} files")
    if not (np.isfinite(w).all() and (w >= 0).all() and abs(w.sum() - 1.0) <= 1e-6):
        raise ValueError(f"average: the weights must be >= 0 and sum to 1, got {w.tolist()}")
    files = [read_native(p) for p in paths]
    cfg0, p0, meta0 = files[0]
    for path, (cfg, params, _) in zip(paths[1:], files[1:]):
        if cfg != cfg0:
            diff = [f"{f.name} {getattr(cfg, f.name)} vs {getattr(cfg0, f.name)}"
                    for f in dataclasses.fields(cfg0) if getattr(cfg, f.name) != getattr(cfg0, f.name)]
            raise ValueError(f"average: {path} is another network than {paths[0]} "
                             f"({'; '.join(diff)})")
        for name, a in p0.items():
            r = _correlation(a, params[name])
            if not r >= min_correlation:
                raise ValueError(
                    f"average: {path} is not in the basis of {paths[0]}: parameter {name} "
                    f"correlates {r:.3f} < {min_correlation} (networks trained apart)")
    dtype = next(iter(p0.values())).dtype
    params = {name: sum(float(wi) * f[1][name].astype(np.float64) for wi, f in zip(w, files))
              .astype(dtype) for name in p0}
    metas = [f[2] for f in files]
    big = max(range(len(files)), key=lambda i: float(metas[i].get("epochs", 0) or 0))
    prov: dict[str, Any] = {
        "source": "tpnet train average", "producer": "tpnet_ref.training",
        "recipe": json.dumps({"recipe": "average", "mix": [float(x) for x in w],
                              "files": [portable_path(str(p)) for p in paths]}),
        "average_of": json.dumps([{"weights_file": portable_path(str(p)), "weight": float(wi),
                                   "content_sha256": str(m.get(DIGEST_ATTR, ""))}
                                  for p, wi, m in zip(paths, w, metas)]),
        "parent_runs": json.dumps([inherited(p, file_state(p, m))["runs"][-1]
                                   for p, m in zip(paths, metas)], sort_keys=True),
        "data": str(metas[big].get("data", "")), "data_sha256": str(metas[big].get("data_sha256", "")),
        "hardware": "; ".join(sorted({str(m.get("hardware", "")) for m in metas} - {""})),
    }
    for key in _COUNTERS:
        if key in metas[big]:
            prov[key] = metas[big][key]
    write_native(out, cfg0, params, dtype=dtype, meta=prov)
    return prov


__all__ = ["average", "MIN_CORRELATION"]

"""Where a run's starting weights came from: the provenance a fine-tune (``--init-from``) or a
weight average (:mod:`tpnet_ref.training.average`) carries of its parents. NumPy only (no
torch), so that ``tpnet train average`` needs none."""
from __future__ import annotations

import json
import os
from typing import Any

from ..weights.provenance import portable_path, scrub_text


def file_state(path: str | os.PathLike, meta: dict[str, Any]) -> dict[str, Any]:
    """The provenance state of a native weights file read as a parent (its root attributes
    ``meta``): the file's counters already total the chain that made it, so it becomes one
    inherited entry whose recipe names the file, its source, recipe and parent runs."""
    return {"data": str(meta.get("data", "")), "data_sha256": str(meta.get("data_sha256", "")),
            "step": int(meta.get("training_steps", 0)),
            "epochs": float(meta.get("epochs", 0.0)),
            "windows_seen": int(meta.get("windows_seen", 0)),
            "wall_s": float(meta.get("wall_time_s", 0.0)),
            "recipe": {"weights_file": portable_path(path),
                       "source": portable_path(str(meta.get("source", ""))),
                       "recipe": json.loads(meta.get("recipe", "{}") or "{}"),
                       "parent_runs": json.loads(meta.get("parent_runs", "[]") or "[]")}}


def inherited(source: str | os.PathLike, pstate: dict) -> dict:
    """Provenance carried into a fine-tuning run: the training that made its starting weights
    (summed over the whole chain of runs, each listed)."""
    prev = pstate.get("inherited", {"runs": [], "windows_seen": 0, "wall_s": 0.0, "steps": 0,
                                    "epochs": 0.0})
    me = {"run": portable_path(source), "data": portable_path(pstate.get("data", "")),
          "data_sha256": pstate.get("data_sha256", ""), "steps": int(pstate.get("step", 0)),
          "epochs": float(pstate["epochs"]) if "epochs" in pstate else
          float(pstate.get("step", 0)) / (pstate.get("steps_per_epoch", 0) or 1),
          "windows_seen": int(pstate.get("windows_seen", 0)),
          "wall_s": float(pstate.get("wall_s", 0.0)),
          "recipe": json.loads(scrub_text(json.dumps(pstate.get("recipe", {}))))}
    return {"runs": prev["runs"] + [me],
            "windows_seen": prev["windows_seen"] + me["windows_seen"],
            "wall_s": prev["wall_s"] + me["wall_s"], "steps": prev["steps"] + me["steps"],
            "epochs": prev["epochs"] + me["epochs"]}


__all__ = ["file_state", "inherited"]

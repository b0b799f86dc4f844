"""Training checkpoints: write, read, split into parts, and the provenance of fine-tuning runs.

A run directory holds ``checkpoint.json`` (the recipe, the position and the counters, written
last) and the torch payload ``{"model": state dict, "optimizer": Adam state dict}`` (tensors and
plain containers only, read with ``torch.load(weights_only=True)``), either as one file
``checkpoint.pt`` or, with ``part_mib``, as ``checkpoint.pt.000``, ``checkpoint.pt.001``, ...
of at most that many MiB each (for machines whose files travel in pieces of at most 16 MiB).
``checkpoint.json`` lists the files with the payload's size and SHA-256, so a missing or
damaged part is refused with a one-line error.

``optimizer`` decides how much of Adam's state is kept: ``full`` (float32; a resumed run computes
exactly what the uninterrupted one computes), ``bf16`` (the two moment tensors in bfloat16: half
the size, resumed runs differ by the rounding of the moments) or ``none`` (the model only, a
third of the size; the resumed run starts a fresh Adam at its position in the schedule).
The full-size network's payload: about 85 MB ``full``, 57 MB ``bf16``, 28 MB ``none``.
"""
from __future__ import annotations

import hashlib
import io
import json
import math
import os
from pathlib import Path
from typing import Any

from .. import load
from ..config import TPNetConfig
from ..extras import require
from .lineage import file_state
from .recipe import OPTIMIZER_MODES, Recipe
from .torch_model import TorchTPNet

torch = require("torch", "train")

CKPT_NAME = "checkpoint.pt"
SIDECAR_NAME = "checkpoint.json"


def _payload(net: Any, opt: Any, optimizer: str) -> dict:
    if optimizer not in OPTIMIZER_MODES:
        raise ValueError(f"optimizer must be one of {OPTIMIZER_MODES}, got {optimizer!r}")
    out: dict[str, Any] = {"model": net.state_dict()}
    if optimizer == "full":
        out["optimizer"] = opt.state_dict()
    elif optimizer == "bf16":
        out["optimizer"] = _bf16_moments(opt.state_dict())
    return out


def _bf16_moments(sd: dict) -> dict:
    """An Adam state dict with its moment tensors in bfloat16 (the step counts, scalars, stay);
    Optimizer.load_state_dict casts them back to the parameters' dtype."""
    low = {k: {n: (v.to(torch.bfloat16) if torch.is_tensor(v) and v.is_floating_point()
                   and v.dim() > 0 else v) for n, v in s.items()}
           for k, s in sd["state"].items()}
    return {"state": low, "param_groups": sd["param_groups"]}


def _write_atomic(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def _part_names(run_dir: Path) -> list[Path]:
    return sorted(p for p in run_dir.glob(CKPT_NAME + ".[0-9][0-9][0-9]"))


def save_checkpoint(run_dir: str | os.PathLike, net: Any, opt: Any, state: dict,
                    part_mib: float | None = None, optimizer: str = "full") -> list[Path]:
    """Write the run's checkpoint (see the module docstring); returns the payload's files.
    ``state`` (JSON-able) gets ``checkpoint_files`` and is written last, atomically."""
    return _write_payload(Path(run_dir), _payload(net, opt, optimizer), state, part_mib, optimizer)


def repack_checkpoint(src: str | os.PathLike, dst: str | os.PathLike, optimizer: str = "bf16",
                      part_mib: float | None = 16.0) -> list[Path]:
    """``src``'s checkpoint written again into ``dst`` with Adam's state kept as ``optimizer``
    (``bf16``: the moments rounded to bfloat16, two thirds of the size; the run resumes from
    ``dst`` with that rounding) in parts of ``part_mib``; ``dst`` gets ``src``'s
    ``checkpoint.json`` with its file list updated. Refused where ``src`` has no Adam state and
    one is asked for."""
    if optimizer not in OPTIMIZER_MODES:
        raise ValueError(f"optimizer must be one of {OPTIMIZER_MODES}, got {optimizer!r}")
    payload, state = load_checkpoint(src)
    out: dict[str, Any] = {"model": payload["model"]}
    if optimizer != "none":
        if "optimizer" not in payload:
            raise ValueError(f"{src}: its checkpoint keeps no Adam state, so none can be "
                             f"packed as {optimizer!r} (use optimizer='none')")
        out["optimizer"] = (payload["optimizer"] if optimizer == "full"
                            else _bf16_moments(payload["optimizer"]))
    return _write_payload(Path(dst), out, state, part_mib, optimizer)


def _write_payload(run_dir: Path, payload: dict, state: dict, part_mib: float | None,
                   optimizer: str) -> list[Path]:
    run_dir.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    torch.save(payload, buf)
    data = buf.getvalue()
    if part_mib is not None:
        size = int(part_mib * (1 << 20))
        if size < 1:
            raise ValueError(f"part_mib must be > 0, got {part_mib}")
        n = max(1, math.ceil(len(data) / size))
        files = [run_dir / f"{CKPT_NAME}.{i:03d}" for i in range(n)]
        if n > 1000:
            raise ValueError(f"part_mib={part_mib}: {n} parts, more than 1000")
        for i, f in enumerate(files):
            _write_atomic(f, data[i * size:(i + 1) * size])
    else:
        files = [run_dir / CKPT_NAME]
        _write_atomic(files[0], data)
    state["checkpoint_files"] = {"files": [f.name for f in files], "bytes": len(data),
                                 "sha256": hashlib.sha256(data).hexdigest(),
                                 "optimizer": optimizer}
    _write_atomic(run_dir / SIDECAR_NAME, json.dumps(state, indent=1, sort_keys=True).encode())
    for stale in [run_dir / CKPT_NAME, *_part_names(run_dir)]:
        if stale not in files and stale.exists():
            stale.unlink()
    return files


def load_checkpoint(path: str | os.PathLike) -> tuple[dict, dict]:
    """``(torch payload, sidecar state)`` from a run directory or its ``checkpoint.pt``, whether
    the payload is one file or parts. The payload has no ``"optimizer"`` when it was saved with
    ``optimizer="none"``."""
    p = Path(path)
    run_dir = p if p.is_dir() else p.parent
    side = run_dir / SIDECAR_NAME
    state = json.loads(side.read_text()) if side.is_file() else {}
    listed = state.get("checkpoint_files")
    if listed is None:                      # a file without a sidecar, or an older run
        ckpt = run_dir / CKPT_NAME if p.is_dir() else p
        if not ckpt.is_file():
            raise FileNotFoundError(f"checkpoint not found: {ckpt}")
        return torch.load(ckpt, map_location="cpu", weights_only=True), state
    payload = torch.load(io.BytesIO(checkpoint_bytes(run_dir, listed)), map_location="cpu",
                         weights_only=True)
    return payload, state


def checkpoint_bytes(run_dir: str | os.PathLike, listed: dict | None = None) -> bytes:
    """The payload of ``run_dir``'s checkpoint files (parts joined), checked against the list,
    size and SHA-256 in its ``checkpoint.json`` (``listed``: its ``checkpoint_files``, read
    when not given); a missing part raises FileNotFoundError, a damaged or mixed set
    ValueError."""
    run_dir = Path(run_dir)
    if listed is None:
        listed = json.loads((run_dir / SIDECAR_NAME).read_text())["checkpoint_files"]
    chunks = []
    for name in listed["files"]:
        f = run_dir / name
        if not f.is_file():
            raise FileNotFoundError(f"checkpoint part not found: {f} (checkpoint.json lists "
                                    f"{len(listed['files'])} files)")
        chunks.append(f.read_bytes())
    data = b"".join(chunks)
    if len(data) != listed["bytes"] or hashlib.sha256(data).hexdigest() != listed["sha256"]:
        raise ValueError(f"{run_dir}: checkpoint files {listed['files']} do not match "
                         f"checkpoint.json ({len(data):,} bytes, expected {listed['bytes']:,}, "
                         "or another SHA-256): incomplete or mixed copies")
    return data


def load_parent(source: str | os.PathLike) -> tuple[dict, dict, TPNetConfig]:
    """Starting weights of a fine-tuning run: ``(torch state dict, provenance state, config)``
    from a run directory / ``checkpoint.pt`` or from a native weights file (``.h5``, e.g. a
    shipped model; its stored provenance becomes the inherited chain)."""
    p = Path(source)
    if p.suffix in (".h5", ".hdf5") and p.is_file():
        model = load(p, dtype="float32")
        net = TorchTPNet.from_numpy(model)
        return net.state_dict(), file_state(p, model.meta), model.config
    parent, pstate = load_checkpoint(source)
    if "recipe" not in pstate:
        raise ValueError(f"--init-from {source}: checkpoint has no checkpoint.json recipe")
    return parent["model"], pstate, Recipe.from_dict(pstate["recipe"]).tpnet_config


def load_parent_optimizer(source: str | os.PathLike) -> dict:
    """Adam's state (moments and step counts) in a parent run's checkpoint, for a branch that
    keeps it (``init_optimizer``); a weights file or a checkpoint saved without it is refused."""
    p = Path(source)
    if p.suffix in (".h5", ".hdf5"):
        raise ValueError(f"--init-optimizer: {source} is a weights file, it holds no optimizer "
                         "state; give the parent's run directory")
    parent, _ = load_checkpoint(source)
    if "optimizer" not in parent:
        raise ValueError(f"--init-optimizer: {source}'s checkpoint was saved without Adam's "
                         "state (--checkpoint-optimizer none)")
    return parent["optimizer"]


__all__ = ["save_checkpoint", "load_checkpoint", "load_parent", "load_parent_optimizer",
           "CKPT_NAME", "SIDECAR_NAME", "OPTIMIZER_MODES"]

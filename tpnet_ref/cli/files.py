"""Reading and writing the ``.npy`` files the commands take and give, with one-line errors."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def output_path(path: str, what: str = "output", suffix: str | None = None) -> Path:
    """``path`` as given (no suffix added), after checking its directory exists and, with
    ``suffix``, that it ends in it."""
    if suffix is not None and not str(path).lower().endswith(suffix):
        raise ValueError(f"{what} {path}: must end in {suffix} (the file is written as {suffix}, "
                         "exactly at the path given)")
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise FileNotFoundError(f"{what} {path}: directory {parent} does not exist")
    if p.is_dir():
        raise ValueError(f"{what} {path}: is a directory")
    return p


def save_npy(path: str, arr: np.ndarray, what: str = "output") -> Path:
    """Write ``arr`` in the ``.npy`` format to exactly ``path`` (NumPy would add ``.npy``)."""
    p = output_path(path, what)
    with open(p, "wb") as fh:
        np.save(fh, arr, allow_pickle=False)
    return p


def load_npy(path: str, what: str = "window file") -> np.ndarray:
    """One numeric array from a ``.npy`` file; never unpickles."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{what} not found: {path}")
    with open(p, "rb") as fh:
        magic = fh.read(6)
    if magic != b"\x93NUMPY":
        kind = "an .npz archive" if magic[:2] == b"PK" else "no .npy header"
        raise ValueError(f"{what} {path}: not a numeric .npy array ({kind}; save one array "
                         "with numpy.save)")
    try:
        arr: Any = np.load(p, allow_pickle=False)
    except (ValueError, EOFError, OSError) as exc:
        reason = "holds Python objects, which are never unpickled" if "pickle" in str(exc) \
            else str(exc).split("\n")[0]
        raise ValueError(f"{what} {path}: not a numeric .npy array ({reason})") from None
    return arr


__all__ = ["output_path", "save_npy", "load_npy"]

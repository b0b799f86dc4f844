"""Provenance that travels: file references without the writing machine's paths, and a data
file's SHA-256.

A weights file is shipped to other machines, so what it records about where it came from (the
training data, the run directory, the parent weights) names files the way the repository does
(``data/grid-m4.h5``, ``runs/m4``) or by file name, never by an absolute path of the machine
that wrote it; the data file is identified by its SHA-256 (``data_sha256``) instead.
:func:`portable_path` makes such a reference, :func:`file_sha256` the digest.

:func:`scrub` rewrites an existing native weights file whose metadata holds absolute paths
(``tpnet scrub-provenance SRC DST``): every absolute path in its root attributes (also inside
their JSON: the chain of training runs) becomes :func:`portable_path` of it, the parameters,
config, unit order and masks are written back unchanged (checked bit for bit before the file
replaces ``DST``) and the file gets its content digest (:mod:`tpnet_ref.weights.native`).
"""
from __future__ import annotations

import hashlib
import os
import re
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from . import native

#: an absolute POSIX path of at least two components (``/x/y/runs/m4``), or a Windows one
#: (``C:\\Users\\...``), standing on its own in a text (not the tail of a URL or relative path)
ABSOLUTE_PATH = re.compile(r"(?<![\w.~/:-])/(?:[\w.+@-]+/)+[\w.+@-]*|\b[A-Za-z]:\\[^\s\"',;]+")


#: the repository's folders a recorded path may start from (``data/``: datasets, ``runs/``:
#: training runs, ``weights/``: weights files), wherever the checkout lies
LAYOUT = ("data", "runs", "weights")


def _checkout_root() -> Path | None:
    """The repository checkout this package runs from, or None (an installed wheel)."""
    root = Path(native.__file__).resolve().parent.parent
    return root if (root / "pyproject.toml").is_file() else None


Roots = "str | os.PathLike | list[str | os.PathLike] | tuple[str | os.PathLike, ...] | None"


def portable_path(path: str | os.PathLike, root: Roots = None) -> str:
    """A reference to ``path`` that names no machine: relative to the first of ``root`` (a
    folder or a list of them; default: the repository checkout) that holds it; else from its
    first folder named like one of the repository's (:data:`LAYOUT`: ``/x/y/runs/m4`` ->
    ``runs/m4``); else its file name. A relative path stays as it is unless it climbs out
    (``..``), which gives the file name."""
    s = str(path)
    if not s:
        return s
    p = Path(s).expanduser()
    if not p.is_absolute() and not re.match(r"^[A-Za-z]:\\", s):
        if ".." not in p.parts:
            return p.as_posix()
        p = Path.cwd() / p
    if re.match(r"^[A-Za-z]:\\", s):
        return s.replace("\\", "/").rstrip("/").rsplit("/", 1)[-1]
    p = Path(os.path.normpath(p))
    if root is None:
        bases = [b for b in (_checkout_root(),) if b]
    else:
        bases = [Path(r) for r in ([root] if isinstance(root, (str, os.PathLike)) else root)]
    for base in bases:
        b = Path(os.path.normpath(Path(base).resolve()))
        if len(b.parts) < 2:                       # never relative to "/" itself
            continue
        try:
            rel = p.relative_to(b)
        except ValueError:
            continue
        if rel.parts:
            return rel.as_posix()
    parts = p.parts[1:]
    for i, part in enumerate(parts[:-1]):
        if part in LAYOUT:
            return "/".join(parts[i:])
    return p.name


def file_sha256(path: str | os.PathLike, chunk: int = 1 << 22) -> str:
    """``sha256:<hex>`` of a file's bytes (read in chunks)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while True:
            b = fh.read(chunk)
            if not b:
                break
            h.update(b)
    return "sha256:" + h.hexdigest()


def absolute_paths(text: str) -> list[str]:
    """Every absolute path in ``text`` (:data:`ABSOLUTE_PATH`)."""
    return ABSOLUTE_PATH.findall(text)


def scrub_text(text: str, root: Roots = None) -> str:
    """``text`` with every absolute path replaced by :func:`portable_path` of it (JSON inside
    stays valid: a path holds no quote or backslash once rewritten)."""
    return ABSOLUTE_PATH.sub(lambda m: portable_path(m.group(0), root), text)


def _same_arrays(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> bool:
    return a.keys() == b.keys() and all(
        a[k].dtype == b[k].dtype and a[k].shape == b[k].shape
        and np.ascontiguousarray(a[k]).tobytes() == np.ascontiguousarray(b[k]).tobytes() for k in a)


def scrub(src: str | os.PathLike, dst: str | os.PathLike, data: str | os.PathLike | None = None,
          root: Roots = None) -> dict[str, Any]:
    """Rewrite the native weights file ``src`` as ``dst`` (may be ``src``) with every absolute
    path in its root attributes made portable (:func:`scrub_text` with ``root``), ``data_sha256`` set to the
    SHA-256 of ``data`` when given, the same storage (a rounded file's note kept), ``created``,
    config, parameters, unit order and masks, and a content digest. The new file is checked to
    hold the same config and bit-identical arrays before it replaces ``dst``.

    Returns ``{"changed": {attribute: (before, after)}, "digest": ..., "arrays": n,
    "values": n}``."""
    src, dst = Path(src), Path(dst)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", native.UnverifiedFileWarning)   # what it is here for
        cfg, params, meta = native.read_native(src)
    groups = native.extra_groups(src)
    new = {k: scrub_text(v, root) if isinstance(v, str) else v for k, v in meta.items()
           if k not in ("path", native.DIGEST_ATTR)}
    if data is not None:
        new["data_sha256"] = file_sha256(data)
    tmp = dst.with_name(dst.name + ".scrub.tmp")
    try:
        native.write_replacing(tmp, cfg, params, new, groups, storage=new.get("storage"),
                               rounding_note=new.get("storage_rounding"))
        cfg2, params2, meta2 = native.read_native(tmp)
        groups2 = native.extra_groups(tmp)
        same = (cfg2 == cfg and _same_arrays(params, params2) and groups.keys() == groups2.keys()
                and all(_same_arrays(groups[g][1], groups2[g][1]) for g in groups))
        if not same:
            raise ValueError(f"{src}: the rewritten file does not hold the same parameters, unit "
                             "order and masks; nothing written")
        os.replace(tmp, dst)
    finally:
        if tmp.exists():
            tmp.unlink()
    kept = {k: v for k, v in meta2.items() if k not in ("path", native.DIGEST_ATTR)}
    old = {k: v for k, v in meta.items() if k not in ("path", native.DIGEST_ATTR)}
    changed = {k: (old.get(k), kept.get(k)) for k in sorted(set(old) | set(kept))
               if old.get(k) != kept.get(k)}
    return {"changed": changed, "digest": meta2[native.DIGEST_ATTR], "arrays":
            len(params) + sum(len(a) for _, a in groups.values()),
            "values": sum(int(a.size) for a in params.values())}


__all__ = ["ABSOLUTE_PATH", "LAYOUT", "portable_path", "file_sha256", "absolute_paths", "scrub_text",
           "scrub"]

"""The shipped models and where to find them, and the package data that carries them.

Shipped models (``weights/MODEL_CARD.md``): ``tpnet-m{3,4,5}.h5`` (the paper's network size) and
the reduced sizes ``tpnet-m4-{size}.h5`` (the same architecture at smaller widths, for lower
latency), looked up by :func:`shipped_weights_path` in ``$TPNET_WEIGHTS_DIR``, then in the
installed wheel (this folder, which carries the m = 4 files only), then in the repository
checkout's ``weights/``. ``tpnet-m3.h5`` and ``tpnet-m5.h5`` are not tracked in git (the tracked
tree must leave room for a checkpoint on a GPU machine, ``weights/README.md``):
``tools/restore_weights.sh`` puts them back, bit-identical, from the repository's history.

Package data: the m = 4 weights (links to weights/ in the repository; the files themselves
inside a built wheel) and an example window to start from, ``example_window.npy``:
``tpnet_ref.sim.simulate(1.3, 225.0, 28.6, 32.5)[0:16:4]``, a scene of the training grid (force
1.3, angle 225 degrees, start (28.6, 32.5); not a held-out test case), rows 0, 4, 8, 12:
``(4, 30, 2)`` float64, world units (``tests/test_weights_shipped.py`` checks it against the
simulator).
"""
from __future__ import annotations

import os
from pathlib import Path

SHIPPED_DIR = Path(__file__).resolve().parent               # inside an installed wheel
REPO_WEIGHTS_DIR = SHIPPED_DIR.parents[2] / "weights"        # in a repository checkout
SHIPPED_M = (3, 4, 5)
#: the network sizes shipped besides the paper's (``full``), m = 4 only: ``tpnet-m4-{size}.h5``
SHIPPED_SIZES = ("half", "quarter")
#: the shipped files that git does not track, and the command that restores them
UNTRACKED = {"tpnet-m3.h5", "tpnet-m5.h5"}
RESTORE_COMMAND = "bash tools/restore_weights.sh"


def weights_dir() -> Path:
    """Where the default model is read from: ``$TPNET_WEIGHTS_DIR``, else the installed wheel's
    ``tpnet_ref/weights/shipped/`` if it exists, else the repository's ``weights/``."""
    env = os.environ.get("TPNET_WEIGHTS_DIR")
    if env:
        return Path(env)
    return SHIPPED_DIR if SHIPPED_DIR.is_dir() else REPO_WEIGHTS_DIR


def shipped_weights_path(m: int = 4, size: str = "full") -> Path:
    """The shipped model for windows of ``m`` frames, ``tpnet-m{m}.h5`` (m = 4 is the default
    model; m = 3 and 5 are fine-tuned from it, ``weights/MODEL_CARD.md``), or at a reduced
    network ``size`` (:data:`SHIPPED_SIZES`, m = 4 only), ``tpnet-m4-{size}.h5``.

    Looked up in ``$TPNET_WEIGHTS_DIR`` when set (and only there), else in the installed wheel's
    ``tpnet_ref/weights/shipped/``, else in the repository's ``weights/``. Raises a one-line
    ``FileNotFoundError`` when the file is in none of them (a wheel carries m = 4 only; a
    checkout without m = 3 and 5 is told the command that restores them).
    """
    if m not in SHIPPED_M:
        raise ValueError(f"no model is shipped for m={m!r}: there are m = 3, 4 and 5")
    if size != "full" and size not in SHIPPED_SIZES:
        raise ValueError(f"no model is shipped at size={size!r}: there are 'full' and "
                         + ", ".join(repr(s) for s in SHIPPED_SIZES))
    if size != "full" and m != 4:
        raise ValueError(f"the reduced sizes are shipped for m = 4 only, got m={m!r}")
    name = f"tpnet-m{m}.h5" if size == "full" else f"tpnet-m{m}-{size}.h5"
    env = os.environ.get("TPNET_WEIGHTS_DIR")
    places = [Path(env)] if env else [SHIPPED_DIR, REPO_WEIGHTS_DIR]
    for d in places:
        if (d / name).is_file():
            return d / name
    looked = " or ".join(str(d) for d in places)
    hint = (f" (git does not track it: `{RESTORE_COMMAND}` in the repository restores it)"
            if name in UNTRACKED else "")
    raise FileNotFoundError(f"no shipped weights {name} in {looked}{hint}: pass the path of a "
                            f"weights file, or set TPNET_WEIGHTS_DIR to a folder that holds {name}")


def default_weights_path() -> Path:
    """The file ``tpnet_ref.load()`` reads when called without a path (the m = 4 model)."""
    return shipped_weights_path(4)


__all__ = ["weights_dir", "shipped_weights_path", "default_weights_path", "SHIPPED_M",
           "SHIPPED_SIZES", "UNTRACKED", "RESTORE_COMMAND"]

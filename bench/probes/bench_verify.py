"""What checking a weights file's content digest costs at load (docs/weights.md, "Integrity").

    PYTHONPATH=bench python bench/probes/bench_verify.py [WEIGHTS.h5 ...]     # default: the shipped m = 4 file and the
                                                      # half and quarter sizes

For each file: the median time of ``tpnet_ref.load`` (read, digest check, model build), of
``read_native`` alone, and of the digest computation alone on arrays already read (what
verifying adds), alternating call by call.
"""
from __future__ import annotations

import sys
import warnings

import h5py

import _common
import tpnet_ref
from tpnet_ref.weights import native
from tpnet_ref.weights.shipped import shipped_weights_path


def main(argv: list[str]) -> int:
    files = argv or [str(shipped_weights_path(4, s)) for s in ("full", "half", "quarter")]
    print(_common.machine())
    print(_common.load_average())
    warnings.simplefilter("ignore", native.UnverifiedFileWarning)
    for path in files:
        _, params, meta = native.read_native(path)
        has = native.DIGEST_ATTR in meta

        def digest(_):
            with h5py.File(path, "r") as f:
                native.content_digest(f, path, params)

        t = _common.alternate({"load": lambda _: tpnet_ref.load(path),
                               "read_native": lambda _: native.read_native(path),
                               "digest": digest}, [None], reps=15)
        mb = sum(a.nbytes for a in params.values()) / 1e6
        print(f"{path}: {mb:.1f} MB of parameters; load {t['load'] * 1e3:.1f} ms, read_native "
              f"{t['read_native'] * 1e3:.1f} ms, of which the digest {t['digest'] * 1e3:.1f} ms"
              + ("" if has else " (the file has no digest: read_native skips it)"))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

"""How does OpenVINO run the exported ONNX file: at which precision, how close, how fast?

    python bench/probes/openvino_runtime.py [--seconds 2]     # pip install -e '.[openvino,sim]'

Exports the shipped m = 4 model (``tpnet_ref.conformance.onnx_peer.export_onnx``), compiles it for OpenVINO's
CPU device twice -- its default settings and ``INFERENCE_PRECISION_HINT: f32`` -- and prints each
one's inference precision, its largest distance to ``predict_batch`` (NumPy engine, float32) on
256 windows of the held-out test cases (world units), and, interleaved round by round with
tpnet_ref's default engine, B = 1 latency and B = 256 throughput (docs/deployment.md, "OpenVINO").
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

import tpnet_ref
from tpnet_ref.conformance.onnx_peer import export_onnx


def _windows(model):
    from tpnet_ref.sim.protocol import FRAME_EVERY
    from tpnet_ref.sim.cases import TEST_CASES
    from tpnet_ref.sim.scene import simulate
    wins = []
    for case in TEST_CASES[:8]:
        traj = simulate(*case)[::FRAME_EVERY]
        starts = np.linspace(0, len(traj) - 4, 32).astype(int)
        wins.append(np.stack([traj[s:s + 4] for s in starts]))
    return np.concatenate(wins).astype(np.float32)


def _median_time(fn, seconds: float, reps: int = 5) -> float:
    fn()
    times, start = [], time.perf_counter()
    while len(times) < reps or time.perf_counter() - start < seconds:
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=2.0, help="timing block per peer and round")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved timing rounds")
    args = ap.parse_args()
    import openvino as ov
    warnings.simplefilter("ignore", tpnet_ref.checks.OutsideTrainingRangeWarning)
    ref = tpnet_ref.load(engine="numpy")
    default = tpnet_ref.load()                                  # numba where installed
    x256 = _windows(ref)
    x1 = x256[:1]
    want = ref.predict_batch(x256)
    core = ov.Core()
    cpu = core.get_property("CPU", "FULL_DEVICE_NAME")
    print(f"OpenVINO {ov.get_version()} on {cpu}; load average "
          + " ".join(f"{v:.2f}" for v in os.getloadavg()))
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "tpnet.onnx"
        export_onnx(ref, path)
        compiled = {
            "default": core.compile_model(str(path), "CPU"),
            "f32 hint": core.compile_model(str(path), "CPU", {"INFERENCE_PRECISION_HINT": "f32"})}
        for name, c in compiled.items():
            got = c({"window": x256})[c.output(0)]
            print(f"  OpenVINO {name:9s} inference precision {c.get_property('INFERENCE_PRECISION_HINT')}"
                  f", max |OpenVINO - predict_batch| = {np.abs(got - want).max():.3g} world units")
        ov32 = compiled["f32 hint"]
        req1, req256 = ov32.create_infer_request(), ov32.create_infer_request()
        peers = {"OpenVINO f32": (lambda: req1.infer({"window": x1}),
                                  lambda: req256.infer({"window": x256})),
                 f"tpnet_ref ({default.engine})": (lambda: default.predict_batch(x1),
                                                   lambda: default.predict_batch(x256))}
        res: dict = {k: ([], []) for k in peers}
        for _ in range(args.rounds):
            for k, (one, many) in peers.items():
                res[k][0].append(_median_time(one, args.seconds / 2, 20))
                res[k][1].append(_median_time(many, args.seconds / 2, 3))
        for k, (b1, b256) in res.items():
            print(f"  {k:22s} B = 1 {np.median(b1) * 1e3:6.2f} ms   B = 256 "
                  f"{256 / np.median(b256):7.0f} windows/s   (medians of {args.rounds} rounds)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

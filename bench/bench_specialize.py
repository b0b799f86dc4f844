"""The scene-specialised model against the full one: exactness, fallbacks, B = 1 speed.

    python bench/bench_specialize.py            # 36 training-grid trajectories to calibrate
    python bench/bench_specialize.py --quick    # 12

Calibrates the shipped m = 4 model on windows of simulated training-grid trajectories (every
window, plus the windows of the model's own 40-frame rollouts from them; never the test cases),
then checks on the 60 test cases (their simulated windows and the model's own rollout windows,
in batches and one window at a time) and on inputs built to trip every guard: max |specialised -
full| in world units (target <= 1e-4) and the fraction of windows that fall back to the full
network. Then, on 64 test windows, interleaved, medians: B = 1 latency of ``predict`` of both
(target: specialised >= 2x faster), of the prediction network alone on the same features, and
where one specialised prediction spends its time (the feature extractor is the full model's).
"""
from __future__ import annotations

import argparse
import sys
import time
import warnings

import numpy as np

import tpnet_ref
from tpnet_ref.sim import dataset as D
from tpnet_ref.engines import specialised as S
from tpnet_ref.model import ENGINE_MAX_BATCH
from tpnet_ref.sim.protocol import FRAME_EVERY
from tpnet_ref.sim.cases import TEST_CASES
from tpnet_ref.sim.scene import simulate


def windows(frames: np.ndarray, m: int) -> np.ndarray:
    return np.stack([frames[s:s + m] for s in range(len(frames) - m + 1)])


def parse_quick(doc: str, argv: list[str] | None) -> bool:
    """The calibration benches' one option, ``--quick`` (12 trajectories instead of 36); also
    silences warnings."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    quick = ap.parse_args(argv).quick
    warnings.simplefilter("ignore")
    return quick


def main(argv: list[str] | None = None) -> int:
    quick = parse_quick(__doc__, argv)
    n_cal = 12 if quick else 36
    full = tpnet_ref.load(engine="numpy")
    m = full.config.m
    t0 = time.perf_counter()
    cal = D.calibration_windows(full, n_cal, seed=0, rollout=40)
    spec = full.specialize(cal)
    print(f"calibrated on {len(cal)} windows of {n_cal} training-grid trajectories "
          f"({time.perf_counter() - t0:.0f} s): units used "
          + ", ".join(f"{k} {a}/{b}" for k, (a, b) in S.fraction_used(spec.specialization.used).items())
          + f"; head parameters read {spec.specialization.num_params():,} of {full.num_params:,}")

    test = [simulate(*c)[::FRAME_EVERY] for c in TEST_CASES]
    sim_w = np.concatenate([windows(t, m) for t in test])
    roll_w = np.concatenate([windows(np.concatenate([t[:m], full.rollout(t[:m], 80)]), m)
                             for t in test])
    rng = np.random.default_rng(1)
    centre = sim_w[:200].mean(axis=2, keepdims=True)
    trips = {"random points": rng.uniform(0, 45, (200, m, 30, 2)),
             "ring far outside the box": sim_w[:200] + 300.0,
             "tiny ring (x0.01)": centre + (sim_w[:200] - centre) * 0.01,
             "huge ring (x10)": centre + (sim_w[:200] - centre) * 10}
    print(f"\n{'windows':36s} {'count':>6s} {'max |spec - full| (world)':>26s} {'fallback':>9s}")
    worst = 0.0
    fallback = {}
    for name, w in [("test cases, simulated", sim_w), ("test cases, model's own rollout", roll_w),
                    *trips.items()]:
        spec.counts.update(windows=0, fallbacks=0)
        d = float(np.abs(spec.predict_batch(w) - full.predict_batch(w)).max())
        worst = max(worst, d)
        fallback[name] = spec.counts["fallbacks"] / spec.counts["windows"]
        print(f"{name:36s} {len(w):6d} {d:26.2e} {fallback[name]:9.2%}")

    # one window at a time (the specialised head's own path for B = 1) on part of them
    sub = sim_w[np.random.default_rng(3).choice(len(sim_w), 300, replace=False)]
    spec.counts.update(windows=0, fallbacks=0)
    d = max(float(np.abs(spec.predict(w) - full.predict(w)).max()) for w in sub)
    worst = max(worst, d)
    print(f"{'test cases, simulated, one at a time':36s} {len(sub):6d} {d:26.2e} "
          f"{spec.counts['fallbacks'] / spec.counts['windows']:9.2%}")

    # B = 1 latency on the scene's windows, medians of 5 rounds of 64 windows. In runs: each round
    # runs each of them on the 64 windows in turn (its weights as warm as its own working set
    # allows, as in use); alternating: full and specialised on each window in turn (each evicts
    # the other's weights from the cache)
    sample = sim_w[np.random.default_rng(2).choice(len(sim_w), 64, replace=False)]
    feats = [full.window_features(np.asarray(w)[None]) for w in sample]
    jobs = {"full": lambda i: full.predict(sample[i]), "spec": lambda i: spec.predict(sample[i]),
            "full head": lambda i: full.sequence_head(feats[i]),
            "spec head": lambda i: spec.sequence_head(feats[i]),
            "features": lambda i: full.window_features(np.asarray(sample[i])[None])}
    t: dict[str, list[float]] = {k: [] for k in (*jobs, "full alt", "spec alt")}
    stages: dict[str, list[float]] = {}
    clock = time.perf_counter
    rounds: dict[str, list[float]] = {k: [] for k in t}      # each round's median
    for rep in range(5 if quick else 15):
        for name, job in jobs.items():
            for i in range(len(sample)):
                t0 = clock()
                job(i)
                t[name].append(clock() - t0)
            rounds[name].append(float(np.median(t[name][-len(sample):])))
        for f in feats:
            marks: list = []
            t0 = clock()
            spec.specialization(f, marks)
            for label, tm in marks:
                stages.setdefault(label, []).append(tm - t0)
                t0 = tm
        for w in sample:
            t0 = clock()
            full.predict(w)
            t1 = clock()
            spec.predict(w)
            t["full alt"].append(t1 - t0)
            t["spec alt"].append(clock() - t1)
        for k in ("full alt", "spec alt"):
            rounds[k].append(float(np.median(t[k][-len(sample):])))
    ms = {k: 1e3 * float(np.median(v)) for k, v in t.items()}

    def speedup(a: str, b: str) -> float:
        """Median over the rounds of a round's median of ``a`` over its median of ``b`` (the
        machine's load drifts between rounds, much less within one)."""
        return float(np.median(np.array(rounds[a]) / np.array(rounds[b])))
    f_ms, s_ms, gain = ms["full"], ms["spec"], speedup("full", "spec")
    print(f"\nB = 1 latency on test-case windows: full {f_ms:.3f} ms, specialised {s_ms:.3f} ms "
          f"({gain:.2f}x, median of {len(rounds['full'])} rounds; each in runs of 64 windows)")
    print(f"  alternating window by window: full {ms['full alt']:.3f} ms, specialised "
          f"{ms['spec alt']:.3f} ms ({speedup('full alt', 'spec alt'):.2f}x)")
    print(f"  prediction network alone, same features: full {ms['full head']:.3f} ms, "
          f"specialised {ms['spec head']:.3f} ms ({speedup('full head', 'spec head'):.2f}x); "
          f"feature extractor (shared) {ms['features']:.3f} ms")
    try:                 # the optional engine: its full network against the NumPy models
        nb = full.with_engine("numba")
        nb_spec = spec.with_engine("numba")
    except ImportError as exc:
        print(f"  engine=numba: skipped ({exc})")
    else:
        nb.predict(sample[0])
        nb_spec.predict(sample[0])
        nbr: dict[str, list[float]] = {"full": [], "nb": [], "nb spec": []}
        for _ in range(5 if quick else 15):
            for k, model in (("full", full), ("nb", nb), ("nb spec", nb_spec)):
                ts = []
                for w in sample:
                    t0 = clock()
                    model.predict(w)
                    ts.append(clock() - t0)
                nbr[k].append(float(np.median(ts)))
        print(f"  engine=numba, same rounds: full {1e3 * np.median(nbr['nb']):.3f} ms "
              f"({np.median(np.array(nbr['full']) / np.array(nbr['nb'])):.2f}x faster than the NumPy "
              f"full model), specialised {1e3 * np.median(nbr['nb spec']):.3f} ms (its batches up to "
              f"{ENGINE_MAX_BATCH} run the engine's own full network, which skips zero rows itself)")
    print("  where the specialised prediction network's time goes (medians, one window):")
    med = {label: 1e6 * float(np.median(v)) for label, v in stages.items()}
    for label, us in med.items():
        print(f"    {label:44s} {us:7.0f} us  {us / sum(med.values()):6.1%}")
    print("\ntargets:")
    for label, val, ok in [("max |specialised - full|, world units (target <= 1e-4)", worst,
                            worst <= 1e-4),
                           ("B = 1 speed-up over the full model (target >= 2)", gain,
                            gain >= 2.0),
                           ("fallback fraction, simulated test windows (reported)",
                            fallback["test cases, simulated"], None)]:
        print(f"  {label:58s} {val:10.3g}  {'' if ok is None else ('MET' if ok else 'NOT MET')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

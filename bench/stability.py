"""Stability figures for docs/stability.md (stiff springs, extreme impulses, long runs).

    PYTHONPATH=. python bench/stability.py          # Box2D / naive rows when importable
    PYTHONPATH=. python bench/stability.py --spin   # only the spinning-particles table

    PYTHONPATH=. python bench/stability.py --long   # only the first-step and long-run tables
    PYTHONPATH=. python bench/stability.py --first-step   # only the first-step table
    PYTHONPATH=. python bench/stability.py --3d     # only the 3-D scene's tables (sim3d extra)

Energies: E_motion = kinetic (linear + rotational) + gravitational, E_total adds the springs'
potential energy as ideal springs of stiffness mu (2 pi f)^2. Positions in world units; the free
area is [1, 44]^2 and Box2D's continuous collision keeps centres at >= 0.145 from a wall.

E0 is the energy after the first step, in every table. With the start impulse at the ring centre
(the default) the built state holds each particle's unclamped spin (up to ~3,300 rad/s, about
99 % of the energy at F = 1.6); Box2D's rotation clamp (pi/2 per step) removes it in the first
step's solve, before any position update, so that energy never takes part in the motion. The
long-run table prints that first-step ratio E0 / E_built separately.
"""
from __future__ import annotations

import importlib.util
import math
import sys
import time

import numpy as np

from tpnet_ref.sim import SceneParams, build_scene, spring_pairs

PAIRS = spring_pairs()


def run(force, angle, x, y, steps, **kw):
    """Row k of (traj, em, et) is the state after k steps (row 0: as built, before the first
    step's rotation clamp)."""
    p = SceneParams(**kw)
    sc = build_scene(x, y, force, angle, p)
    traj = np.empty((steps, 30, 2))
    em = np.empty(steps)
    et = np.empty(steps)
    for k in range(steps):
        b = sc.read()
        traj[k] = b[:30, :2]
        em[k] = sc.energy(springs=False)
        et[k] = sc.energy()
        if k + 1 < steps:
            sc.step()
    return traj, em, et


def stretch(traj):
    L = np.linalg.norm(traj[:, PAIRS[:, 1]] - traj[:, PAIRS[:, 0]], axis=2)
    return np.abs(L - L[0]).max()


def spin_table() -> None:
    """Particles spinning at the rotation clamp (released start impulse, every particle at
    pi/2 per step) against walls with friction 1: 3,000 steps per case."""
    print("## spinning particles: impulse at the ring centre, 3,000 steps, sleep off")
    print("| case | finite | min / max centre | max abs(w) dt / (pi/2) | max E_total / E0 | "
          "E_total end / E0 | spinning particles at the end |")
    print("|" + "---|" * 7)
    limit = 0.5 * math.pi
    for name, args, kw in (("F=1.6, 200 deg, start (41.9, 41.2) (corner)",
                            (1.6, 200, 41.9, 41.2), {}),
                           ("F=1.6, 270 deg, start (41.9, 31.7) (floor)",
                            (1.6, 270, 41.9, 31.7), {}),
                           ("F=1.0, 180 deg, start (2.9, 2.9) (corner)", (1.0, 180, 2.9, 2.9), {}),
                           ("F=16, 225 deg, start (30, 30)", (16.0, 225, 30, 30), {}),
                           ("F=16, 225 deg, no rotation clamp", (16.0, 225, 30, 30),
                            {"max_rotation": None}),
                           ("F=1.6, 225 deg, 20 Hz springs", (1.6, 225, 30, 30),
                            {"frequency": 20.0})):
        p = SceneParams(**kw)
        sc = build_scene(args[2], args[3], args[0], args[1], p)
        lo, hi, wmax = 99.0, -99.0, 0.0
        e = np.empty(3000)
        finite = True
        for k in range(3000):
            sc.step()
            b = sc.read()
            e[k] = sc.energy(springs=p.frequency <= 1.0)   # stiff: E_motion, as above
            finite &= bool(np.isfinite(b[:30]).all())
            lo, hi = min(lo, b[:30, :2].min()), max(hi, b[:30, :2].max())
            wmax = max(wmax, np.abs(b[:30, 4]).max() * p.dt / limit)
        spinning = int((np.abs(b[:30, 4]) > 1.0).sum())
        print(f"| {name} | {finite} | {lo:.4f} / {hi:.4f} | {wmax:.4f} | {e.max() / e[0]:.4f} | "
              f"{e[-1] / e[0]:.4f} | {spinning} |")
    print("(w: angular velocity in rad/s, read between steps: particle-pair contacts and the "
          "walls' time of impact act after the clamp, the next step clamps again; E0: energy "
          "after the first step, with the clamped spin; 20 Hz: E_motion)")


def first_step() -> None:
    """The first step's rotation clamp: energy of the built state (unclamped start spin) and
    after one step, free flight (F 1.6, 45 deg, start (22, 22), no walls, no gravity)."""
    print("## first step, free flight: F=1.6, 45 deg, start (22, 22), no walls, no gravity")
    print("| impulse point | max abs(w) built (rad/s) | E built | of it rotational | "
          "E after step 1 | of it rotational | max abs(w) after step 1 | E after 2,001 steps |")
    print("|" + "---|" * 8)
    for ip in ("ring_centre", "particle_centre"):
        p = SceneParams(walls=False, gravity=(0.0, 0.0), impulse_point=ip)
        sc = build_scene(22.0, 22.0, 1.6, 45.0, p)
        rows = []
        for k in range(2002):
            if k:
                sc.step()
            b = sc.read()
            if k in (0, 1, 2001):
                w = b[:30, 4]
                rows.append((np.abs(w).max(), sc.energy(), 0.5 * p.inertia * float((w ** 2).sum())))
        (w0, e0, r0), (w1, e1, r1), (_, e2, _) = rows
        print(f"| {ip} | {w0:.1f} | {e0:.1f} | {r0:.1f} | {e1:.1f} | {r1:.1f} | {w1:.2f} | "
              f"{e2:.1f} |")


def long_table() -> None:
    """Long runs with damping ratio 0: 10,000 steps each."""
    print("## long runs: 10,000 steps, damping ratio 0, sleep off (E0: after the first step)")
    print("| case | max E / E0 | largest one-step rise of E / E0 | E end / E0 | "
          "E0 / E_built (first step's rotation clamp) | min / max centre |")
    print("|" + "---|" * 6)
    for name, kw, args in (("1 Hz, walls, F=1.6", {}, (1.6, 225, 30, 30)),
                           ("1 Hz, wall restitution 1", {"wall_restitution": 1.0},
                            (1.6, 225, 30, 30)),
                           ("20 Hz, F=16, restitution 1", {"wall_restitution": 1.0,
                                                           "frequency": 20.0},
                            (16.0, 225, 30, 30)),
                           ("1 Hz, no walls, no gravity", {"walls": False,
                                                           "gravity": (0.0, 0.0)},
                            (1.6, 45, 22, 22)),
                           ("1 Hz, no walls, no gravity, impulse at particle centres",
                            {"walls": False, "gravity": (0.0, 0.0),
                             "impulse_point": "particle_centre"}, (1.6, 45, 22, 22))):
        tr, em, et = run(*args, 10_001, sleep=False, **kw)
        e = et if kw.get("frequency", 1.0) <= 1.0 else em
        tag = " (E_total)" if e is et else " (E_motion)"
        e0 = e[1]
        print(f"| {name}{tag} | {e[1:].max() / e0:.6f} | {np.diff(e[1:]).max() / e0:.2e} | "
              f"{e[-1] / e0:.4f} | {e0 / e[0]:.4f} | {tr[1:].min():.3f} / {tr[1:].max():.3f} |")


def tables_3d() -> None:
    """The 3-D scene (tpnet_ref.sim.scene3d): stiff springs, extreme throws, refused cases."""
    from tpnet_ref.sim import scene3d as s3

    cp = s3.contact_pairs3d()

    def throw(*case, steps=600, **kw):
        p = s3.SceneParams3D(**kw)
        sc = s3.build_scene3d(*case, p)
        t = time.perf_counter()
        tr = np.empty((steps, sc.n, 3))
        e = np.empty(steps)
        for k in range(steps):
            sc.step()
            tr[k] = sc.positions()
            e[k] = sc.energy()
        length = np.linalg.norm(tr[:, sc.pairs[:, 1]] - tr[:, sc.pairs[:, 0]], axis=2)
        gap = np.linalg.norm(tr[:, cp[:, 0]] - tr[:, cp[:, 1]], axis=2).min()
        return (tr, e, (np.abs(length - sc.rest) / sc.rest).max(), gap, sc.substeps,
                time.perf_counter() - t)

    print("## 3-D: stiff springs: F=1.6, azimuth 225, elevation -35, start (35, 35, 35), "
          "600 steps")
    print("| f (Hz) | omega_max dt (stiffest mode) | substeps | finite | min centre | "
          "max centre | max abs(L-L0)/L0 | max E / E0 | E end / E0 | s |")
    print("|" + "---|" * 10)
    for f in (1.0, 2.0, 4.0, 8.0, 16.0, 64.0):
        tr, e, st, _, n, sec = throw(1.6, 225.0, -35.0, 35.0, 35.0, 35.0, frequency=f)
        w = s3.omega_max(s3.SceneParams3D(frequency=f))
        print(f"| {f:g} | {w / 45:.2f} | {n} | {np.isfinite(tr).all()} | {tr.min():.4f} | "
              f"{tr.max():.4f} | {st:.3f} | {e.max() / e[0]:.4f} | {e[-1] / e[0]:.4f} | "
              f"{sec:.1f} |")
    print()
    print("## 3-D: extreme throws: 8 directions (azimuth 0, 90, 180, 270 at elevation 0; "
          "45 and 225 at +-35), starts (41, 41, 41) and (4, 4, 4), 600 steps")
    print("| force | f (Hz) | substeps | finite | min centre | max centre | max speed (units/s) "
          "| min gap of unsprung pairs | s per throw |")
    print("|" + "---|" * 9)
    dirs = [(0, 0), (90, 0), (180, 0), (270, 0), (45, 35), (45, -35), (225, 35), (225, -35)]
    for force, f in ((1.6, 1.0), (4.0, 1.0), (8.0, 1.0), (16.0, 1.0), (16.0, 8.0)):
        lo, hi, vmax, gmin, fin, secs = 99.0, -99.0, 0.0, 99.0, True, []
        for az, el in dirs:
            for c in ((41.0, 41.0, 41.0), (4.0, 4.0, 4.0)):
                tr, _, _, gap, n, sec = throw(force, az, el, *c, frequency=f)
                fin &= bool(np.isfinite(tr).all())
                lo, hi, gmin = min(lo, tr.min()), max(hi, tr.max()), min(gmin, gap)
                vmax = max(vmax, 45 * np.linalg.norm(np.diff(tr, axis=0), axis=2).max())
                secs.append(sec)
        print(f"| {force:g} | {f:g} | {n} | {fin} | {lo:.4f} | {hi:.4f} | {vmax:.1f} | "
              f"{gmin:.3f} | {np.mean(secs):.1f} |")
    print()
    print("## 3-D: at and beyond the substep limit (2,000 per step): 45 rows, or the one-line "
          "error")
    for kw, force in (({"frequency": 1000.0}, 1.6), ({}, 300.0), ({"frequency": 5000.0}, 1.6),
                      ({}, 1000.0), ({}, float("nan"))):
        name = f"force {force:g}" + "".join(f", {k} {v:g}" for k, v in kw.items())
        try:
            tr, _, _, _, n, sec = throw(force, 225.0, -35.0, 35.0, 35.0, 35.0, steps=45, **kw)
            print(f"- {name}: {n} substeps, finite {np.isfinite(tr).all()}, min / max centre "
                  f"{tr.min():.4f} / {tr.max():.4f}, {sec:.1f} s")
        except ValueError as exc:
            print(f"- {name}: ValueError: {exc}")


def main() -> int:
    if "--3d" in sys.argv[1:]:
        tables_3d()
        return 0
    if "--spin" in sys.argv[1:]:
        spin_table()
        return 0
    if "--long" in sys.argv[1:]:
        first_step()
        print()
        long_table()
        return 0
    if "--first-step" in sys.argv[1:]:
        first_step()
        return 0
    from compare_box2d import simulate_naive          # the plain pymunk port
    from tpnet_ref.sim import box2d                   # Box2D itself: the box2d extra
    simulate_box2d = box2d.simulate_box2d if importlib.util.find_spec("Box2D") else None
    print("## stiff springs: F=1.6, 225 deg, start (30, 30), 600 steps, sleep off "
          "(E0: after the first step)")
    print("| f (Hz) | omega dt | finite | min centre | max centre | max abs(L-L0) | "
          "Box2D max abs(L-L0) | max E_motion / E0 | max E_total / E0 | naive pymunk | ms |")
    print("|" + "---|" * 11)
    for f in (1, 2, 5, 20, 100, 1000):
        t = time.perf_counter()
        tr, em, et = run(1.6, 225, 30, 30, 600, frequency=f, sleep=False)
        ms = 1e3 * (time.perf_counter() - t)
        b2 = f"{stretch(simulate_box2d(1.6, 225, 30, 30, 600, frequency=f)):.3f}" \
            if simulate_box2d else "n/a"
        nv = "n/a"
        if simulate_naive:
            with np.errstate(all="ignore"):
                nt = simulate_naive(1.6, 225, 30, 30, 600, frequency=f)
            ok = np.isfinite(nt).all() and nt.min() > 0 and nt.max() < 45
            nv = f"max abs(L-L0) {stretch(nt):.3g}" if ok else "blows up / leaves box"
        print(f"| {f} | {2 * math.pi * f / 45:.2f} | {np.isfinite(tr).all()} | {tr.min():.4f} | "
              f"{tr.max():.4f} | {stretch(tr):.3f} | {b2} | {em[1:].max() / em[1]:.4f} | "
              f"{et[1:].max() / et[1]:.4g} | {nv} | {ms:.0f} |")
    print()
    print("## impulses: 8 directions, start (41, 41) and (4, 4), 600 steps")
    print("| force | clamp (Box2D max translation 2/step) | min centre | max centre | "
          "max speed (units/s) |")
    print("|" + "---|" * 5)
    for force in (1.6, 4.0, 8.0, 16.0, 160.0):
        for clamp in (2.0, None):
            lo, hi, vmax = 99.0, -99.0, 0.0
            for a in range(0, 360, 45):
                for x, y in ((41.0, 41.0), (4.0, 4.0)):
                    tr, _, _ = run(force, a, x, y, 600, max_translation=clamp)
                    lo, hi = min(lo, tr[1:].min()), max(hi, tr[1:].max())
                    vmax = max(vmax, 45 * np.linalg.norm(np.diff(tr, axis=0), axis=2).max())
            print(f"| {force} | {clamp} | {lo:.4f} | {hi:.4f} | {vmax:.1f} |")
    lo, hi = 99.0, -99.0
    for a in range(0, 360, 45):
        for x, y in ((41.0, 41.0), (4.0, 4.0)):
            tr, _, _ = run(16.0, a, x, y, 300, max_translation=None, continuous=False)
            lo, hi = min(lo, tr[1:].min()), max(hi, tr[1:].max())
    print(f"\nwithout continuous collision (continuous=False), force 16, no clamp: "
          f"min / max centre {lo:.2f} / {hi:.2f}")
    print()
    spin_table()
    print()
    first_step()
    print()
    long_table()
    return 0


if __name__ == "__main__":
    sys.exit(main())

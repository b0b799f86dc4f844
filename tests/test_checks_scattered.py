"""The one-body test's shortcut for scattered points (issue 47: a window of random points cost
the input checks twice a ring's): ``checks._cannot_hold_a_body`` decides in a few NumPy calls
that a frame holds no body of the scene's size, and ``window_body_problem`` says exactly what it
said without it, on rings, rings with strays, two blobs, arcs and scattered points."""
from __future__ import annotations

import numpy as np
import pytest

from tpnet_ref import checks as C


def _ring(rng, n=30, r=2.0, centre=(20.0, 20.0)):
    a = np.sort(rng.uniform(0, 2 * np.pi, n))
    return np.stack([centre[0] + r * np.cos(a), centre[1] + r * np.sin(a)], axis=1)


def _windows(seed: int):
    rng = np.random.default_rng(seed)
    c = rng.uniform(5, 40, 2)
    ring = np.stack([_ring(rng, centre=c + [0.5 * t, 0]) for t in range(4)])
    yield "ring", ring
    stray = ring.copy()
    stray[2, 5] += rng.uniform(3, 9, 2)
    yield "ring with a stray point", stray
    blob = ring.copy()
    blob[1, :12] = c + rng.uniform(6, 12, 2) + rng.normal(0, 0.4, (12, 2))
    yield "a second blob", blob
    yield "random points", rng.uniform(1, 44, (4, 30, 2))
    yield "random points, small box", rng.uniform(10, 10 + rng.uniform(5, 15), (4, 30, 2))
    half = ring.copy()
    half[:, 15:] = rng.uniform(1, 44, (4, 15, 2))
    yield "half ring, half scattered", half
    first_ok = rng.uniform(1, 44, (4, 30, 2))
    first_ok[0] = stray[2]
    yield "a stray frame, then scattered ones", first_ok
    yield "a tiny ring", ring * 0.01 + 20
    yield "few points", ring[:, :6]
    yield "ragged", [ring[0], ring[1][:20], rng.uniform(1, 44, (25, 2)), ring[3]]


@pytest.mark.parametrize("seed", range(12))
def test_the_shortcut_changes_no_answer(seed, monkeypatch):
    cases = list(_windows(seed))
    fast = [C.window_body_problem(w if isinstance(w, np.ndarray) else list(w)) for _, w in cases]
    monkeypatch.setattr(C, "_cannot_hold_a_body", lambda f: np.zeros(len(f), dtype=bool))
    slow = [C.window_body_problem(w if isinstance(w, np.ndarray) else list(w)) for _, w in cases]
    assert fast == slow, [name for (name, _), a, b in zip(cases, fast, slow) if a != b]


def test_scattered_frames_are_decided_without_the_pairwise_test(monkeypatch):
    rng = np.random.default_rng(0)
    window = rng.uniform(1, 44, (4, 30, 2))
    assert C._cannot_hold_a_body(window).all()
    assert not C._cannot_hold_a_body(np.stack([_ring(rng) for _ in range(4)])).any()

    def pairwise(*a, **k):
        raise AssertionError("body_outliers ran on a scattered window")

    monkeypatch.setattr(C, "body_outliers", pairwise)
    assert C.window_body_problem(window) is None

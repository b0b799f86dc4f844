"""Ring geometry: what the shape error E_s can reach, and how a predicted outline differs.

The body at rest is a ring of 30 particles of radius 2 world units (docs/spec.md §5); these
functions give the reference scores that make E_s readable (a perfect ring at an unknown
rotation phase, the ring collapsed to its centre) and the tools ``bench/probes/shape_floor.py`` uses
to tell an outline's error from its spacing's.
"""
from __future__ import annotations

import numpy as np

from ..config import NORM_HI, NORM_LO


def rest_ring(phases: float | np.ndarray = 0.0, n: int = 30, radius: float = 2.0) -> np.ndarray:
    """The body's undeformed ring (docs/spec.md §5: particle ``i`` at angle ``i·2π/n`` from +y towards
    +x, ``radius`` world units) in normalised units about the origin, each particle's angle
    advanced by ``phases`` (radians, scalar or ``(P,)``): ``(n, 2)`` or ``(P, n, 2)``."""
    r = radius / (NORM_HI - NORM_LO)
    a = 2 * np.pi * np.arange(n) / n + np.asarray(phases, dtype=np.float64)[..., None]
    return np.stack([r * np.sin(a), r * np.cos(a)], axis=-1)


def ring_phase_floor(n: int = 30, radius: float = 2.0, samples: int = 720,
                     variant: str = "released") -> float:
    """Shape error E_s (reading ``variant``, docs/spec.md §3) between the body's rest ring (``n`` particles, ``radius`` world
    units, normalised like the data) and the same ring rotated by a phase drawn uniformly from
    one particle spacing (``samples`` evenly spaced phases, averaged). A prediction that has the
    exact shape but not the particles' rotation phase scores this on average: copying the last
    frame scores about this once the body has turned, so beating it on E_s needs the phase or
    a nearly exact outline (``bench/probes/shape_floor.py``)."""
    from ..metrics import shape_error
    turned = rest_ring((np.arange(samples) + 0.5) / samples * (2 * np.pi / n), n, radius)
    return float(np.mean(shape_error(np.broadcast_to(rest_ring(0.0, n, radius), turned.shape),
                                     turned, variant=variant)))


def collapsed_ring_error(n: int = 30, radius: float = 2.0, variant: str = "released") -> float:
    """Shape error E_s (reading ``variant``) of the body's rest ring against ``n`` points all at
    its centre: what a prediction that keeps no shape at all scores. Squared reading:
    ``2 n r²`` (r in normalised units); paper: ``2 r²``; released: ``2 n r``."""
    from ..metrics import shape_error
    ring = rest_ring(0.0, n, radius)
    return float(shape_error(ring, np.zeros_like(ring), variant=variant))


def reading_evidence(variant: str, n: int = 30, radius: float = 2.0) -> dict[str, float]:
    """The two scene-fixed references of one metric reading (docs/spec.md §3): ``floor``, a
    perfect ring at a random rotation phase (:func:`ring_phase_floor`), and ``collapsed``, the
    ring collapsed to its centre (:func:`collapsed_ring_error`). A model's E_s that keeps the
    shape lies between them; below ``floor`` is impossible for every model, above
    ``collapsed`` is worse than no shape."""
    return {"floor": ring_phase_floor(n, radius, variant=variant),
            "collapsed": collapsed_ring_error(n, radius, variant)}


def spacing_stats(sets: np.ndarray) -> dict[str, float]:
    """How evenly a set's points cover the body, in world units, averaged over ``sets (K, N, 2)``
    (normalised coordinates): ``nn_mean`` the mean distance from a point to its nearest other
    point, ``nn_min`` the smallest such distance in a set, ``radius_std`` the spread of the
    points' distances from the set's centroid. The body's rest ring has 0.418 / 0.418 / 0.
    Points clumped in pairs (two outputs on one particle, a gap next to it) show as a small
    ``nn_min``: the Chamfer distance barely penalises it, the shape error E_s does."""
    x = np.asarray(sets, dtype=np.float64)
    if x.ndim != 3 or x.shape[1] < 2:
        raise ValueError(f"sets: expected (K, N >= 2, dim), got shape {x.shape}")
    scale = NORM_HI - NORM_LO
    d = np.linalg.norm(x[:, :, None] - x[:, None, :], axis=-1)
    d[:, np.arange(x.shape[1]), np.arange(x.shape[1])] = np.inf
    nn = d.min(axis=2)
    r = np.linalg.norm(x - x.mean(axis=1, keepdims=True), axis=-1)
    return {"nn_mean": float(nn.mean() * scale), "nn_min": float(nn.min(axis=1).mean() * scale),
            "radius_std": float(r.std(axis=1).mean() * scale)}


def resample_outline(sets: np.ndarray, offset: float | np.ndarray = 0.0) -> np.ndarray:
    """Each set's outline, resampled with its points evenly spaced along it.

    The outline is the closed polygon through the points taken in angular order about the
    centroid; point ``j`` of the result sits at arc length ``(j + offset) / N`` of its perimeter,
    starting from the point of smallest angle. ``sets (K, N, 2)``; ``offset`` a scalar or
    ``(K,)`` array, in spacings. Returns ``(K, N, 2)`` float64 (same units as ``sets``). Used to
    tell an outline's error from its spacing's: clumped points and the same outline evenly
    spaced have the same polygon."""
    x = np.asarray(sets, dtype=np.float64)
    if x.ndim != 3 or x.shape[-1] != 2 or x.shape[1] < 3:
        raise ValueError(f"sets: expected (K, N >= 3, 2), got shape {x.shape}")
    k, n = x.shape[:2]
    off = np.broadcast_to(np.asarray(offset, dtype=np.float64), (k,))
    d = x - x.mean(axis=1, keepdims=True)
    order = np.argsort(np.arctan2(d[..., 1], d[..., 0]), axis=1, kind="stable")
    q = np.take_along_axis(x, order[..., None], axis=1)
    q = np.concatenate([q, q[:, :1]], axis=1)                      # close the polygon
    s = np.concatenate([np.zeros((k, 1)),
                        np.cumsum(np.linalg.norm(np.diff(q, axis=1), axis=-1), axis=1)], axis=1)
    out = np.empty_like(x)
    for i in range(k):
        t = (np.arange(n) + off[i]) % n / n * s[i, -1]
        out[i, :, 0] = np.interp(t, s[i], q[i, :, 0])
        out[i, :, 1] = np.interp(t, s[i], q[i, :, 1])
    return out


def radial_fit(sets: np.ndarray, modes: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Each set's distance from its centroid as a Fourier series in the angle about it.

    Least-squares fit of ``r(θ) = a_0 + Σ_{k=1..modes} (a_k cos kθ + b_k sin kθ)`` to the points
    of each set. ``sets (K, N, 2)`` -> ``(coef (K, 1 + 2·modes), residual (K, N))``, coefficients
    ordered ``a_0, a_1, b_1, a_2, ...`` and the residual in the units of ``sets``. ``modes = 0``
    fits a circle (``a_0`` the mean radius); mode 2 is the ring's squash. The residual's spread
    tells a ragged outline (point to point) from a smooth deformation."""
    x = np.asarray(sets, dtype=np.float64)
    if x.ndim != 3 or x.shape[-1] != 2 or x.shape[1] < 1 + 2 * modes or modes < 0:
        raise ValueError(f"sets: expected (K, N >= {1 + 2 * max(modes, 0)}, 2) and modes >= 0, "
                         f"got shape {x.shape}, modes {modes}")
    d = x - x.mean(axis=1, keepdims=True)
    th = np.arctan2(d[..., 1], d[..., 0])
    r = np.linalg.norm(d, axis=-1)
    a = _radial_basis(th, modes)                                    # (K, N, 1 + 2·modes)
    coef = np.stack([np.linalg.lstsq(a[i], r[i], rcond=None)[0] for i in range(len(x))])
    return coef, r - np.einsum("knj,kj->kn", a, coef)


def _radial_basis(th: np.ndarray, modes: int) -> np.ndarray:
    cols = [np.ones_like(th)]
    for k in range(1, modes + 1):
        cols += [np.cos(k * th), np.sin(k * th)]
    return np.stack(cols, axis=-1)


def radial_outline(sets: np.ndarray, modes: int = 0, phase: float | np.ndarray = 0.0) -> np.ndarray:
    """Each set replaced by its smooth outline (:func:`radial_fit` with ``modes``) sampled at
    ``N`` evenly spaced angles ``phase + 2πj/N`` (radians, scalar or ``(K,)``) about the same
    centroid: ``(K, N, 2)`` float64. ``modes = 0`` gives the circle of the set's mean radius,
    the best phase-blind guess at a ring whose vibration is unknown (``bench/probes/shape_floor.py``)."""
    x = np.asarray(sets, dtype=np.float64)
    coef, _ = radial_fit(x, modes)
    k, n = x.shape[:2]
    th = np.broadcast_to(np.asarray(phase, dtype=np.float64), (k,))[:, None] \
        + 2 * np.pi * np.arange(n) / n
    r = np.einsum("knj,kj->kn", _radial_basis(th, modes), coef)
    return x.mean(axis=1, keepdims=True) + np.stack([r * np.cos(th), r * np.sin(th)], axis=-1)


def ring_rotation(frames: np.ndarray, n: int = 30) -> np.ndarray:
    """How far the body has turned since its start, in degrees (counter-clockwise positive):
    the circular mean, over the particles, of each particle's angle about the centroid minus its
    start angle (docs/spec.md §5: particle ``i`` starts at ``i·360°/n`` from +y towards +x).
    ``frames (..., n, 2)`` in the simulator's particle order -> ``(...)``."""
    x = np.asarray(frames, dtype=np.float64)
    if x.shape[-2:] != (n, 2):
        raise ValueError(f"frames: expected (..., {n}, 2) in particle order, got {x.shape}")
    d = x - x.mean(axis=-2, keepdims=True)
    ang = np.arctan2(d[..., 0], d[..., 1])            # from +y towards +x, like the start ring
    start = 2 * np.pi * np.arange(n) / n
    return -np.degrees(np.angle(np.exp(1j * (ang - start)).mean(axis=-1)))


__all__ = ["rest_ring", "ring_phase_floor", "collapsed_ring_error", "reading_evidence",
           "spacing_stats", "resample_outline", "radial_fit", "radial_outline", "ring_rotation"]

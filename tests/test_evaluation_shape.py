"""tpnet_ref.evaluation.shape: the shape-error references of the ring and the outline analysis.
"""
from __future__ import annotations


import numpy as np
import pytest

pytest.importorskip("h5py")

from tpnet_ref import evaluation as E  # noqa: E402


def test_ring_phase_floor_matches_its_closed_form():
    """E_s of the rest ring against itself turned by phase φ is 60 · 2r·sin(d/2), d = the
    angular distance to the nearest particle (both directions alike); averaged over φ uniform
    in one spacing this is the floor results.md quotes."""
    from tpnet_ref.metrics import shape_error
    from tpnet_ref.config import NORM_HI, NORM_LO
    n, r = 30, 2.0 / (NORM_HI - NORM_LO)
    s = 2 * np.pi / n
    ph = (np.arange(720) + 0.5) / 720 * s
    d = np.minimum(ph, s - ph)
    closed = float(np.mean(60 * 2 * r * np.sin(d / 2)))
    assert E.ring_phase_floor() == pytest.approx(closed, rel=1e-9)
    assert 0.14 < closed < 0.15
    a = 2 * np.pi * np.arange(n) / n
    ring = np.stack([r * np.sin(a), r * np.cos(a)], -1)
    assert shape_error(ring, ring[::-1] + 0.3, variant="released") == pytest.approx(0, abs=1e-12)
    # the same phases in the squared reading: 60 · (2r·sin(d/2))²
    sq = float(np.mean(60 * (2 * r * np.sin(d / 2)) ** 2))
    assert E.ring_phase_floor(variant="squared") == pytest.approx(sq, rel=1e-9)
    assert E.ring_phase_floor(variant="paper") == pytest.approx(sq / 30, rel=1e-9)


def test_collapsed_ring_scores_its_closed_form_in_each_reading():
    """30 points at radius r against 30 points at the centre: every nearest distance is r."""
    from tpnet_ref.config import NORM_HI, NORM_LO
    r = 2.0 / (NORM_HI - NORM_LO)
    assert E.collapsed_ring_error(variant="released") == pytest.approx(60 * r, rel=1e-12)
    assert E.collapsed_ring_error(variant="squared") == pytest.approx(60 * r ** 2, rel=1e-12)
    assert E.collapsed_ring_error(variant="paper") == pytest.approx(2 * r ** 2, rel=1e-12)
    assert E.reading_evidence("squared") == {"floor": E.ring_phase_floor(variant="squared"),
                                             "collapsed": E.collapsed_ring_error(variant="squared")}


def _ring(n=30, r=2.0, turn_deg=0.0, centre=(10.0, 20.0)):
    """The body's start ring (docs/spec.md §5 particle order), turned counter-clockwise by turn_deg."""
    a = 2 * np.pi * np.arange(n) / n - np.radians(turn_deg)
    return np.stack([centre[0] + r * np.sin(a), centre[1] + r * np.cos(a)], -1)


@pytest.mark.parametrize("turn", [0.0, 5.0, -30.0, 179.0])
def test_ring_rotation_reads_how_far_the_body_has_turned(turn):
    assert E.ring_rotation(_ring(turn_deg=turn)) == pytest.approx(turn, abs=1e-9)
    moved = _ring(turn_deg=turn, centre=(30.0, 5.0))        # any place, and batched
    np.testing.assert_allclose(E.ring_rotation(np.stack([moved, moved])), [turn, turn], atol=1e-9)
    with pytest.raises(ValueError, match="particle order"):
        E.ring_rotation(moved[:29])


def test_resample_outline_spaces_points_evenly_along_the_same_polygon():
    """An evenly spaced ring comes back as itself (offset 0) or turned by half a spacing
    (offset 0.5); a ring with one point moved onto its neighbour (a clump and a gap) comes back
    evenly spaced, on the clumped polygon."""
    from tpnet_ref.metrics import shape_error
    ring = _ring()
    rng = np.random.default_rng(1)
    shuffled = ring[rng.permutation(30)][None]
    back = E.resample_outline(shuffled)
    assert shape_error(ring, back[0], variant="released") == pytest.approx(0, abs=1e-9)
    half = E.resample_outline(shuffled, 0.5)[0]              # midpoints of the polygon's sides
    mid = 0.5 * (ring + np.roll(ring, -1, axis=0))
    assert shape_error(mid, half, variant="released") == pytest.approx(0, abs=1e-9)
    clumped = ring.copy()
    clumped[7] = ring[8] + 1e-3
    st0 = E.spacing_stats(E.normalize(clumped)[None])
    st1 = E.spacing_stats(E.normalize(E.resample_outline(clumped[None], [0.25])))
    assert st0["nn_min"] < 0.01 and st1["nn_min"] > 0.38      # world units; the ring has 0.418
    d = np.linalg.norm(np.diff(E.resample_outline(clumped[None])[0], axis=0), axis=1)
    assert d.std() < 0.05 * d.mean()
    with pytest.raises(ValueError, match="sets"):
        E.resample_outline(ring)


def test_radial_fit_reads_radius_squash_and_raggedness():
    """A circle fits with its radius and no residual; an ellipse (a mode-2 squash) needs mode 2;
    a ragged ring (every other point pushed out) leaves its raggedness in the residual."""
    a = 2 * np.pi * np.arange(30) / 30
    circle = _ring(r=2.0)
    coef, res = E.radial_fit(circle[None], modes=4)
    assert coef[0, 0] == pytest.approx(2.0, abs=1e-9)
    np.testing.assert_allclose(coef[0, 1:], 0, atol=1e-9)
    np.testing.assert_allclose(res, 0, atol=1e-9)
    ellipse = np.stack([2.2 * np.cos(a), 1.8 * np.sin(a)], -1)
    _, r0 = E.radial_fit(ellipse[None], modes=0)
    c2, r2 = E.radial_fit(ellipse[None], modes=2)
    assert c2[0, 3] > 0.15 and np.abs(r2).max() < 0.2 * np.abs(r0).max()
    ragged = circle + 0.05 * np.where(np.arange(30) % 2, 1, -1)[:, None] * (circle - circle.mean(0)) / 2
    _, rr = E.radial_fit(ragged[None], modes=4)
    assert np.abs(rr).mean() == pytest.approx(0.05, rel=1e-6)
    with pytest.raises(ValueError, match="sets"):
        E.radial_fit(circle)


@pytest.mark.parametrize("phase", [0.0, 0.1])
def test_radial_outline_is_the_evenly_spaced_smooth_outline(phase):
    """modes = 0 turns a ragged, clumped, shuffled ring into the evenly spaced circle of its
    mean radius at the given phase; a circle at that phase comes back unchanged."""
    from tpnet_ref.metrics import shape_error
    a = 2 * np.pi * np.arange(30) / 30 + phase
    circle = np.stack([3 + 2 * np.cos(a), 4 + 2 * np.sin(a)], -1)
    np.testing.assert_allclose(E.radial_outline(circle[None], 0, phase)[0], circle, atol=1e-12)
    rng = np.random.default_rng(0)
    messy = circle * 1.0
    messy[3] = messy[4] + 1e-3
    messy = (messy - messy.mean(0)) * (1 + 0.01 * rng.standard_normal((30, 1))) + messy.mean(0)
    out = E.radial_outline(messy[rng.permutation(30)][None], 0, [phase])[0]
    r = np.linalg.norm(out - out.mean(0), axis=1)
    assert r.std() < 1e-12
    assert shape_error(circle, out, variant="released") < 0.05 * 60
    ang = np.unwrap(np.arctan2(*(out - out.mean(0)).T[::-1]))
    assert ang[0] == pytest.approx(phase, abs=1e-12)
    np.testing.assert_allclose(np.diff(ang), 2 * np.pi / 30, atol=1e-12)

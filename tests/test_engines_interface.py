"""tpnet_ref.engines.interface: which head runs a batch, and the interface every head keeps (each head's
numbers are checked against the reference in tests/test_engines_reference.py)."""
from __future__ import annotations

import numpy as np
import pytest

from tpnet_ref.engines import interface as H
from tpnet_ref.model import init_random

from ring_helpers import SMALL, rings


@pytest.fixture(scope="module")
def small():
    return init_random(SMALL, seed=2, dtype="float64")


def _windows(n: int) -> np.ndarray:
    return rings(np.random.default_rng(1), n)


def test_resolve_engine_checks_and_resolves():
    assert H.resolve_engine("numpy") == "numpy"
    assert H.resolve_engine("auto") in ("numpy", "numba")
    with pytest.raises(ValueError, match="engine must be one of"):
        H.resolve_engine("cuda")


def test_heads_are_fastest_first_and_a_batch_goes_to_the_first_that_runs_it(small):
    spec = small.specialize(_windows(20))
    nb = spec.with_engine("numba")
    assert [h.name for h in small.heads] == ["numpy"]
    assert [h.name for h in spec.heads] == ["specialised", "numpy"]
    assert [h.name for h in nb.heads] == ["numba", "specialised", "numpy"]
    for b in (1, H.ENGINE_MAX_BATCH):
        assert nb.head_for(b).name == "numba"
    assert nb.head_for(H.ENGINE_MAX_BATCH + 1).name == "specialised"
    assert spec.head_for(1000).name == "specialised"
    assert H.for_batch(small.heads, 10 ** 6) is small.heads[-1]
    assert small.heads[-1].max_batch is None            # the last head takes any batch


def test_every_head_keeps_the_interface(small):
    """``project`` gives the per-frame projection its call accepts (or None), ``__call__`` gives
    ``(B, n_out, dim)`` in [0, 1], and a head fed its own projections equals the head alone."""
    model = small.specialize(_windows(20)).with_engine("numba")
    feats = model.window_features(_windows(3))                       # (B, m, k)
    m = model.config.m
    for head in model.heads:
        assert isinstance(head.threaded, bool) and isinstance(head.name, str)
        y = head(feats)
        assert y.shape == (3, model.config.n_out, model.config.dim)
        assert ((y >= 0) & (y <= 1)).all()
        proj = head.project(feats.transpose(1, 0, 2).reshape(m * 3, -1), 3)
        if proj is None:
            assert head.name == "specialised"
            continue
        again = head(feats, proj.reshape(m, 3, -1))
        np.testing.assert_array_equal(again, y)


def test_the_specialised_head_counts_windows_and_fallbacks(small):
    spec = small.specialize(_windows(20))
    spec.counts.update(windows=0, fallbacks=0)
    spec.predict_batch(_windows(5))
    assert spec.counts["windows"] == 5
    wild = _windows(4) * 2.0 - 20                     # far outside: dropped units wake up
    spec.predict_batch(wild)
    assert spec.counts["windows"] == 9
    assert spec.counts["fallbacks"] > 0
    np.testing.assert_allclose(spec.predict_batch(wild), small.predict_batch(wild), atol=1e-9)

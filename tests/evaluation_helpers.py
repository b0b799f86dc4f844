"""Shared by the tests of tpnet_ref.evaluation: small random networks, a few simulated held-out
cases, fake curves. Fixtures here are imported by name into the test modules that use them."""
from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from tpnet_ref import evaluation as E
from tpnet_ref.model import TPNetConfig, init_random

SMALL = dict(input_tnet_mlp=(4, 8), input_tnet_fc=(8,), mlp1=(8, 8), feature_tnet_mlp=(8,),
             feature_tnet_fc=(8,), mlp2=(16, 32), global_features=16, lstm_units=(16, 8, 8))
HAS_MPL = importlib.util.find_spec("matplotlib") is not None


def small_model(m: int = 4, seed: int = 0, dtype: str = "float64"):
    return init_random(TPNetConfig(m=m, **SMALL), seed=seed, dtype=dtype)


@pytest.fixture(scope="module")
def weights_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("w") / "small_m4.h5"
    small_model(4, seed=3, dtype="float32").save(str(path))
    return str(path)


@pytest.fixture(scope="module")
def frames3():
    """Model frames of the first three held-out cases, long enough for m=4 + 6 predictions."""
    return E.simulate_cases(E.TEST_CASES[:3], E.FRAME_EVERY * 10 + 1, workers=1)


def fake_curves(m=4, H=90, names=("copy last", "TP-Net x.h5")):
    out = []
    for i, n in enumerate(names):
        for o in E.ORDERINGS:
            err = {f"{k}_{v}": np.tile(np.linspace(0.01, 1, H) * (i + 1), (3, 1))
                   for k in ("Ep", "Es") for v in E.VARIANTS}
            out.append(E.Curve(n, m, o, err))
    return out

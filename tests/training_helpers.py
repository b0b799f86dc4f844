"""Shared by the tests/test_training_*.py modules: a tiny dataset and a tiny recipe."""
from __future__ import annotations

import pytest

from tpnet_ref.sim import dataset as D
from tpnet_ref.training import recipe as R


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """6 short trajectories (120 rows = 30 frames), 20 windows each, no test cases."""
    path = tmp_path_factory.mktemp("data") / "tiny.h5"
    grid = D.train_grid([1.3], [200.0, 245.0], positions=3)
    D.generate(str(path), grid, None, m=4, steps=120, seed=0, progress=False)
    return str(path)


def tiny_recipe(**kw):
    base = dict(recipe="paper", epochs=2, batch=16, lr=3e-3, warmup_steps=2, clip=10.0,
                val_fraction=0.2, seed=3, config=R.size_config("tiny").to_dict())
    return R.Recipe(**{**base, **kw})

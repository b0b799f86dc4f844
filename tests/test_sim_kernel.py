"""The step kernel (tpnet_ref.sim.kernel) through the scene: Box2D's per-step clamps, and numba as
the ``sim`` extra."""
from __future__ import annotations

import importlib
import math
import sys

import numpy as np
import pytest

from tpnet_ref.extras import MissingExtraError
from tpnet_ref.sim.scene import SceneParams, build_scene


def _spin_all(scene, w: float) -> None:
    """Every particle spinning at ``w`` rad/s: ``step`` advances from ``read``'s buffer."""
    scene.read()[: scene.n, 4] = w


@pytest.mark.parametrize("w", [1e4, -3e3])
def test_rotation_clamped_to_max_rotation_per_step(w):
    sc = build_scene(22.0, 22.0, 0.0, 0.0, SceneParams(gravity=(0.0, 0.0)))
    _spin_all(sc, w)
    sc.step()
    ang = sc.read()[: sc.n, 4]
    h = sc.params.dt
    np.testing.assert_allclose(ang * h, math.copysign(0.5 * math.pi, w), rtol=1e-12)


def test_translation_clamped_to_max_translation_per_step():
    sc = build_scene(22.0, 22.0, 40.0, 0.0, SceneParams(gravity=(0.0, 0.0), walls=False))
    sc.read()
    sc.step()
    v = sc.read()[: sc.n, 2:4]
    np.testing.assert_allclose(np.hypot(*v.T) * sc.params.dt, 2.0, rtol=1e-12)


def test_missing_numba_names_the_sim_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "numba", None)
    monkeypatch.delitem(sys.modules, "tpnet_ref.sim.kernel", raising=False)
    with pytest.raises(MissingExtraError, match=r"tpnet-ref\[sim\]") as exc:
        importlib.import_module("tpnet_ref.sim.kernel")
    assert "\n" not in str(exc.value)


def test_missing_pymunk_names_the_sim_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "pymunk", None)
    with pytest.raises(MissingExtraError, match=r"tpnet-ref\[sim\]"):
        build_scene(22.0, 22.0)

"""The paper's soft-body scene (docs/spec.md §5), as Box2D 2.3 ran it, and its test cases.

* :mod:`~tpnet_ref.sim.scene`  ``SceneParams`` (every parameter, validated), ``build_scene``,
  ``Scene`` (step by hand) and ``simulate`` (one trajectory, ``(steps, 30, 2)`` world units).
* :mod:`~tpnet_ref.sim.kernel` the Numba step kernel (springs, walls, clamps, time of impact).
* :mod:`~tpnet_ref.sim.cases`  the training grid and the 60 held-out test cases.
* :mod:`~tpnet_ref.sim.protocol`  the evaluation protocol on the scene's trajectories: frame
  spacing, horizons, input orderings, the copy-last and constant-velocity baselines.
* :mod:`~tpnet_ref.sim.dataset`  the synthetic dataset: ``generate`` (``tpnet data generate``),
  ``load_windows``, ``load_trajectories``, calibration windows.
* :mod:`~tpnet_ref.sim.scene3d` the 3-D scene (docs/spec.md §8): ``SceneParams3D``,
  ``simulate3d`` (one throw of a soft ball of 42 particles, ``(steps, 42, 3)``), in MuJoCo.
* :mod:`~tpnet_ref.sim.cases3d` the 3-D training grid's values and its 60 held-out test cases.
* :mod:`~tpnet_ref.sim.plot`   ``show``: a PNG of one trajectory.
* :mod:`~tpnet_ref.sim.box2d`  ``simulate_box2d``: the same scene in Box2D 2.3 (``box2d`` extra),
  for validation only; not imported here.

pymunk and numba (the ``sim`` extra), mujoco (``sim3d``) and matplotlib (``plot``) are imported
on first use.
"""
from __future__ import annotations

from .cases import TEST_CASES, TRAIN_ANGLES_DEG, TRAIN_FORCES, TRAIN_POSITIONS
from .cases3d import (TEST_CASES3D, TRAIN_AZIMUTHS_DEG, TRAIN_ELEVATIONS_DEG, TRAIN_FORCES3D,
                      TRAIN_POSITIONS3D)
from .plot import show
from .scene import (Scene, SceneParams, build_scene, connected_matrix, ring_positions, simulate,
                    spring_energy_k, spring_pairs, validate_params)
from .scene3d import (Scene3D, SceneParams3D, build_scene3d, simulate3d, spring_pairs3d,
                      validate_params3d)

__all__ = ["SceneParams", "Scene", "simulate", "build_scene", "ring_positions", "spring_pairs",
           "connected_matrix", "validate_params", "spring_energy_k", "show", "TEST_CASES",
           "TRAIN_POSITIONS", "TRAIN_FORCES", "TRAIN_ANGLES_DEG", "SceneParams3D", "Scene3D",
           "simulate3d", "build_scene3d", "spring_pairs3d", "validate_params3d", "TEST_CASES3D",
           "TRAIN_POSITIONS3D", "TRAIN_FORCES3D", "TRAIN_AZIMUTHS_DEG", "TRAIN_ELEVATIONS_DEG"]

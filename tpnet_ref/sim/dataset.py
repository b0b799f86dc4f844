"""Synthetic dataset (docs/spec.md §5): trajectories of the soft-body scene and training windows.

File layout (HDF5, written by ``tpnet data generate``)::

    /                       attrs: m, n_targets, frame_every, steps, seed, norm_lo, norm_hi,
                                   scene (JSON of SceneParams), format, dim (2 or 3; a file
                                   without it is 2-D), and for dim = 2 the scene
                                   convention: impulse_point ("ring_centre" or
                                   "particle_centre"), sleep (bool)
    /train/params           (T, 4) float64   force, angle_deg, x, y per trajectory (dim = 3:
                                             (T, 6) force, azimuth_deg, elevation_deg, x, y, z)
    /train/positions        (T, F, N, D) float32  world units, model frames (every 4th row);
                                             D = dim (N = 30 in 2-D, 42 in 3-D)
    /train/normalized       (T, F, N, D) float32  (x - NORM_LO) / (NORM_HI - NORM_LO)
    /train/contact          (T, F, 2 D) bool some particle touches the wall at the low / high
                                             end of each axis (x, y[, z]): left, right,
                                             bottom, top[, floor, ceiling] in 2-D[3-D]
    /train/done             (T,) bool        trajectory written (resuming skips these)
    /train/windows          (W, 3) int64     trajectory, first frame, kind (1 wall collision,
                                             0 normal interval, 2 whole-trajectory window)
    /train/rows             (T, S, N, D) float32  normalised, EVERY simulator row (only in a
                                             file made with ``windows="released"``)
    /train/windows_released (W', 3) int64    trajectory, first simulator ROW, kind: the released
                                             preprocessing's windows (:func:`released_windows`;
                                             only with ``windows="released"``)
    /test/...               the 60 held-out cases, same datasets, no windows

Model frame ``j`` is simulation row ``4 j``, the state after ``4 j + 1`` steps (``simulate``'s
convention, which is the paper's: see docs/simulator.md), so a 600-step trajectory has
``F = 150`` frames, and a test window's inputs are frames ``0..m-1`` (rows 0, 4, ..., 4(m-1)).
A training window is ``m`` input frames followed by 8 target frames.

The scene convention (where the start impulse acts, whether bodies may sleep) changes every
trajectory after the first wall contact, so :func:`load_windows` and :func:`load_trajectories`
refuse (one-line ``ValueError``) a file made with another convention than the one asked for
(default: the simulator's default, ``SceneParams()``) unless ``allow_other_scene=True``. A file
without the attributes was made before they existed, with ``impulse_point="particle_centre"``
and the ``sleep`` recorded in its ``scene`` JSON.

The 3-D scene (docs/spec.md §8, :mod:`tpnet_ref.sim.scene3d`) writes the same layout with
``dim = 3`` (``generate(..., dim=3)``, ``tpnet data generate --dim 3``). Every reader takes the
dimension it expects (``dim=2`` unless told, or a ``SceneParams3D`` given as ``scene``) and
refuses a file of the other in one line naming both, whatever ``allow_other_scene`` says.
"""
from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..checks import as_real_array, check_finite
from ..config import NORM_HI, NORM_LO, normalize
from ..extras import require
from .protocol import FRAME_EVERY, SIM_ROWS
from .cases import TRAIN_ANGLES_DEG, TRAIN_FORCES, TRAIN_POSITIONS
from .cases3d import train_grid3d
from .scene import SceneParams, simulate, validate_params
from .scene3d import SceneParams3D, check_throw, simulate3d, validate_params3d

FORMAT = "tpnet_ref.data/3"
#: the convention of files written before it was recorded
LEGACY_IMPULSE_POINT = "particle_centre"
N_TARGETS = 8
KIND_NORMAL, KIND_COLLISION, KIND_WHOLE = 0, 1, 2
#: how windows are drawn: "model" (starts at model frames, a collision begins inside the
#: window) or "released" (the authors' preprocessing: starts at any simulator row)
WINDOW_MODES = ("model", "released")
#: the released preprocessing's COLLISION_RANGE_BOUND: a window is a "collision" window when a
#: coordinate of its FIRST frame is within this many world units of the particle-centre range
RELEASED_COLLISION_RANGE = 0.2
#: the released share of training trajectories kept whole (int(0.035 * 6875) = 240)
RELEASED_WHOLE_FRACTION = 0.035


def train_grid(forces: Sequence[float] = TRAIN_FORCES, angles: Sequence[float] = TRAIN_ANGLES_DEG,
               positions: int | None = None) -> np.ndarray:
    """``(T, 4)`` (force, angle_deg, x, y) of the training grid, forces outermost, then angles,
    then positions (the first ``positions`` of the 75; all by default)."""
    pos = np.asarray(TRAIN_POSITIONS, dtype=float)
    if positions is not None:
        if not 1 <= positions <= len(pos):
            raise ValueError(f"positions: must be in 1..{len(pos)}, got {positions}")
        pos = pos[:positions]
    out = [(f, a, x, y) for f in forces for a in angles for x, y in pos]
    return np.asarray(out, dtype=float).reshape(-1, 4)


def wall_contact(frames: np.ndarray, params: SceneParams | SceneParams3D | None = None,
                 margin: float = 0.02) -> np.ndarray:
    """``(F, 2 D)`` bool: some particle centre is within ``radius + skin + margin`` of the wall
    at the low and the high end of each axis: left, right, bottom, top (2-D; the 3-D scene adds
    floor and ceiling, its walls have no skin). ``frames``: ``(F, N, D)`` world units."""
    p = params or SceneParams()
    reach = p.particle_radius + getattr(p, "wall_skin", 0.0) + margin
    lo = frames.min(axis=1)          # (F, D)
    hi = frames.max(axis=1)
    cols = []
    for a in range(frames.shape[-1]):
        cols += [lo[:, a] < p.free_lo + reach, hi[:, a] > p.free_hi - reach]
    return np.stack(cols, axis=1)


def collision_frames(contact: np.ndarray) -> np.ndarray:
    """``(F,)`` bool: frames where a wall contact begins (some wall touched now and not at the
    frame before). ``contact``: ``(F,)`` or ``(F, walls)`` bool."""
    c = np.asarray(contact, dtype=bool)
    if c.ndim == 1:
        c = c[:, None]
    onset = c.copy()
    onset[1:] &= ~c[:-1]
    onset[0] = False   # a body that starts against a wall has not collided yet
    return onset.any(axis=1)


def sample_windows(contact: np.ndarray, rng: np.random.Generator, m: int,
                   n_collision: int = 15, n_normal: int = 5,
                   n_targets: int = N_TARGETS) -> np.ndarray:
    """``(n_collision + n_normal, 2)`` (first frame, kind) of training windows of one trajectory,
    from its ``(F,)`` or ``(F, 4)`` wall contacts.

    A window covers frames ``[s, s + m + n_targets)``; it "includes a wall collision" when a
    contact begins inside it. Starts are drawn without replacement where enough exist; when one
    kind has too few starts the rest come from the other kind (so every trajectory gives the
    same number of windows)."""
    length = m + n_targets
    n_starts = len(contact) - length + 1
    if n_starts < 1:
        raise ValueError(f"trajectory of {len(contact)} frames is shorter than a window "
                         f"({length} frames)")
    onset = collision_frames(contact).astype(np.int64)
    cs = np.concatenate([[0], np.cumsum(onset)])
    has = (cs[length:length + n_starts] - cs[:n_starts]) > 0
    coll = np.nonzero(has)[0]
    norm = np.nonzero(~has)[0]
    want_c = min(n_collision, len(coll)) if len(norm) else n_collision + n_normal
    want_n = n_collision + n_normal - want_c
    pick_c = _draw(rng, coll, want_c)
    pick_n = _draw(rng, norm, want_n)
    starts = np.concatenate([pick_c, pick_n])
    kinds = np.concatenate([np.full(len(pick_c), KIND_COLLISION), np.full(len(pick_n),
                                                                        KIND_NORMAL)])
    return np.stack([starts, kinds], axis=1).astype(np.int64)


def released_windows(rows: np.ndarray, rng: np.random.Generator, m: int, whole: bool = False,
                     n_collision: int = 15, n_normal: int = 5, n_targets: int = N_TARGETS,
                     frame_every: int = FRAME_EVERY) -> np.ndarray:
    """``(W, 2)`` (first simulator row, kind) of one trajectory's windows as the authors'
    preprocessing draws them (docs/spec.md §5), from its ``(S, N, 2)`` rows in normalised
    coordinates.

    A window may start at ANY row ``s`` in ``0 .. S - (m + n_targets - 1) * frame_every - 1``;
    its frames are rows ``s, s + frame_every, ...``. It is a collision window (kind 1) when
    some coordinate of its FIRST frame is within :data:`RELEASED_COLLISION_RANGE` world units
    of the particle-centre range (the normalisation bounds). ``n_normal`` starts are drawn from
    all starts (kind 0), up to ``n_collision`` from the collision starts, and a collision start
    already drawn as a normal one is dropped (the released code meant to; its loop that removes
    from the list it iterates keeps some). ``whole``: every start instead (kind 2)."""
    span = (m + n_targets - 1) * frame_every
    n_starts = len(rows) - span
    if n_starts < 1:
        raise ValueError(f"trajectory of {len(rows)} rows is shorter than a window "
                         f"({span + 1} rows)")
    starts = np.arange(n_starts)
    if whole:
        return np.stack([starts, np.full(n_starts, KIND_WHOLE)], axis=1).astype(np.int64)
    bound = RELEASED_COLLISION_RANGE / (NORM_HI - NORM_LO)
    first = rows[:n_starts].reshape(n_starts, -1)
    near = (first.max(axis=1) >= 1.0 - bound) | (first.min(axis=1) <= bound)
    normal = np.sort(rng.choice(starts, size=min(n_normal, n_starts), replace=False))
    pool = starts[near]
    coll = np.sort(rng.choice(pool, size=min(n_collision, len(pool)), replace=False))
    coll = coll[~np.isin(coll, normal)]
    kinds = np.concatenate([np.full(len(normal), KIND_NORMAL), np.full(len(coll), KIND_COLLISION)])
    return np.stack([np.concatenate([normal, coll]), kinds], axis=1).astype(np.int64)


def released_whole(n_trajectories: int) -> int:
    """How many of ``n_trajectories`` training trajectories the released preprocessing keeps
    whole: ``int(0.035 n)`` (240 of the 2-D grid's 6,875; 11 of the 3-D grid's 342)."""
    return int(RELEASED_WHOLE_FRACTION * int(n_trajectories))


def _draw(rng: np.random.Generator, pool: np.ndarray, k: int) -> np.ndarray:
    if k <= 0 or len(pool) == 0:
        return np.zeros(0, dtype=np.int64)
    return np.sort(rng.choice(pool, size=k, replace=len(pool) < k))


# --------------------------------------------------------------------------- generation
#: the dimensions a dataset can have, and each one's case columns
DIMS = (2, 3)
CASE_COLUMNS = {2: ("force", "angle_deg", "x", "y"),
                3: ("force", "azimuth_deg", "elevation_deg", "x", "y", "z")}


def _simulate_one(job: tuple[int, tuple[float, ...], int, dict]) -> tuple:
    """Worker: one trajectory -> (index, rows (S, N, D) float64: every simulator row)."""
    idx, case, steps, scene = job
    if len(case) == 6:
        return idx, simulate3d(*case, steps, params=SceneParams3D(**scene))
    return idx, simulate(*case, steps, params=SceneParams(**scene))


def _frames_of(m: Any, steps: Any, workers: Any, windows: Any, seed: Any, whole: Any) -> int:
    """:func:`generate`'s arguments checked (one-line errors); the frames of a trajectory."""
    if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or m < 1:
        raise ValueError(f"m: must be a positive integer, got {m!r}")
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
        raise ValueError(f"steps: must be a positive integer, got {steps!r}")
    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise ValueError(f"workers: must be a positive integer, got {workers!r}")
    n_frames = (steps - 1) // FRAME_EVERY + 1
    if n_frames < m + N_TARGETS:
        raise ValueError(f"steps: {steps} rows give {n_frames} frames, fewer than a window "
                         f"(m + {N_TARGETS} = {m + N_TARGETS})")
    if windows not in WINDOW_MODES:
        raise ValueError(f"windows: must be one of {WINDOW_MODES}, got {windows!r}")
    for name, v in (("seed", seed), ("whole", whole)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
            raise ValueError(f"{name}: must be a non-negative integer, got {v!r}")
    return n_frames


def _scene_of(params: SceneParams | SceneParams3D | None,
              dim: Any) -> SceneParams | SceneParams3D:
    """The scene of a ``dim``-D dataset: ``params`` (default: that dimension's default scene)
    checked to be of that dimension and valid (one-line errors)."""
    if isinstance(dim, bool) or dim not in DIMS:
        raise ValueError(f"dim: must be 2 or 3, got {dim!r}")
    kind = SceneParams if dim == 2 else SceneParams3D
    p = kind() if params is None else params
    if not isinstance(p, kind):
        raise ValueError(f"params: dim = {dim} needs a {kind.__name__}, got "
                         f"{type(p).__name__}")
    (validate_params if dim == 2 else validate_params3d)(p)
    return p


def _check_starts(splits: dict[str, np.ndarray], p: SceneParams | SceneParams3D) -> None:
    """Every case's force >= 0 and its start inside the box (2-D: with walls, the start centre;
    3-D: :func:`~tpnet_ref.sim.scene3d.check_throw`); a one-line ``ValueError`` naming the
    first case the scene cannot simulate."""
    for split, cases in splits.items():
        name = "grid" if split == "train" else "test_cases"
        bad = np.flatnonzero(cases[:, 0] < 0)
        if bad.size:
            raise ValueError(f"{name}[{bad[0]}]: force must be >= 0, got {cases[bad[0], 0]}")
        if isinstance(p, SceneParams3D):
            for i, case in enumerate(cases):
                try:
                    check_throw(*case, p)
                except ValueError as exc:
                    raise ValueError(f"{name}[{i}]: {exc}") from None
            continue
        reach = p.ring_radius - p.particle_radius
        lo, hi = p.free_lo + reach, p.free_hi - reach
        if p.walls:
            bad = np.flatnonzero(((cases[:, 2:] < lo) | (cases[:, 2:] > hi)).any(axis=1))
            if bad.size:
                raise ValueError(f"{name}[{bad[0]}]: start centre {tuple(cases[bad[0], 2:])} puts "
                                 f"the body outside the box; must be in [{lo:g}, {hi:g}]")


def _create_split(g: Any, cases: np.ndarray, n_frames: int, n: int, rows: int | None,
                  dim: int = 2) -> None:
    """A split's datasets in a new file: its cases, positions (``dim`` coordinates), contacts
    (two walls per axis), what is done; with ``rows`` (the released windows) every simulator
    row too."""
    t = len(cases)
    g.create_dataset("params", data=cases)
    shape = (t, n_frames, n, dim)
    chunks = (1, n_frames, n, dim)
    g.create_dataset("positions", shape=shape, dtype="f4", chunks=chunks)
    g.create_dataset("normalized", shape=shape, dtype="f4", chunks=chunks)
    g.create_dataset("contact", shape=(t, n_frames, 2 * dim), dtype=bool)
    g.create_dataset("done", shape=(t,), dtype=bool)
    if rows is not None:
        g.create_dataset("rows", shape=(t, rows, n, dim), dtype="f4", chunks=(1, rows, n, dim))


def generate(path: str, grid: np.ndarray, test_cases: np.ndarray | None = None, *, m: int = 4,
             steps: int = SIM_ROWS, seed: int = 0, workers: int = 1, whole: int = 0,
             params: SceneParams | SceneParams3D | None = None, progress: bool = True,
             windows: str = "model", dim: int = 2) -> dict:
    """Simulate ``grid`` (``(T, 4)`` force, angle, x, y) and ``test_cases`` into HDF5 ``path``;
    ``dim=3``: the 3-D scene (``(T, 6)`` force, azimuth, elevation, x, y, z; ``params`` a
    ``SceneParams3D``), the same layout with ``dim = 3`` recorded.

    Resumable: an existing file with the same settings keeps its finished trajectories.
    Deterministic: the simulation is deterministic and windows are drawn from
    ``default_rng([seed, trajectory])``. ``whole`` trajectories (chosen with the seed) also
    give every window start (the paper keeps 240 whole). ``windows="released"`` also keeps
    every simulator row of the training trajectories (``/train/rows``, ~1 GB for the grid) and
    the released preprocessing's windows (``/train/windows_released``, :func:`released_windows`:
    ``whole`` trajectories give all their row starts and no sampled window). Returns counts."""
    import h5py

    n_frames = _frames_of(m, steps, workers, windows, seed, whole)
    p = _scene_of(params, dim)
    scene = dataclasses.asdict(p)
    settings = {"format": FORMAT, "m": int(m), "n_targets": N_TARGETS,
                "frame_every": FRAME_EVERY, "steps": int(steps), "seed": int(seed),
                "whole": int(whole), "norm_lo": NORM_LO, "norm_hi": NORM_HI,
                "scene": json.dumps(scene, sort_keys=True), "dim": int(dim)}
    if dim == 2:
        settings.update(impulse_point=p.impulse_point, sleep=bool(p.sleep))
    if windows != "model":              # files of the default mode keep their old attributes
        settings["windows"] = windows
    splits = {"train": _cases(grid, "grid", dim)}
    if test_cases is not None:
        splits["test"] = _cases(test_cases, "test_cases", dim)
    _check_starts(splits, p)            # every case checked before the file is touched
    n = p.n_particles
    mode = "a" if os.path.exists(path) else "w"
    if mode == "w" and os.path.dirname(path):
        os.makedirs(os.path.dirname(path), exist_ok=True)
    counts = {}
    try:
        h5 = h5py.File(path, mode)
    except OSError as exc:
        raise ValueError(f"{path}: cannot open for writing as HDF5 ({exc})") from None
    with h5 as h:
        if "train" in h and file_dim(h) != dim:
            raise ValueError(f"{path}: holds a {file_dim(h)}-D dataset (dim = {file_dim(h)}), "
                             f"not dim = {dim}; use another file")
        made = _attr(h.attrs["windows"]) if "windows" in h.attrs else "model"
        if "train" in h and made != windows:
            raise ValueError(f"{path}: was written with windows={made!r}, not {windows!r}; "
                             "use another file")
        for k, v in settings.items():
            if k in h.attrs and _attr(h.attrs[k]) != v:
                raise ValueError(f"{path}: was written with {k}={_attr(h.attrs[k])!r}, not "
                                 f"{v!r}; use another file")
            h.attrs[k] = v
        for split, cases in splits.items():
            g = h.require_group(split)
            t = len(cases)
            if "params" in g and not np.array_equal(g["params"][...], cases):
                raise ValueError(f"{path}: /{split} holds another set of trajectories; "
                                 "use another file")
            if "params" not in g:
                _create_split(g, cases, n_frames, n, steps if split == "train"
                              and windows == "released" else None, dim)
            done = g["done"][...]
            todo = [i for i in range(t) if not done[i]]
            counts[f"{split}_skipped"] = t - len(todo)
            _run(g, cases, todo, steps, scene, workers, p, progress, split)
            counts[f"{split}_trajectories"] = t
            if split == "train":
                counts["train_windows"] = _write_windows(g, m, seed, whole)
                if windows == "released":
                    counts["train_windows_released"] = _write_released_windows(g, m, seed,
                                                                               whole)
    return counts


def _cases(a: Any, name: str, dim: int = 2) -> np.ndarray:
    """``(T, 4)`` finite float cases (force, angle, x, y); ``dim=3``: ``(T, 6)`` (force,
    azimuth, elevation, x, y, z)."""
    arr = as_real_array(a, name)
    width = len(CASE_COLUMNS[dim])
    if arr.ndim == 1 and arr.size == width:
        arr = arr[None]
    if arr.ndim != 2 or arr.shape[1] != width or arr.shape[0] == 0:
        other = 3 if dim == 2 else 2
        hint = (f"; {len(CASE_COLUMNS[other])} columns are {other}-D cases"
                if arr.ndim == 2 and arr.shape[1] == len(CASE_COLUMNS[other]) else "")
        raise ValueError(f"{name}: expected shape (T, {width}) ({', '.join(CASE_COLUMNS[dim])}) "
                         f"for dim = {dim}, got {arr.shape}{hint}")
    return check_finite(arr.astype(float), name)


def _attr(v: Any) -> Any:
    return v.decode() if isinstance(v, bytes) else (v.item() if hasattr(v, "item") else v)


def _run(g: Any, cases: np.ndarray, todo: list[int], steps: int, scene: dict, workers: int,
         p: SceneParams | SceneParams3D, progress: bool, split: str) -> None:
    if not todo:
        return
    jobs = [(i, tuple(cases[i]), steps, scene) for i in todo]
    bar = None
    if progress:
        tqdm = require("tqdm", "eval", "the progress bar (pass progress=False / --quiet)")
        bar = tqdm.tqdm(total=len(jobs), desc=f"simulate {split}", unit="traj")

    def store(idx: int, rows: np.ndarray) -> None:
        frames = rows[::FRAME_EVERY]
        if "rows" in g:
            g["rows"][idx] = normalize(rows).astype(np.float32)
        g["positions"][idx] = frames.astype(np.float32)
        g["normalized"][idx] = normalize(frames).astype(np.float32)
        g["contact"][idx] = wall_contact(frames, p)
        g["done"][idx] = True
        if bar is not None:
            bar.update(1)

    if workers == 1:
        for job in jobs:
            store(*_simulate_one(job))
    else:
        import multiprocessing as mp
        ctx = mp.get_context("spawn")
        with ctx.Pool(workers) as pool:
            for idx, frames in pool.imap_unordered(_simulate_one, jobs, chunksize=4):
                store(idx, frames)
                if idx % 64 == 0:
                    g.file.flush()
    if bar is not None:
        bar.close()


def _whole_trajectories(t: int, seed: int, whole: int) -> np.ndarray:
    """The sorted indices of the ``whole`` (at most ``t``) trajectories that give every window."""
    if not whole:
        return np.zeros(0, dtype=np.int64)
    return np.sort(np.random.default_rng([seed, t, 7]).choice(t, size=min(whole, t),
                                                              replace=False))


def _write_windows(g: Any, m: int, seed: int, whole: int) -> int:
    contact = g["contact"][...]
    t, n_frames = contact.shape[:2]
    rows = []
    for i in range(t):
        w = sample_windows(contact[i], np.random.default_rng([seed, i]), m)
        rows.append(np.column_stack([np.full(len(w), i), w]))
    if whole:
        keep = _whole_trajectories(t, seed, whole)
        starts = np.arange(n_frames - m - N_TARGETS + 1)
        for i in keep:
            rows.append(np.column_stack([np.full(len(starts), i), starts,
                                         np.full(len(starts), KIND_WHOLE)]))
    win = np.concatenate(rows).astype(np.int64)
    if "windows" in g:
        del g["windows"]
    g.create_dataset("windows", data=win)
    return len(win)


def _write_released_windows(g: Any, m: int, seed: int, whole: int) -> int:
    """``/train/windows_released``: :func:`released_windows` of every trajectory; the ``whole``
    ones (the same trajectories as ``/train/windows``' whole ones) give every start only."""
    rows = g["rows"]
    t = rows.shape[0]
    keep = set(_whole_trajectories(t, seed, whole).tolist())
    out = []
    for i in range(t):
        w = released_windows(rows[i], np.random.default_rng([seed, i, 11]), m, whole=i in keep)
        out.append(np.column_stack([np.full(len(w), i), w]))
    win = np.concatenate(out).astype(np.int64)
    if "windows_released" in g:
        del g["windows_released"]
    g.create_dataset("windows_released", data=win)
    return len(win)


# --------------------------------------------------------------------------- reading
def file_dim(h: Any) -> int:
    """The dimension of a dataset file (open ``h5py.File``): its ``dim`` attribute, 2 without."""
    return int(_attr(h.attrs["dim"])) if "dim" in h.attrs else 2


def check_dim(h: Any, path: str, dim: int) -> None:
    """A one-line ``ValueError`` when the file's dimension is not ``dim``."""
    got = file_dim(h)
    if got != dim:
        ask = "dim=3 (--dim 3)" if got == 3 else "dim=2 (the default)"
        raise ValueError(f"{path}: a {got}-D dataset (dim = {got}); this reader expects "
                         f"dim = {dim}: read it with {ask}")


def scene_convention(h: Any) -> dict[str, Any]:
    """``{"impulse_point": ..., "sleep": ...}`` a dataset file (open ``h5py.File``) was made with."""
    a = h.attrs
    point = _attr(a["impulse_point"]) if "impulse_point" in a else LEGACY_IMPULSE_POINT
    if "sleep" in a:
        sleep = bool(_attr(a["sleep"]))
    else:
        scene = json.loads(_attr(a["scene"])) if "scene" in a else {}
        sleep = bool(scene.get("sleep", True))      # the old default
    return {"impulse_point": point, "sleep": sleep}


def check_scene(h: Any, path: str, expected: SceneParams | SceneParams3D | None = None,
                allow_other_scene: bool = False, dim: int | None = None) -> dict[str, Any]:
    """The file's scene convention; a one-line ``ValueError`` when it is not ``expected``'s
    (default ``SceneParams()``) unless ``allow_other_scene``, and always when the file's
    dimension is not ``dim`` (default: 3 for a ``SceneParams3D``, else 2). A 3-D file has no
    convention to check: ``{"dim": 3}``."""
    if dim is None:
        dim = 3 if isinstance(expected, SceneParams3D) else 2
    check_dim(h, path, dim)
    if dim == 3:
        return {"dim": 3}
    if isinstance(expected, SceneParams3D):
        raise ValueError(f"scene: a SceneParams3D for a {dim}-D reader")
    got = scene_convention(h)
    want = expected or SceneParams()
    if not allow_other_scene:
        for k in ("impulse_point", "sleep"):
            if got[k] != getattr(want, k):
                raise ValueError(
                    f"{path}: made with the scene convention {k}={got[k]!r}, not {k}="
                    f"{getattr(want, k)!r}; regenerate it (tpnet data generate) or pass "
                    "allow_other_scene=True (--allow-other-scene)")
    return got


def load_windows(path: str, split: str = "train", *, normalized: bool = True,
                 kinds: Sequence[int] | None = None,
                 scene: SceneParams | SceneParams3D | None = None,
                 allow_other_scene: bool = False,
                 dim: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Training windows as arrays: inputs ``(W, m, N, D)`` and targets ``(W, 8, N, D)``
    (float32; model coordinates unless ``normalized=False``). ``kinds`` filters by window kind
    (0 normal, 1 wall collision, 2 whole trajectory). The file must have been made with
    ``scene``'s convention (default ``SceneParams()``) unless ``allow_other_scene``, and be of
    dimension ``dim`` (:func:`check_scene`: 2 unless told or ``scene`` is 3-D)."""
    import h5py

    with h5py.File(path, "r") as h:
        check_scene(h, path, scene, allow_other_scene, dim)
        m = int(h.attrs["m"])
        nt = int(h.attrs["n_targets"])
        g = h[split]
        if "windows" not in g:
            raise KeyError(f"{path}: /{split} has no windows")
        if not g["done"][...].all():
            raise ValueError(f"{path}: /{split} is incomplete; run generate again to finish it")
        win = g["windows"][...]
        if kinds is not None:
            win = win[np.isin(win[:, 2], np.asarray(kinds))]
        data = g["normalized" if normalized else "positions"][...]
    idx = win[:, 1:2] + np.arange(m + nt)[None, :]
    frames = data[win[:, 0:1], idx]                       # (W, m + nt, N, 2)
    return frames[:, :m], frames[:, m:]


def load_trajectories(path: str, split: str = "test", *, normalized: bool = False,
                      scene: SceneParams | SceneParams3D | None = None,
                      allow_other_scene: bool = False,
                      dim: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """All frames of a split: ``(T, F, N, D)`` float32 and their ``(T, 4)`` parameters
    (``(T, 6)`` in 3-D). The file must have been made with ``scene``'s convention (default
    ``SceneParams()``) unless ``allow_other_scene``, and be of dimension ``dim``
    (:func:`check_scene`)."""
    import h5py

    with h5py.File(path, "r") as h:
        check_scene(h, path, scene, allow_other_scene, dim)
        g = h[split]
        return g["normalized" if normalized else "positions"][...], g["params"][...]


def calibration_cases(n_trajectories: int = 36, seed: int = 0) -> np.ndarray:
    """``(n, 4)`` (force, angle_deg, x, y): ``n_trajectories`` training-grid cases
    (:func:`train_grid`) drawn without replacement with ``seed``; never a held-out
    test case (any grid row equal to one is left out)."""
    from .cases import TEST_CASES
    grid = train_grid()
    test = np.asarray(TEST_CASES, dtype=float)
    grid = grid[~(grid[:, None, :] == test[None]).all(axis=2).any(axis=1)]
    if isinstance(n_trajectories, bool) or not 1 <= int(n_trajectories) <= len(grid):
        raise ValueError(f"n_trajectories: must be in 1..{len(grid)}, got {n_trajectories!r}")
    pick = np.random.default_rng(seed).choice(len(grid), int(n_trajectories), replace=False)
    return grid[pick]


def calibration_windows(model: Any, n_trajectories: int = 36, seed: int = 0,
                        rollout: int = 40) -> np.ndarray:
    """Calibration windows ``(B, m, N, 2)`` (world units) of training-grid trajectories for
    :meth:`tpnet_ref.model.TPNet.specialize` and :meth:`~tpnet_ref.model.TPNet.sort_units`: for
    each of :func:`calibration_cases`, every window
    of its simulated trajectory (default scene, one frame every ``FRAME_EVERY`` rows) and every
    window of the model's own ``rollout``-frame rollout from its first m frames (the rollouts
    stepped together). ``B = n_trajectories * (F - m + 1 + rollout + 1)`` with ``F`` frames per
    trajectory (150: 188 windows each for m = 4). Simulates with :mod:`tpnet_ref.sim`."""
    m = model.config.m
    if isinstance(rollout, bool) or int(rollout) < 0:
        raise ValueError(f"rollout: must be >= 0, got {rollout!r}")
    trajs = np.stack([simulate(*case)[::FRAME_EVERY]
                      for case in calibration_cases(n_trajectories, seed)])    # (n, F, N, 2)
    if trajs.shape[1] < m:
        raise ValueError(f"calibration trajectories have {trajs.shape[1]} frames, fewer than m={m}")
    parts = [trajs]
    if rollout:
        own = np.asarray(model.rollout_batch(trajs[:, :m], int(rollout)), dtype=np.float64)
        parts.append(np.concatenate([trajs[:, :m], own], axis=1))
    out = []
    for t in parts:                     # every window of every trajectory, trajectory by trajectory
        idx = np.arange(t.shape[1] - m + 1)[:, None] + np.arange(m)        # (W, m)
        out.append(t[:, idx])                                              # (n, W, m, N, 2)
    # interleave: trajectory 0's simulated windows, its rollout windows, trajectory 1's ...
    return np.concatenate([np.concatenate([o[i] for o in out]) for i in range(len(trajs))])


__all__ = ["calibration_cases", "calibration_windows", "generate", "load_windows", "load_trajectories", "train_grid", "train_grid3d", "wall_contact",
           "collision_frames", "sample_windows", "released_windows", "WINDOW_MODES", "scene_convention", "check_scene", "FORMAT",
           "N_TARGETS", "DIMS", "CASE_COLUMNS", "file_dim", "check_dim", "released_whole"]

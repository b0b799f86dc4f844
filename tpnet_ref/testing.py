"""Property tests for any TP-Net implementation: hypothesis strategies and checkers.

A TP-Net, in any framework, is a function from a window -- ``m`` frames, each an unordered set
of points ``(N_t, dim)``, 2-D or 3-D -- to the next point set ``(n_out, dim)``. The checkers here
take any such callable ``fn(window) -> points`` (a NumPy array, a torch tensor, anything
``np.asarray`` reads; a window is a list of ``m`` float64 arrays) and test it with hypothesis,
on the windows of :func:`windows` (2-D by default, ``windows(dim=3)`` for a 3-D network):

- :func:`permutation_invariant` -- permuting each frame's points independently (the
  ``(N!)^m`` per-frame permutations) changes the output by at most ``tol``;
- :func:`agrees_with_reference` -- the output is within a tolerance of
  :func:`tpnet_ref.engines.reference.forward` of a :class:`~tpnet_ref.model.TPNet`'s parameters in
  float64: by default measured on each window from float32 rounding
  (:func:`measured_tolerance`, the rule of ``tpnet vectors``), or a fixed ``tol``;
- :func:`frame_order_matters`, :func:`one_point_matters` -- the non-vacuity checks: reversing or
  rotating the frames in time, or moving one point outward, changes the output by more than
  ``tol`` (a constant, or a function that ignores time, would pass the invariance check).

On a failure each raises :class:`PropertyFailure` with a one-line report of the minimal failing
window hypothesis shrank to (fewest frames and points, the first scale, seed 0, the smallest
permutation). On success each returns the largest difference it saw, a :class:`CheckResult`
whose ``report`` is one line saying what was checked on which windows. tpnet_ref's input
warnings are silenced while a check calls the function: its windows leave the training range on
purpose. The strategies
:func:`windows` and :func:`permutations` are public for tests of one's own.

hypothesis (the ``kit`` extra: ``pip install "tpnet-ref[kit]"``) is imported when a function
here is called, not on import; nothing here imports torch.
docs/testing.md shows a PyTorch module checked in ten lines.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from .config import NORM_HI, NORM_LO
from .extras import require

#: the spreads of the points around a frame's centre :func:`windows` draws from, in world units
#: (the scene's ring has radius 2; the box is 42.7 wide)
SCALES = (1e-3, 1.0, 45.0, 1e3)

#: the rounding bound the project's tests allow a per-frame permutation, in world units, per
#: dtype: the bound the project already states for where a row sits in a BLAS product (a window
#: inside a batch against it alone, README). Measured with the canonical sort off:
#: ``PYTHONPATH=bench python bench/probes/permutation_rounding.py`` (docs/testing.md)
TOLERANCE = {"float32": 5e-4, "float64": 1e-11}

Window = list  # m arrays (N_t, dim), float64


class PropertyFailure(AssertionError):
    """A property does not hold; the message is one line naming the minimal failing window."""


class CheckResult(float):
    """What a check returns: the difference it reports (a float, as before) with ``report``, one
    line saying what was checked on which windows, e.g. ``permutation_invariant: my_predict
    passed on 20 windows (m=4, N=1..64, coordinates in [-1.2, 1.3]): largest change 0
    (tolerance 1e-05)``."""

    report: str

    def __new__(cls, value: float, report: str) -> "CheckResult":
        out = super().__new__(cls, value)
        out.report = report
        return out


class _Seen:
    """The windows a check ran on: how many, their frames, points and coordinates."""

    def __init__(self) -> None:
        self.count, self.ms, self.ns = 0, set(), set()
        self.lo, self.hi = np.inf, -np.inf

    def add(self, window: Sequence[np.ndarray]) -> None:
        self.count += 1
        self.ms.add(len(window))
        self.ns.update(len(f) for f in window)
        self.lo = min(self.lo, min(float(np.min(f)) for f in window))
        self.hi = max(self.hi, max(float(np.max(f)) for f in window))

    def text(self) -> str:
        def span(v: set) -> str:
            return str(min(v)) if len(v) == 1 else f"{min(v)}..{max(v)}"
        if not self.count:
            return "no windows"
        return (f"{self.count} windows (m={span(self.ms)}, N={span(self.ns)}, coordinates in "
                f"[{self.lo:.3g}, {self.hi:.3g}])")


def _call(fn: Callable[[Window], Any], window: Window) -> np.ndarray:
    """``fn(window)`` as a float64 array, tpnet_ref's input warnings silenced: the checks draw
    windows outside the training range on purpose (the properties hold on any input)."""
    import warnings
    from .checks import OutsideTrainingRangeWarning           # NotOneBodyWarning too
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutsideTrainingRangeWarning)
        return _as_array(fn(window))


def _hypothesis() -> Any:
    return require("hypothesis", "kit", "tpnet_ref.testing (property checks)")


def _as_array(y: Any) -> np.ndarray:
    if hasattr(y, "detach"):                        # a torch tensor
        y = y.detach().cpu().numpy()
    return np.asarray(y, dtype=np.float64)


def _name(fn: Any) -> str:
    """``TPNet.predict``, ``my_predict`` (a nested function without its enclosing ones)."""
    name = getattr(fn, "__qualname__", None) or getattr(fn, "__name__", None)
    return name.rsplit("<locals>.", 1)[-1] if name else type(fn).__name__


def _describe(window: Sequence[np.ndarray], perms: Sequence[np.ndarray] | None = None) -> str:
    """One line: the window's shape and, when small, its points (and the permutations)."""
    sizes = tuple(int(len(f)) for f in window)
    lo = min(float(f.min()) for f in window)
    hi = max(float(f.max()) for f in window)
    text = f"m={len(window)}, N={sizes}, coordinates in [{lo:.4g}, {hi:.4g}]"
    if sum(sizes) <= 12:
        pts = "; ".join(" ".join("(" + ", ".join(f"{v:.6g}" for v in p) + ")" for p in f)
                        for f in window)
        text += f", frames: {pts}"
    if perms is not None:
        moved = [p.tolist() for p in perms]
        if sum(sizes) <= 64:
            text += f", permutations {moved}"
    return text


# --------------------------------------------------------------------------- strategies
def windows(m: int | tuple[int, int] | list[int] = 4, n: int | tuple[int, int] = (1, 64),
            ragged: bool | None = None, scales: Sequence[float] = SCALES,
            centre: tuple[float, float] = (-100.0, 100.0), ties: bool | None = None,
            step: tuple[float, float] = (0.0, 0.0), normalized: bool = False,
            dim: int = 2) -> Any:
    """A hypothesis strategy for windows: lists of ``m`` float64 arrays ``(N_t, dim)``.

    ``m``, ``n``: a number, an inclusive range ``(lo, hi)`` or a list of choices (each at
    least 1); ``ragged``: frames of different sizes (None: either); ``scales``: the spreads of the points around the frame's centre, drawn
    from a normal distribution (world units); ``centre``: the range of the window's centre;
    ``ties`` (None: either): in the first frame, the second half of the points repeats the
    first half and one coordinate takes only three values (exact ties and duplicate points);
    ``step``: the range of the distance each frame moves from the one before (a window that
    moves in time, in a random direction); ``normalized``: the windows in model coordinates,
    ``(x - 1.1438) / 42.7124``; ``dim``: coordinates per point (2, the default, draws exactly
    what it always drew; 3 for a 3-D network). Shrinks towards fewer frames, fewer points, the
    first scale, seed 0."""
    st = _hypothesis().strategies

    def ints(v: Any, name: str) -> Any:
        if isinstance(v, (int, np.integer)) and not isinstance(v, bool):
            choices = [int(v)]
        elif isinstance(v, list):
            choices = [int(x) for x in v]
        elif isinstance(v, tuple) and len(v) == 2 and int(v[1]) >= int(v[0]):
            choices = [int(v[0])]
        else:
            raise TypeError(f"windows: {name} must be an int, a (lo, hi) range or a list of "
                            f"choices, got {v!r}")
        if not choices or min(choices) < 1:
            raise ValueError(f"windows: {name} must be at least 1, got {v!r}")
        if isinstance(v, tuple):
            return st.integers(*v)
        return st.just(choices[0]) if len(choices) == 1 else st.sampled_from(choices)

    if isinstance(dim, bool) or not isinstance(dim, (int, np.integer)) or dim < 1:
        raise ValueError(f"windows: dim must be a whole number of coordinates >= 1, got {dim!r}")
    dim = int(dim)
    if not len(scales) or min(scales) <= 0:
        raise ValueError(f"windows: scales must be positive spreads, got {list(scales)!r}")

    ms, ns = ints(m, "m"), ints(n, "n")
    rag = st.booleans() if ragged is None else st.just(bool(ragged))
    tie = st.booleans() if ties is None else st.just(bool(ties))

    @st.composite
    def window(draw: Any) -> Window:
        mm, r = draw(ms), draw(rag)
        n0 = draw(ns)
        sizes = [draw(ns) if r else n0 for _ in range(mm)]
        scale = draw(st.sampled_from(list(scales)))
        c = draw(st.floats(*centre, allow_nan=False, allow_infinity=False))
        tied = draw(tie)
        speed = draw(st.floats(*step)) if step[1] > 0 else 0.0
        rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
        v = speed * _direction(rng, dim)
        frames = [c + t * v + scale * rng.standard_normal((k, dim)) for t, k in enumerate(sizes)]
        if tied:
            f = frames[0]
            f[len(f) // 2:] = f[:len(f) - len(f) // 2]
            f[:, 0] = c + scale * np.round(np.clip((f[:, 0] - c) / scale, -1, 1))
        if normalized:
            frames = [(f - NORM_LO) / (NORM_HI - NORM_LO) for f in frames]
        return frames

    return window()


def _direction(rng: np.random.Generator, dim: int) -> np.ndarray:
    """A random unit vector of ``dim`` coordinates: in 2-D from one angle (the draws the 2-D
    windows always made), else a normalised Gaussian vector."""
    if dim == 2:
        angle = rng.uniform(0, 2 * np.pi)
        return np.array([np.cos(angle), np.sin(angle)])
    u = rng.standard_normal(dim)
    return u / max(float(np.linalg.norm(u)), 1e-300)


_window_strategy = windows      # the checkers' parameter ``windows`` hides the function


def permutations(window: Sequence[np.ndarray]) -> Any:
    """A hypothesis strategy for one permutation of each frame's points (a list of index
    arrays; shrinks towards the identity)."""
    st = _hypothesis().strategies
    return st.tuples(*(st.permutations(range(len(f))) for f in window)).map(
        lambda ps: [np.asarray(p, dtype=np.intp) for p in ps])


def permuted(window: Sequence[np.ndarray], perms: Sequence[np.ndarray]) -> Window:
    """The window with each frame's points in the order ``perms`` gives."""
    return [np.asarray(f)[p] for f, p in zip(window, perms)]


# --------------------------------------------------------------------------- checkers
def _run(prop: Callable[..., None], strategy: Any, max_examples: int, seed: int | None) -> None:
    """Run ``prop`` over ``strategy`` with bounded settings; a :class:`PropertyFailure` of the
    minimal example comes out with its one line (hypothesis' notes dropped)."""
    hyp = _hypothesis()
    cfg = hyp.settings(max_examples=max_examples, deadline=None, database=None,
                       derandomize=False, report_multiple_bugs=False, print_blob=False,
                       suppress_health_check=[hyp.HealthCheck.too_slow,
                                              hyp.HealthCheck.data_too_large,
                                              hyp.HealthCheck.filter_too_much])
    test = cfg(hyp.given(strategy)(prop))
    if seed is not None:
        test = hyp.seed(seed)(test)
    try:
        test()
    except PropertyFailure as exc:
        raise PropertyFailure(str(exc)) from None


def _diff(a: np.ndarray, b: np.ndarray, what: str) -> float:
    if a.shape != b.shape:
        raise PropertyFailure(f"{what}: output shapes differ, {a.shape} against {b.shape}")
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        return float("inf")
    return float(np.max(np.abs(a - b), initial=0.0))


def permutation_invariant(fn: Callable[[Window], Any], windows: Any = None, tol: float = 0.0,
                          max_examples: int = 50, seed: int | None = None) -> float:
    """Check that permuting each frame's points of any window changes ``fn(window)`` by at
    most ``tol`` (max absolute difference; ``tol=0``: the same numbers bit for bit).
    ``windows``: a strategy (default ``windows()``: m = 4, 1..64 points, ragged or not).
    Returns the largest difference seen; raises :class:`PropertyFailure` naming the minimal
    window and permutations where the difference exceeds ``tol``."""
    hyp = _hypothesis()
    strategy = (windows if windows is not None else _window_strategy()).flatmap(
        lambda w: hyp.strategies.tuples(hyp.strategies.just(w), permutations(w)))
    worst, seen = [0.0], _Seen()

    def prop(case: tuple[Window, list[np.ndarray]]) -> None:
        w, perms = case
        a = _call(fn, w)
        d = _diff(a, _call(fn, permuted(w, perms)), "permutation_invariant")
        if not d <= tol:
            raise PropertyFailure(
                f"permutation_invariant: {_name(fn)} changed by {d:.3g} (tolerance {tol:.3g}) "
                f"when each frame's points were permuted; minimal window: {_describe(w, perms)}")
        worst[0] = max(worst[0], d)
        seen.add(w)

    _run(prop, strategy, max_examples, seed)
    return CheckResult(worst[0], f"permutation_invariant: {_name(fn)} passed on {seen.text()}, "
                                 f"each with its frames' points permuted: largest change "
                                 f"{worst[0]:.3g} (tolerance {tol:.3g})")


def measured_tolerance(model: Any, window: Window, normalized: bool = False,
                       expected: dict[str, np.ndarray] | None = None) -> float:
    """The default tolerance of :func:`agrees_with_reference` on one window: the rule of
    ``tpnet vectors`` (:func:`tpnet_ref.conformance.tolerances.measure_gaps` and
    :func:`~tpnet_ref.conformance.tolerances.tolerances_from`) for the last layer, ``SAFETY`` (8) x the
    largest gap between the reference in float32 and in float64 on this window (the window as
    is, moved by one float32 ulp, its points reversed) + ``FLOOR`` (2^-20) x max(1, the
    output's largest magnitude); in model coordinates (``head.sigmoid``) when ``normalized``,
    else in world units (``output``). ``expected``: the window's float64 trace, if known."""
    from .conformance import tolerances
    config = model.config
    params = {k: np.asarray(v, dtype=np.float64) for k, v in model.params.items()}
    world = _world(window, config) if normalized else window
    want = expected if expected is not None else tolerances.trace(config, params, world)
    return _measured(config, params, world, want, normalized)


def _measured(config: Any, params: dict[str, np.ndarray], world: Window,
              expected: dict[str, np.ndarray], normalized: bool) -> float:
    from .conformance import tolerances
    key = "head.sigmoid" if normalized else "output"
    gaps = tolerances.measure_gaps(config, params, world, expected)
    return tolerances.tolerances_from({key: gaps[key]},
                                      {key: float(np.abs(expected[key]).max())})[key]


def _world(window: Window, config: Any) -> Window:
    """Model coordinates -> world units with ``config``'s bounds, in float64."""
    scale = config.norm_hi - config.norm_lo
    return [np.asarray(f, dtype=np.float64) * scale + config.norm_lo for f in window]


def agrees_with_reference(fn: Callable[[Window], Any], model: Any, tol: float | None = None,
                          windows: Any = None, normalized: bool = False,
                          max_examples: int = 50, seed: int | None = None) -> float:
    """Check that ``fn(window)`` is within a tolerance (max absolute difference) of
    :func:`tpnet_ref.engines.reference.forward` with ``model``'s config and parameters in float64
    (``model``: a :class:`~tpnet_ref.model.TPNet`, e.g. :func:`tpnet_ref.load` of the weights
    ``fn`` runs). ``tol``: a fixed tolerance; ``None`` (the default) measures one on each window
    from float32 rounding (:func:`measured_tolerance`, the rule ``tpnet vectors`` gives each
    layer): an honest float32 port passes, and a port off by more than rounding (a LayerNorm
    epsilon of 1e-5 instead of 1e-3) fails where a fixed 1e-4 let it through. ``normalized``:
    windows and outputs in model coordinates (default: world units). Returns the largest
    difference seen; raises :class:`PropertyFailure` on the minimal window beyond the
    tolerance."""
    from .conformance import tolerances
    from .engines import reference
    params = {k: np.asarray(v, dtype=np.float64) for k, v in model.params.items()}
    config = model.config
    strategy = windows if windows is not None else _window_strategy(
        m=config.m, normalized=normalized, dim=config.dim)
    worst, seen, tols = [0.0], _Seen(), [np.inf, 0.0]
    key = "head.sigmoid" if normalized else "output"

    def prop(w: Window) -> None:
        if tol is None:
            world = _world(w, config) if normalized else w
            expected = tolerances.trace(config, params, world)
            want = expected[key]
            limit = _measured(config, params, world, expected, normalized)
            tols[0], tols[1] = min(tols[0], limit), max(tols[1], limit)
        else:
            want = reference.forward(config, params, w, normalized=normalized)
            limit = tol
        d = _diff(_call(fn, w), want, "agrees_with_reference")
        if not d <= limit:
            how = "" if tol is not None else ", measured from float32 rounding on this window"
            raise PropertyFailure(
                f"agrees_with_reference: {_name(fn)} is {d:.3g} from the float64 reference "
                f"(tolerance {limit:.3g}{how}); minimal window: {_describe(w)}")
        worst[0] = max(worst[0], d)
        seen.add(w)

    _run(prop, strategy, max_examples, seed)
    units = "model coordinates" if normalized else "world units"
    told = (f"tolerance {tol:.3g}" if tol is not None else
            "tolerance measured from float32 rounding" + (
                f", {tols[0]:.3g}..{tols[1]:.3g}" if seen.count else ""))
    return CheckResult(worst[0], f"agrees_with_reference: {_name(fn)} passed on {seen.text()}: "
                                 f"at most {worst[0]:.3g} {units} from the float64 reference "
                                 f"({told})")


def frame_order_matters(fn: Callable[[Window], Any], windows: Any = None, tol: float = 0.0,
                        max_examples: int = 20, seed: int | None = None) -> float:
    """Non-vacuity in time: reversing the window's frames, and rotating them by one, each
    change ``fn(window)`` by more than ``tol``. ``windows``: a strategy of windows of at least
    2 frames that move in time (default: m = 4 frames, each 0.5..2 world units from the one
    before). Returns the smallest change seen; raises :class:`PropertyFailure` otherwise."""
    strategy = windows if windows is not None else _window_strategy(step=(0.5, 2.0))
    least, seen = [float("inf")], _Seen()

    def prop(w: Window) -> None:
        if len(w) < 2:
            raise PropertyFailure(f"frame_order_matters: needs windows of 2 frames or more, "
                                  f"got {_describe(w)}")
        a = _call(fn, w)
        seen.add(w)
        for name, other in (("reversing", w[::-1]), ("rotating", w[1:] + w[:1])):
            d = _diff(a, _call(fn, list(other)), "frame_order_matters")
            if not d > tol:
                raise PropertyFailure(
                    f"frame_order_matters: {_name(fn)} changed by only {d:.3g} (needs more than "
                    f"{tol:.3g}) on {name} the frames in time; minimal window: {_describe(w)}")
            least[0] = min(least[0], d)

    _run(prop, strategy, max_examples, seed)
    return CheckResult(least[0], f"frame_order_matters: {_name(fn)} passed on {seen.text()}, "
                                 f"their frames reversed and rotated: smallest change "
                                 f"{least[0]:.3g} (needs more than {tol:.3g})")


def one_point_matters(fn: Callable[[Window], Any], windows: Any = None, tol: float = 0.0,
                      distance: float = 2.0, max_examples: int = 20,
                      seed: int | None = None) -> float:
    """Non-vacuity in space: moving one point of one frame outward, to twice the distance of
    the frame's farthest point from its centroid plus ``distance`` (world units; model
    coordinates when the windows are), changes ``fn(window)`` by more than ``tol``. Returns the smallest change
    seen; raises :class:`PropertyFailure` otherwise."""
    hyp = _hypothesis()
    st = hyp.strategies
    base = windows if windows is not None else _window_strategy()
    strategy = base.flatmap(lambda w: st.tuples(
        st.just(w), st.integers(0, len(w) - 1).flatmap(
            lambda t: st.tuples(st.just(t), st.integers(0, len(w[t]) - 1)))))
    least, seen = [float("inf")], _Seen()

    def prop(case: tuple[Window, tuple[int, int]]) -> None:
        w, (t, i) = case
        f = w[t]
        centroid = f.mean(axis=0)
        reach = float(np.max(np.linalg.norm(f - centroid, axis=1)))
        away = f[i] - centroid
        norm = float(np.linalg.norm(away))
        u = away / norm if norm > 0 else np.eye(f.shape[1])[0]
        moved = [g.copy() for g in w]
        moved[t][i] = centroid + (2 * reach + distance) * u
        d = _diff(_call(fn, w), _call(fn, moved), "one_point_matters")
        if not d > tol:
            raise PropertyFailure(
                f"one_point_matters: {_name(fn)} changed by only {d:.3g} (needs more than "
                f"{tol:.3g}) when point {i} of frame {t} moved to {2 * reach + distance:.3g} from the "
                f"centroid; minimal window: {_describe(w)}")
        least[0] = min(least[0], d)
        seen.add(w)

    _run(prop, strategy, max_examples, seed)
    return CheckResult(least[0], f"one_point_matters: {_name(fn)} passed on {seen.text()}, "
                                 f"one point of each moved outward: smallest change "
                                 f"{least[0]:.3g} (needs more than {tol:.3g})")


__all__ = ["SCALES", "TOLERANCE", "PropertyFailure", "CheckResult", "windows", "permutations", "permuted",
           "permutation_invariant", "agrees_with_reference", "measured_tolerance", "frame_order_matters",
           "one_point_matters"]

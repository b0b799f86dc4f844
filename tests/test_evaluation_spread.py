"""tpnet_ref.evaluation.spread: the per-case spread of a results cell (mean, 95 % bootstrap
interval, median), the cells and the per-case csv that use it."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tpnet_ref import evaluation as E
from tpnet_ref.evaluation import spread as S
from evaluation_helpers import fake_curves  # noqa: F401


def _skewed(n=60, seed=1):
    """Like the rollouts' E_p: most cases small, a few far off."""
    rng = np.random.default_rng(seed)
    return np.exp(rng.normal(-1.0, 1.6, n))


def test_same_values_same_interval_and_the_seed_matters():
    x = _skewed()
    a, b = E.bootstrap_ci(x), E.bootstrap_ci(x.copy())
    assert a == b                                           # deterministic, bit for bit
    assert E.bootstrap_ci(x, seed=1) != a                   # ... because of the fixed seed
    assert E.spread(list(x)) == E.spread(x)


@pytest.mark.parametrize("seed", range(5))
def test_interval_contains_the_mean_and_the_median_is_the_median(seed):
    x = _skewed(seed=seed)
    s = E.spread(x)
    assert s.lo < s.mean < s.hi and s.n == 60
    assert s.median == float(np.median(x)) and s.mean == float(x.mean())
    # a skewed sample: the mean's interval reaches further above the mean than below it
    assert s.hi - s.mean > s.mean - s.lo
    assert s.median < s.mean


def test_constant_values_give_a_zero_width_interval():
    s = E.spread(np.full(60, 0.25))
    assert (s.lo, s.hi, s.median, s.mean) == pytest.approx((0.25,) * 4)


def test_known_case_two_values_matches_the_binomial():
    """k ones among n values: a resample's mean is Binomial(n, k/n) / n, so the interval's ends
    are (up to the resampling noise) that distribution's 2.5 % and 97.5 % quantiles."""
    n, k = 60, 12
    x = np.r_[np.ones(k), np.zeros(n - k)]
    lo, hi = E.bootstrap_ci(x)
    p = k / n
    cdf = np.cumsum([math.comb(n, j) * p ** j * (1 - p) ** (n - j) for j in range(n + 1)])
    q_lo = np.searchsorted(cdf, 0.025) / n
    q_hi = np.searchsorted(cdf, 0.975) / n
    assert abs(lo - q_lo) <= 1 / n + 1e-12 and abs(hi - q_hi) <= 1 / n + 1e-12


def test_known_case_normal_sample_matches_the_normal_interval():
    """For a large normal sample the percentile interval is mean ± 1.96 s/√n to within a few %."""
    x = np.random.default_rng(3).normal(10.0, 2.0, 400)
    lo, hi = E.bootstrap_ci(x)
    half = 1.96 * x.std(ddof=1) / math.sqrt(x.size)
    assert (hi - lo) / 2 == pytest.approx(half, rel=0.06)
    assert (lo + hi) / 2 == pytest.approx(x.mean(), abs=0.1 * half)


def test_level_narrows_the_interval_and_bad_input_is_named():
    x = _skewed()
    lo95, hi95 = E.bootstrap_ci(x)
    lo50, hi50 = E.bootstrap_ci(x, level=0.5)
    assert lo95 < lo50 < hi50 < hi95
    with pytest.raises(ValueError, match="empty"):
        E.spread([])
    with pytest.raises(ValueError, match="1-D"):
        E.spread(np.ones((2, 3)))
    with pytest.raises(ValueError, match="level"):
        E.bootstrap_ci(x, level=1.5)
    lo, hi = E.bootstrap_ci(np.r_[x, np.inf])                # not finite: no interval
    assert math.isnan(lo) and math.isnan(hi)


def test_a_cell_and_its_format():
    x = np.r_[np.full(50, 0.1), np.full(10, 5.0)]
    s = E.spread(x)
    assert E.report.cell(x) == f"{E.report.fmt_err(s.mean)} [{E.report.fmt_err(s.lo)}, " \
                               f"{E.report.fmt_err(s.hi)}] med 0.100"
    assert E.fmt_spread(E.spread([0.5])) == "0.500"             # one case: the mean alone
    assert E.report.cell(np.r_[x, np.nan]).startswith("– [–, –]")


def test_tables_carry_the_spread_and_the_csv_holds_every_case(tmp_path):
    curves = fake_curves()
    rng = np.random.default_rng(0)
    for c in curves:                                            # 3 cases that differ
        for k in c.err:
            c.err[k] = c.err[k] * rng.uniform(0.5, 2.0, (3, 1))
    row = next(r for r in E.results_tables(curves).splitlines() if "copy last" in r)
    e = curves[0].err["Ep_squared"][:, 39]
    assert row.split(" | ")[2] == E.report.cell(e)
    assert " med " in row and "[" in row
    rep = E.Report(command="tpnet eval --baselines-only", n_cases=3, horizon=90, source="test",
                   curves=curves)
    text = E.write_results(rep, tmp_path, plots=False).read_text()
    assert "bootstrap interval" in text and "eval_cases.csv" in text
    lines = (tmp_path / "eval_cases.csv").read_text().splitlines()
    assert lines[0].startswith("group,method,m,ordering,case,step,Ep_squared")
    assert len(lines) == 1 + 2 * 3 * 2                  # 2 names x 3 cases x (40, 80), "given"
    got = [float(r.split(",")[6]) for r in lines[1:] if r.startswith("test,copy last,4,given")
           and r.split(",")[5] == "40"]
    np.testing.assert_allclose(got, e, rtol=1e-5)


def test_distribution_plot(tmp_path):
    pytest.importorskip("matplotlib")
    from tpnet_ref.evaluation import plots as P
    curves = fake_curves() + fake_curves(m=3)
    path = P.plot_spread(curves, tmp_path / "s.png")
    assert path.stat().st_size > 10_000
    with pytest.raises(ValueError):
        P.plot_spread([], tmp_path / "none.png")

"""tpnet_ref.testing's report and defaults (issue 47): each check returns its figure with a one-line
``report`` of what it checked, and the kit's default windows make no tpnet_ref warning when
``tpnet_ref.predict`` itself is the function checked."""
from __future__ import annotations

import warnings

import pytest

pytest.importorskip("hypothesis")

import tpnet_ref  # noqa: E402
from tpnet_ref import testing  # noqa: E402


@pytest.fixture(scope="module")
def model():
    return tpnet_ref.load(engine="numpy")


def test_checks_report_what_they_checked_and_predict_warns_nothing(model):
    def predict(window):
        return tpnet_ref.predict(window, model=model)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        inv = testing.permutation_invariant(predict, max_examples=8, seed=1)
        order = testing.frame_order_matters(predict, max_examples=4, seed=1)
        point = testing.one_point_matters(predict, max_examples=4, seed=1)
    assert [str(w.message) for w in caught] == []
    assert inv == 0.0 and order > 0 and point > 0                     # still the figures
    assert inv.report.startswith("permutation_invariant: predict passed on ")
    assert "windows (m=4, N=" in inv.report and "largest change 0 (tolerance 0)" in inv.report
    assert order.report.startswith("frame_order_matters: predict passed on 4 windows")
    assert "smallest change" in point.report and "\n" not in point.report


def test_agreement_reports_its_units(model):
    frames = testing.windows(m=4, n=(5, 12), normalized=True)
    r = testing.agrees_with_reference(lambda w: model.predict(w, normalized=True), model,
                                      tol=1e-4, windows=frames, normalized=True,
                                      max_examples=3, seed=2)
    assert r <= 1e-4 and "model coordinates from the float64 reference" in r.report
    assert "passed on 3 windows (m=4, N=" in r.report

"""``tpnet_ref.sim.plot.show``: a PNG of one trajectory; matplotlib is the ``plot`` extra."""
from __future__ import annotations

import sys

import pytest

from tpnet_ref.extras import MissingExtraError
from tpnet_ref.sim import simulate
from tpnet_ref.sim.plot import show


def test_show_writes_a_png(tmp_path):
    pytest.importorskip("matplotlib")
    traj = simulate(1.3, 225.0, 30.0, 35.0, 40, include_initial=True)
    path = tmp_path / "t.png"
    show(traj, str(path), every=4, title="t")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_missing_matplotlib_names_the_plot_extra(tmp_path, monkeypatch):
    traj = simulate(1.3, 225.0, 30.0, 35.0, 4)
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(MissingExtraError, match=r"tpnet-ref\[plot\]"):
        show(traj, str(tmp_path / "t.png"))
    assert not (tmp_path / "t.png").exists()

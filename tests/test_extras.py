"""tpnet_ref.extras: a missing optional dependency is one line naming the extra to install."""
from __future__ import annotations

import pytest

from tpnet_ref.cli import main
from tpnet_ref.extras import EXTRAS, MissingExtraError, require


def test_require_returns_the_module():
    import json
    assert require("json", "metrics") is json


def test_missing_module_names_the_extra_in_one_line():
    with pytest.raises(MissingExtraError) as info:
        require("no_such_module_xyz.sub", "sim")
    msg = str(info.value)
    assert "pip install 'tpnet-ref[sim]'" in msg and "no_such_module_xyz" in msg
    assert "\n" not in msg and isinstance(info.value, ImportError)


def test_every_extra_named_in_code_is_declared_in_pyproject():
    import tomllib
    from pathlib import Path
    declared = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())
    extras = declared["project"]["optional-dependencies"]
    assert set(EXTRAS) <= set(extras)


def test_cli_reports_a_missing_extra_in_one_line(monkeypatch, capsys, tmp_path):
    import tpnet_ref.sim.scene as scene

    def missing(*a, **k):
        raise MissingExtraError("the soft-body simulator needs pymunk, which is not installed: "
                                "pip install 'tpnet-ref[sim]'")
    monkeypatch.setattr(scene, "simulate", missing)
    rc = main(["sim", "run", "-o", str(tmp_path / "t.npy"), "--steps", "2"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "tpnet-ref[sim]" in err[0]

"""The layers of docs/architecture.md hold: import-linter's contracts in pyproject.toml
([tool.importlinter]) are checked on every run, so an upward import or a cycle fails the suite."""
from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def test_import_contracts_are_kept():
    exe = shutil.which("lint-imports", path=str(Path(sys.executable).parent))
    if exe is None:
        pytest.fail("lint-imports not installed: pip install -e '.[test]' (import-linter)")
    r = subprocess.run([exe, "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-2000:]
    assert "0 broken" in r.stdout


def test_bench_keeps_twelve_scripts_at_most_and_nothing_patches_sys_path():
    """bench/ holds the measurements the docs cite (at most 12 top-level files, the rest in
    bench/probes/); no script of bench/, tools/ or the package edits ``sys.path``."""
    top = sorted(p.name for p in (ROOT / "bench").glob("*.py"))
    assert len(top) <= 12, top
    patched = [str(p.relative_to(ROOT)) for d in ("bench", "tools", "tpnet_ref")
               for p in (ROOT / d).rglob("*.py")
               if "sys.path.insert" in p.read_text() or "sys.path.append" in p.read_text()]
    assert patched == []


def test_model_module_stays_near_300_lines():
    """TPNet's module keeps the model a user holds; the rollout's loop (recursive.py) and the
    point order (point_order.py) live beside it."""
    assert len((ROOT / "tpnet_ref" / "model.py").read_text().splitlines()) <= 330

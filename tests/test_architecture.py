"""The plan of docs/architecture.md holds: import-linter's contracts in pyproject.toml
([tool.importlinter]) are checked on every run, so an upward import or a cycle fails the suite;
the package's tree is the one the page draws, file for file; the old module paths still import."""
from __future__ import annotations

import ast
import importlib
import re
import shutil
import subprocess
import sys
import warnings
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
    """TPNet's module keeps the model a user holds; the rollout's loop (engines/rollout.py) and
    the point order (point_order.py) live beside it."""
    assert len((ROOT / "tpnet_ref" / "model.py").read_text().splitlines()) <= 330


PACKAGE = ROOT / "tpnet_ref"


def _entries(folder: Path) -> set[str]:
    """What a folder of the package holds: its modules and subfolders (no caches, no data)."""
    return {p.name + ("/" if p.is_dir() else "") for p in folder.iterdir()
            if p.name != "__pycache__" and (p.is_dir() or p.suffix == ".py")}


def _drawn_tree() -> dict[str, set[str]]:
    """docs/architecture.md's tree of tpnet_ref/: folder (relative, "" the root) -> entries."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    block = text[text.index("```\ntpnet_ref/\n") + len("```\ntpnet_ref/\n"):]
    block = block[:block.index("```")]
    tree: dict[str, set[str]] = {"": set()}
    stack: list[str] = []
    for line in block.splitlines():
        m = re.match(r"^((?:│   |    )*)[├└]── (\S+)", line)
        if not m:
            continue
        depth = len(m.group(1)) // 4
        name = m.group(2)
        del stack[depth:]
        tree.setdefault("/".join(stack), set()).add(name)
        if name.endswith("/"):
            stack.append(name.rstrip("/"))
    return tree


def test_the_root_shows_the_plan_in_at_most_17_entries():
    """``ls tpnet_ref/``: the model a user holds and its foundations, then one folder per part."""
    assert len(_entries(PACKAGE)) + 1 <= 17, sorted(_entries(PACKAGE))      # + py.typed


def test_architecture_md_draws_every_module_where_it_is():
    tree = _drawn_tree()
    for folder, drawn in tree.items():
        have = _entries(PACKAGE / folder)
        if folder:                       # a folder's __init__.py may be drawn or not
            drawn, have = drawn - {"__init__.py"}, have - {"__init__.py"}
        assert drawn == have, (folder or "tpnet_ref/", sorted(drawn ^ have))
    folders = {str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob("*")
               if p.is_dir() and p.name != "__pycache__" and (p / "__init__.py").exists()}
    missing = folders - set(tree) - {"weights/shipped"}          # package data, drawn whole
    assert not missing, missing


def test_the_old_module_paths_import_with_a_deprecation_warning():
    """Each old path (``tpnet_ref.heads``, ``tpnet_ref.blas``, ...) gives the names of the
    modules that hold them now, renamed ones included; kept for one release."""
    import tpnet_ref

    for old, homes in tpnet_ref._MOVED.items():
        sys.modules.pop(f"tpnet_ref.{old}", None)
        try:
            with pytest.warns(DeprecationWarning, match=f"tpnet_ref.{old} has moved to"):
                mod = importlib.import_module(f"tpnet_ref.{old}")
        except ImportError:              # its new home needs an extra not installed here
            continue
        try:
            for home in homes:
                new = importlib.import_module(f"tpnet_ref.{home}")
                for name in getattr(new, "__all__", []):
                    assert getattr(mod, name) is getattr(new, name), (old, name)
        finally:
            sys.modules.pop(f"tpnet_ref.{old}", None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        from tpnet_ref.crosscheck import read_vectors, write_vectors
        from tpnet_ref.conformance.vectors import (read_conformance_vectors,
                                                   write_conformance_vectors)
        assert (read_vectors, write_vectors) == (read_conformance_vectors,
                                                 write_conformance_vectors)
        sys.modules.pop("tpnet_ref.crosscheck", None)


def _modules() -> list[Path]:
    return sorted(PACKAGE.rglob("*.py"))


def test_no_private_name_is_imported_across_modules():
    found = []
    for path in _modules():
        for n in ast.walk(ast.parse(path.read_text())):
            if isinstance(n, ast.ImportFrom) and (n.level or (n.module or "").startswith("tpnet_ref")):
                private = [a.name for a in n.names
                           if a.name.startswith("_") and not a.name.startswith("__")]
                if private or any(part.startswith("_") for part in (n.module or "").split(".")):
                    found.append(f"{path.relative_to(ROOT)}:{n.lineno} {private or n.module}")
    assert found == []


def test_no_function_over_100_lines_outside_compiled_kernels_and_argument_parsers():
    long = []
    for path in _modules():
        for n in ast.walk(ast.parse(path.read_text())):
            if not isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            compiled = any("njit" in ast.unparse(d) or "intrinsic" in ast.unparse(d)
                           for d in n.decorator_list)
            parser = path.parent.name == "cli" and n.name.lstrip("_").startswith("add")
            if n.end_lineno - n.lineno + 1 > 100 and not (compiled or parser):
                long.append(f"{path.relative_to(ROOT)}:{n.lineno} {n.name}")
    assert long == []


def test_no_module_over_about_600_lines():
    sizes = {str(p.relative_to(ROOT)): len(p.read_text().splitlines()) for p in _modules()}
    assert {k: v for k, v in sizes.items() if v > 620} == {}

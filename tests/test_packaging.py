"""The built wheel on its own: it installs NumPy, h5py and threadpoolctl only, holds the default
m = 4 weights, predicts out of the box, and names the extra a command needs.

Builds the wheel from this checkout and installs it into a fresh virtual environment (about a
minute, mostly pip fetching NumPy and h5py), so it is marked slow; CI runs it.
"""
from __future__ import annotations

import os
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import pytest

from tpnet_ref.weights.shipped import SHIPPED_SIZES

ROOT = Path(__file__).resolve().parents[1]
OPTIONAL = ("numba", "llvmlite", "scipy", "pymunk", "torch", "matplotlib", "tqdm", "onnxruntime",
            "cv2")


def _run(cmd: list[str], **kw) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "TPNET_WEIGHTS_DIR")}
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env, **kw)


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    r = _run([sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps",
              "--no-build-isolation", "-q", "-w", str(out)])
    assert r.returncode == 0, r.stderr[-2000:]
    (whl,) = out.glob("tpnet_ref-*.whl")
    return whl


def test_wheel_holds_the_m4_weights_and_no_other(wheel):
    """The default model and the reduced sizes (``load(size=...)``), as files, not links; the
    m = 3 and 5 ablation models stay out."""
    names = zipfile.ZipFile(wheel).namelist()
    shipped = ["tpnet-m4.h5"] + [f"tpnet-m4-{s}.h5" for s in SHIPPED_SIZES]
    assert sorted(n for n in names if n.endswith(".h5")) == \
        sorted(f"tpnet_ref/weights/shipped/{n}" for n in shipped)
    for n in shipped:
        info = zipfile.ZipFile(wheel).getinfo(f"tpnet_ref/weights/shipped/{n}")
        assert info.file_size == (ROOT / "weights" / n).stat().st_size    # the file, not a link
    meta = zipfile.ZipFile(wheel).read(
        next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
    core = [ln.split(":", 1)[1].strip() for ln in meta.splitlines()
            if ln.startswith("Requires-Dist:") and "extra ==" not in ln]
    assert sorted(c.split(">")[0].split("=")[0].strip() for c in core) == \
        ["h5py", "numpy", "threadpoolctl"]


@pytest.mark.slow
def test_wheel_alone_predicts_in_a_fresh_venv_and_names_missing_extras(wheel, tmp_path):
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    py = str(env_dir / "bin" / "python")
    r = _run([py, "-m", "pip", "install", "-q", str(wheel)])
    assert r.returncode == 0, r.stderr[-2000:]

    # the README's deployment snippet, run away from the checkout
    code = ("import sys, warnings, numpy as np, tpnet_ref; "
            "warnings.simplefilter('error'); "          # the example window is in range
            "w = tpnet_ref.example_window(); "
            "y = tpnet_ref.predict(w); "
            "assert w.shape == (4, 30, 2) and y.shape == (30, 2) and np.isfinite(y).all(), y; "
            "h = tpnet_ref.predict(w, tpnet_ref.load(size='half')); "     # point sets: compare
            "assert np.abs(h.mean(0) - y.mean(0)).max() < 0.5, h; "          # the centroids
            "assert tpnet_ref.load().engine == 'numpy'; "      # no numba: the NumPy engine
            "print(tpnet_ref.load().meta['path']); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in "
            f"{OPTIONAL!r}))")
    r = _run([py, "-c", code], cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    path, imported = r.stdout.strip().splitlines()[-2:]
    assert "site-packages/tpnet_ref/weights/shipped/tpnet-m4.h5" in path
    assert imported == "[]"

    r = _run([py, "-m", "pip", "list", "--format=freeze"])
    installed = {ln.split("==")[0].lower() for ln in r.stdout.splitlines()}
    assert not installed & set(OPTIONAL), installed & set(OPTIONAL)
    assert not {n for n in installed if n.startswith("opencv")}, installed

    # the camera path's NumPy-only parts work without OpenCV; reading an image names the extra
    code = ("import numpy as np; from tpnet_ref.observe import Camera, drop_outliers, "
            "frames_at_model_rate, points_from_mask; a = np.arange(30) * np.pi / 15; "
            "ring = np.c_[20 + 2 * np.sin(a), 20 + 2 * np.cos(a)]; "
            "print(Camera(0, 640, 640).to_world([[0, 640]]).tolist(), "
            "len(drop_outliers(np.r_[ring, [[5, 5]]]))); "
            "points_from_mask(np.ones((8, 8)), Camera(0, 8, 8))")
    r = _run([py, "-c", code], cwd=tmp_path)
    assert "[[1.0, 1.0]] 30" in r.stdout, r.stdout + r.stderr[-2000:]
    assert "pip install 'tpnet-ref[vision]'" in r.stderr.strip().splitlines()[-1], r.stderr

    tpnet = str(env_dir / "bin" / "tpnet")
    r = _run([tpnet, "demo"], cwd=tmp_path)
    assert r.returncode == 2
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "tpnet-ref[eval]" in r.stderr, r.stderr      # the one extra that covers the demo
    r = _run([tpnet, "export", "onnx", "-o", str(tmp_path / "m.onnx")], cwd=tmp_path)
    assert r.returncode == 2 and "pip install 'tpnet-ref[onnx]'" in r.stderr, r.stderr
    r = _run([tpnet, "--help"], cwd=tmp_path)
    assert r.returncode == 0 and "demo" in r.stdout

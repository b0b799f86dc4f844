"""Optional dependencies: each lives in an extra named after what it enables.

``require("numba", "metrics")`` imports and returns the module, or raises
:class:`MissingExtraError` (an ``ImportError``) whose one-line message names the extra to install.
The core (config, layers, model, checks, native weights file) needs NumPy and h5py only.
"""
from __future__ import annotations

import importlib
import importlib.util
from types import ModuleType

#: what each extra enables (pyproject.toml [project.optional-dependencies] has the pins)
EXTRAS: dict[str, str] = {
    "metrics": "the Chamfer metrics and the Numba inference engine (numba)",
    "sim": "the soft-body simulator (pymunk, numba)",
    "sim3d": "the 3-D scene, a soft ball in a box (MuJoCo)",
    "plot": "figures (matplotlib)",
    "eval": "the evaluation protocol and the demo (metrics, sim, plot, tqdm)",
    "train": "training (PyTorch, scipy, tqdm)",
    "onnx": "the ONNX export, tpnet export onnx (onnx)",
    "openvino": "the exported ONNX file run in OpenVINO (onnx, openvino)",
    "crosscheck": "framework cross-checks (PyTorch, onnx, onnxruntime)",
    "vision": "the camera path: masks, images and videos (OpenCV headless)",
    "box2d": "the Box2D 2.3 scene that validates the simulator (tpnet_ref.sim.box2d)",
    "kit": "the property checks of any TP-Net, tpnet_ref.testing (hypothesis)",
}


class MissingExtraError(ImportError):
    """An optional dependency is missing; the message names the extra that installs it."""


def require(module: str, extra: str, what: str | None = None) -> ModuleType:
    """``importlib.import_module(module)``, or a one-line :class:`MissingExtraError` naming
    ``extra`` (``pip install 'tpnet-ref[extra]'``)."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        need = what or EXTRAS.get(extra, extra)
        top = module.split(".")[0]
        raise MissingExtraError(
            f"{need} needs {top}, which is not installed: pip install 'tpnet-ref[{extra}]'"
        ) from exc


def require_all(modules: tuple[str, ...], extra: str, what: str) -> None:
    """Before any work: a one-line :class:`MissingExtraError` naming ``extra`` if any of
    ``modules`` is not installed (looked up, not imported), so a command does not fail halfway
    asking for one extra after another."""
    missing = [m for m in modules if importlib.util.find_spec(m) is None]
    if missing:
        raise MissingExtraError(f"{what} needs {', '.join(missing)}, which "
                                f"{'is' if len(missing) == 1 else 'are'} not installed: "
                                f"pip install 'tpnet-ref[{extra}]'")


#: what the ``eval`` extra installs (``tpnet eval``, ``tpnet demo``)
EVAL_MODULES = ("numba", "pymunk", "matplotlib", "tqdm", "scipy")

__all__ = ["require", "require_all", "MissingExtraError", "EXTRAS", "EVAL_MODULES"]

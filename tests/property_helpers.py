"""The implementations the property tests check, each as a function window -> next point set
(world units), for :mod:`tpnet_ref.testing`: the float64/float32 reference, the NumPy and the Numba
engine with the canonical sort off (or on), the PyTorch model, the ONNX export run by onnxruntime.

Bounded as tests/conftest.py asks: one TP-Net per (m, dtype) (its NumPy and Numba heads share
it), one PyTorch module per dtype, one ONNX session; the caches live in a :class:`Implementations`
that a module-scoped fixture clears after the module.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from tpnet_ref.engines import reference
from tpnet_ref.checks import check_windows
from tpnet_ref.model import TPNet, TPNetConfig, init_random

#: the m the invariance tests draw windows with (1 frame, the shortest time order, the released 4)
MS = [1, 2, 4]
SEED = 21
#: the suite's TP-Net: the released structure at a quarter of every width (the shipped
#: ``size="quarter"`` shape, 0.45 M parameters), so that a property runs many windows quickly;
#: ``bench/probes/permutation_rounding.py`` measures the released shape
QUARTER = dataclasses.replace(TPNetConfig(), mlp1=(16, 16), mlp2=(32, 64, 128),
                              global_features=32, lstm_units=(128, 64, 64))


def onnx_export_session(model: TPNet, n_points: int):
    """An onnxruntime session of ``model``'s ONNX export (float32, ``n_points`` per frame).

    The one place the tests export ONNX (:func:`tpnet_ref.conformance.onnx_peer.onnx_session`:
    ``build_onnx`` + onnxruntime): another export path replaces it here without touching a
    test."""
    from tpnet_ref.conformance.onnx_peer import onnx_session
    return onnx_session(model, n_points, threads=1)


class Implementations:
    """Lazily built models, one per (m, dtype), and the window -> point set functions on them."""

    def __init__(self, config: TPNetConfig = QUARTER) -> None:
        self.base = {dt: init_random(config, seed=SEED, dtype=dt) for dt in ("float32", "float64")}
        self._models: dict = {}
        self._torch: dict = {}
        self._onnx: dict = {}

    def clear(self) -> None:
        self._models.clear()
        self._torch.clear()
        self._onnx.clear()
        self.base.clear()

    def model(self, m: int, dtype: str) -> TPNet:
        """The (m, dtype) TP-Net with the Numba head first (windows of 1..8) and the NumPy head
        last, canonical sort on; :meth:`TPNet.with_point_sort` copies share its parameters."""
        if (m, dtype) not in self._models:
            base = self.base[dtype]
            self._models[m, dtype] = TPNet(dataclasses.replace(base.config, m=m), base.params,
                                           dtype, engine="numba")
        return self._models[m, dtype]

    # ------------------------------------------------------------ window -> points
    def reference(self, dtype: str):
        base = self.base[dtype]

        def reference_forward(window):
            cfg = dataclasses.replace(base.config, m=len(window))
            return reference.forward(cfg, base.params, window)
        return reference_forward

    def engine(self, engine: str, dtype: str, sort: bool = False):
        """``predict`` on the ``engine`` ("numpy" or "numba": its feature extractor and head),
        the canonical sort on or off: the window's features, that head, denormalised (what
        ``predict`` runs)."""
        def predict(window):
            model = self.model(len(window), dtype)
            model.sort_points = sort       # the flag canonical_points reads; nothing else caches it
            try:
                head = next(h for h in model.heads if h.name == engine)
                # each engine's own feature extractor: the compiled one with the numba head
                frames, _ = check_windows([window], model.config.m, model.config.dim,
                                          model.dtype)
                feats = model.frame_features(*model.canonical_points(frames),
                                             1 if engine == "numba" else None)
                return model.denormalize(head(feats.reshape(1, model.config.m, -1))[0])
            finally:
                model.sort_points = True
        predict.__qualname__ = f"{engine}_engine_{'sorted' if sort else 'unsorted'}_{dtype}"
        return predict

    def torch_module(self, dtype: str):
        if dtype not in self._torch:
            from tpnet_ref.training.torch_model import TorchTPNet
            self._torch[dtype] = TorchTPNet.from_numpy(self.base[dtype]).eval()
        return self._torch[dtype]

    def torch(self, dtype: str):
        """:class:`tpnet_ref.training.torch_model.TorchTPNet` (no sort of its own): ``forward`` on equal
        frames, ``frame_features`` frame by frame and ``sequence_head`` on ragged ones."""
        import torch
        net, base = self.torch_module(dtype), self.base[dtype]

        def torch_model(window):
            x = [torch.from_numpy(base.normalize(np.asarray(f, dtype=dtype))) for f in window]
            threads = torch.get_num_threads()
            torch.set_num_threads(1)          # small products: a second thread only waits
            try:
                with torch.no_grad():
                    if len({len(f) for f in x}) == 1:
                        y = net(torch.stack(x)[None])[0]
                    else:
                        g = torch.cat([net.frame_features(f[None]) for f in x])
                        y = net.sequence_head(g[None])[0]
            finally:
                torch.set_num_threads(threads)
            return base.denormalize(y.numpy())
        return torch_model

    def onnx(self, n_points: int):
        """The m = 4 float32 network's ONNX export under onnxruntime (frames of ``n_points``)."""
        if n_points not in self._onnx:
            self._onnx[n_points] = onnx_export_session(self.model(4, "float32"), n_points)
        sess, base = self._onnx[n_points], self.base["float32"]

        def onnx_export(window):
            x = base.normalize(np.stack(window).astype(np.float32))[None]
            return base.denormalize(sess.run(None, {"window": x})[0][0])
        return onnx_export

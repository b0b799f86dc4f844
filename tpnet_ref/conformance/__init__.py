"""Conformance: where does a port diverge from the reference, layer by layer?

:func:`tpnet_ref.engines.reference.forward` records every named intermediate of the forward pass
(``trace=``); this package turns those traces into files another implementation can test
against and compares a port's own trace with them, naming the first layer that disagrees
(docs/crosscheck.md; ``tpnet vectors``, ``tpnet crosscheck``):

* :mod:`.layer_names`  the layers in forward order, their shapes and meanings
* :mod:`.tolerances`   the reference's trace of a window (``trace``), each layer's float32
                       tolerance measured from rounding (``measure_tolerances``)
* :mod:`.cases`        the conformance cases (scene windows, shuffled points, ragged N, the
                       edges of the trained range, a short rollout)
* :mod:`.vectors`      the vectors' files, ``DIR/manifest.json`` + ``DIR/vectors.npz``
                       (``write_conformance_vectors`` / ``read_conformance_vectors``), and a
                       port's trace file checked against them (``load_trace``)
* :mod:`.compare`      per case, the first layer beyond its tolerance and where it starts
* :mod:`.report`       ``tpnet crosscheck``'s output, text or JSON
* :mod:`.traces`       the traces of PyTorch (hooks), ONNX (marked outputs), Keras and the engines
* :mod:`.onnx_peer`    the same network as an ONNX graph (``tpnet export onnx``) and the
                       onnxruntime peer

NumPy only, but for the framework traces and the ONNX peer (their extras); nothing is imported
here.
"""

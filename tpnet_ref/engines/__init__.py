"""The engines: the ways to run TP-Net, behind one interface (docs/architecture.md, "Heads").

* :mod:`.interface`     the :class:`~tpnet_ref.engines.interface.Head` interface; which head runs
                        a batch (``build``, ``for_batch``), the engine names
* :mod:`.reference`     the forward pass written to be read: the oracle every engine is tested
                        against; :mod:`.layers`, the layers as NumPy functions it is built from
* :mod:`.numpy_engine`  the NumPy engine: the feature extractor every engine uses, the NumPy head
* :mod:`.numba_engine`  the Numba engine (``engine="numba"``; the ``metrics`` extra), its kernels
                        by stage: :mod:`.numba_products` and :mod:`.numba_tiles` (the products,
                        built of :mod:`.numba_codegen`'s IR), :mod:`.numba_lstm` (the
                        prediction network), :mod:`.numba_features` (the feature extractor); its
                        first pass over a window (:mod:`.numba_checks`: the input checks' verdict,
                        the canonical order), a rollout's steps in one call (:mod:`.numba_rollout`)
                        and a prediction's network in one call (:mod:`.numba_predict`)
* :mod:`.specialised`   the scene-specialised head (``model.specialize``); its pass on one
                        window in :mod:`.specialised_window`
* :mod:`.unit_order`    each layer's units laid out most used first
* :mod:`.rollout`       the rollout's loop, on whichever engine runs the model
* :mod:`.blas`          the BLAS under NumPy, always one thread; :mod:`.thread_policy` (one thread
                        or two, same bits), :mod:`.load_monitor` (other processes' cores),
                        :mod:`.batch_split` (a large batch in chunks on a pool of threads)
* :mod:`.compile_watch` the Numba compilations a command announces

Every engine gives the result of :mod:`tpnet_ref.engines.reference` up to rounding; only speed and
the order of the sums differ. Nothing is imported here: the Numba engine loads numba when a model
asks for it. A new engine is one module here, a ``Head``, and a line in ``interface.build``.
"""

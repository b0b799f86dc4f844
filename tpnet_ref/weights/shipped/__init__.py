"""Package data: the default m = 4 weights (a link to weights/tpnet-m4.h5 in the repository;
the file itself inside a built wheel) and an example window to start from.

``example_window.npy``: ``tpnet_ref.sim.simulate(1.3, 225.0, 28.6, 32.5)[0:16:4]``, a scene of the
training grid (force 1.3, angle 225 degrees, start (28.6, 32.5); not a held-out test case),
rows 0, 4, 8, 12: ``(4, 30, 2)`` float64, world units (``tests/test_shipped_weights.py`` checks
it against the simulator)."""

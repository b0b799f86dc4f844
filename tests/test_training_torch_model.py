"""The PyTorch TP-Net's training pieces: template head, the shape and matched-distance loss terms."""
from __future__ import annotations

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import tpnet_ref  # noqa: E402
from tpnet_ref.training import loop as L  # noqa: E402
from tpnet_ref.training import step as ST  # noqa: E402
from tpnet_ref.training import recipe as R  # noqa: E402
from tpnet_ref.training.torch_model import TorchTPNet  # noqa: E402
from training_helpers import dataset, tiny_recipe  # noqa: E402,F401


def test_template_head_init_outputs_a_ring_of_the_body_size(dataset):
    """--head-init template: before any step the network's output is (close to) a ring of the
    rest radius around the data's mean position, whatever the input."""
    r = tiny_recipe(head_init="template")
    data = R.WindowData(dataset, r.val_fraction, r.split_seed)
    torch.manual_seed(0)
    net = TorchTPNet(r.tpnet_config)
    L.init_head_template(net, data)
    x, _ = data.gather(data.train_win[:8])
    with torch.no_grad():
        y = net(torch.from_numpy(x)).numpy().astype(np.float64)        # (8, 30, 2)
    f0 = data.frames[:, 0].astype(np.float64)
    radius = np.linalg.norm(f0 - f0.mean(1, keepdims=True), axis=-1).mean()
    c = y.mean(1, keepdims=True)
    r_out = np.linalg.norm(y - c, axis=-1)
    assert abs(r_out.mean() - radius) < 0.25 * radius                   # a ring of the body's size
    assert np.median(np.abs(r_out / radius - 1)) < 0.5                  # ... not a few stray points
    mean_pos = data.frames.reshape(-1, 2).mean(0)
    assert np.abs(c[:, 0] - mean_pos).max() < 0.05                        # near the data's middle
    # the default initialisation gives no such ring
    torch.manual_seed(0)
    plain = TorchTPNet(r.tpnet_config)
    with torch.no_grad():
        yp = plain(torch.from_numpy(x)).numpy()
    rp = np.linalg.norm(yp - yp.mean(1, keepdims=True), axis=-1)
    assert abs(rp.mean() - radius) > 0.5 * radius


def test_shape_term_is_the_released_shape_error_and_is_optimised(dataset, tmp_path):
    """--shape-weight λ adds λ·Σ w_i·E_s (released shape error of the centred sets): the torch
    term equals tpnet_ref.metrics.shape_error, is invariant to translating either set, and the
    run logs val_es1 / val_esK."""
    from tpnet_ref.metrics import shape_error
    from tpnet_ref.training.torch_model import chamfer_shape

    rng = np.random.default_rng(0)
    p, q = rng.uniform(0, 1, (5, 3, 30, 2)), rng.uniform(0, 1, (5, 3, 27, 2))
    ours = chamfer_shape(torch.from_numpy(p), torch.from_numpy(q)).numpy()
    ref = np.asarray(shape_error(q, p, variant="released")).mean(0)
    np.testing.assert_allclose(ours, ref, rtol=1e-10)
    shifted = chamfer_shape(torch.from_numpy(p + 0.3), torch.from_numpy(q - 0.1)).numpy()
    np.testing.assert_allclose(shifted, ours, rtol=1e-10)

    r = tiny_recipe(epochs=1, shape_weight=2.0, rollout=3)
    data = R.WindowData(dataset, r.val_fraction, r.split_seed)
    x, y = (torch.from_numpy(a) for a in data.gather(data.train_win[:8]))
    net = TorchTPNet(r.tpnet_config)
    with torch.no_grad():
        plain = float(ST.loss_fn(net, x, y, 3, 9.0))
        both = float(ST.loss_fn(net, x, y, 3, 9.0, 2.0))
        es = chamfer_shape(net.rollout(x, 3), y[:, :3]).numpy()
    assert both == pytest.approx(plain + 2.0 * float(es @ np.array([9.0, 1.0, 1.0])), rel=1e-5)
    L.train(dataset, tmp_path / "run", r, threads=1, progress=False)
    log = [json.loads(s) for s in (tmp_path / "run" / L.LOG_NAME).read_text().splitlines()]
    assert {"val_es1", "val_es3", "val_cd1", "val_cd3"} <= set(log[0])
    with pytest.raises(ValueError, match="shape_weight"):
        tiny_recipe(shape_weight=-1.0)


def test_matched_distance_is_the_optimal_bijection_and_penalises_clumping():
    import itertools

    from tpnet_ref.training.torch_model import chamfer_released, matched_distance

    g = torch.Generator().manual_seed(0)
    p = torch.rand(4, 2, 6, 2, generator=g, dtype=torch.float64)
    q = torch.rand(4, 2, 6, 2, generator=g, dtype=torch.float64)
    got = matched_distance(p, q)
    assert got.shape == (2,)
    for s in range(2):
        brute = [2 * min(sum(float(torch.linalg.norm(p[b, s, k] - q[b, s, perm[k]]))
                             for k in range(6)) for perm in itertools.permutations(range(6)))
                 for b in range(4)]
        assert float(got[s]) == pytest.approx(np.mean(brute), rel=1e-12)
    assert (got >= chamfer_released(p, q) - 1e-12).all()       # Chamfer pairs need not be 1:1
    # two predictions on one target, one target uncovered: Chamfer sees half of the gap,
    # the matched distance all of it; the gradient moves a duplicate towards the free target
    ring = torch.tensor([[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]], dtype=torch.float64)
    clump = torch.tensor([[[0.0, 0.0], [1.0, 0.0], [1.0, 0.0]]], dtype=torch.float64,
                         requires_grad=True)
    assert float(chamfer_released(clump.detach(), ring)) == pytest.approx(1.0)
    em = matched_distance(clump, ring)
    assert float(em.detach()) == pytest.approx(2.0)
    em.backward()
    assert float(clump.grad[0, 1:, 0].min()) < 0                # one duplicate pushed to x = 2
    with pytest.raises(ValueError, match="equal shape"):
        matched_distance(p[:, :, :5], q)

"""The training ablations: the pushforward trick (``--grad-steps``: the first K − G
predictions of the K-step loss without gradient, the loss over the last G) and structured input
noise (``--noise-kind walk``: a random walk over the input frames)."""
from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tpnet_ref import cli  # noqa: E402
from tpnet_ref.training.torch_model import TorchTPNet, chamfer_released, chamfer_shape  # noqa: E402
from tpnet_ref.training import checkpoint as C  # noqa: E402
from tpnet_ref.training import loop as L  # noqa: E402
from tpnet_ref.training import native_export as NE  # noqa: E402
from tpnet_ref.training import precision as PR  # noqa: E402
from tpnet_ref.training import step as ST  # noqa: E402
from tpnet_ref.training import recipe as R  # noqa: E402
from training_helpers import dataset, tiny_recipe  # noqa: E402,F401


def _net_and_batch(dtype=torch.float32, k=6, seed=0):
    cfg = R.size_config("tiny")
    torch.manual_seed(seed)
    net = TorchTPNet(cfg).to(dtype)
    rng = np.random.default_rng(seed)
    x = torch.from_numpy(rng.uniform(0.2, 0.8, (5, cfg.m, cfg.n_out, cfg.dim))).to(dtype)
    y = torch.from_numpy(rng.uniform(0.2, 0.8, (5, k, cfg.n_out, cfg.dim))).to(dtype)
    return net, x, y


def _grad(net, loss):
    net.zero_grad(set_to_none=True)
    loss.backward()
    return torch.cat([p.grad.flatten() for p in net.parameters()])


# ------------------------------------------------------------------------------- pushforward
def test_grad_steps_zero_or_all_is_the_published_loss_bit_for_bit():
    """G = 0 and G = K compute today's loss exactly (the whole rollout's weighted terms, shape
    and matched ones included) and its gradient; so does G > K, which is what the curriculum's
    shorter rollouts see."""
    net, x, y = _net_and_batch()
    for k in (1, 3, 6):
        for sw, mw in ((0.0, 0.0), (2.0, 0.5)):
            today = net._loss(net.rollout(x, k), y[:, :k], 9.0, sw, mw)
            for g in (0, k, k + 2):
                assert torch.equal(ST.loss_fn(net, x, y, k, 9.0, sw, mw, grad_steps=g), today)
            g_today = _grad(net, today)
            for g in (0, k):
                assert torch.equal(_grad(net, ST.loss_fn(net, x, y, k, 9.0, sw, mw, g)), g_today)


@pytest.mark.parametrize("k, g", [(6, 2), (6, 5), (3, 1)])
def test_grad_steps_loss_and_gradient_are_the_manual_pushforward(k, g):
    """G < K: the loss and its gradient (float64) are those of K − G steps under no_grad, then
    G steps with gradient from the window they end in, every graded term with weight 1."""
    net, x, y = _net_and_batch(torch.float64, k=k)
    got = ST.loss_fn(net, x, y, k, 9.0, 2.0, 0.0, grad_steps=g)
    with torch.no_grad():
        early = net.rollout(x, k - g)
    window = torch.cat([x, early], dim=1)[:, -x.shape[1]:]
    pred = net.rollout(window, g)
    ref = chamfer_released(pred, y[:, k - g:]).sum() + 2.0 * chamfer_shape(pred, y[:, k - g:]).sum()
    assert float(got.detach()) == pytest.approx(float(ref.detach()), rel=1e-12)
    g_got, g_ref = _grad(net, got), _grad(net, ref)
    assert torch.allclose(g_got, g_ref, rtol=1e-10, atol=1e-13)
    # the full rollout with the same weights on the same steps has another gradient: the one
    # through the early predictions
    full = net.rollout(x, k)[:, k - g:]
    g_full = _grad(net, chamfer_released(full, y[:, k - g:]).sum()
                   + 2.0 * chamfer_shape(full, y[:, k - g:]).sum())
    assert float((g_full - g_ref).norm()) > 1e-6 * float(g_ref.norm())


def test_no_gradient_flows_through_the_early_predictions():
    """The early predictions carry no gradient; with K − G >= m the graded window is made of
    them alone, so the loss has no gradient with respect to the inputs at all."""
    net, x, y = _net_and_batch(k=6)
    pred = net.rollout(x, 6, grad_from=4)
    with torch.no_grad():
        full = net.rollout(x, 6)
    assert float((pred.detach() - full).abs().max()) < 1e-5    # the same predictions
    early = torch.autograd.grad(pred[:, :4].sum(), list(net.parameters()), allow_unused=True)
    assert all(gp is None or not gp.any() for gp in early)
    x.requires_grad_(True)
    loss = ST.loss_fn(net, x, y, 6, 9.0, grad_steps=2)           # m = 4 = K − G
    assert not torch.autograd.grad(loss, x)[0].any()
    loss = ST.loss_fn(net, x, y, 6, 9.0, grad_steps=3)           # K − G = 3: x's last frame is
    gx = torch.autograd.grad(loss, x)[0]                        # in the window, as data
    assert gx[:, :3].abs().max() == 0 and gx[:, 3].abs().max() > 0
    with pytest.raises(ValueError, match="grad_from must be in 0..5"):
        net.rollout(x, 6, grad_from=6)


def test_grad_steps_in_bf16_and_under_torch_compile():
    """The pushforward loss keeps the float32 loss in bf16 autocast, and traces with
    ``torch.compile`` (eager backend) to the eager loss and gradient."""
    net, x, y = _net_and_batch(k=4)
    eager = PR.step_loss(net, "off", "float32")(x, y, 4, 9.0, 1.0, 0.0, 2)
    g_eager = _grad(net, eager)
    bf = PR.step_loss(net, "off", "bf16")(x, y, 4, 9.0, 1.0, 0.0, 2)
    assert bf.dtype == torch.float32
    assert float(bf.detach()) == pytest.approx(float(eager.detach()), rel=0.02)
    compiled = PR.step_loss(net, "eager", "float32")(x, y, 4, 9.0, 1.0, 0.0, 2)
    assert float(compiled.detach()) == pytest.approx(float(eager.detach()), rel=1e-6)
    assert torch.allclose(_grad(net, compiled), g_eager, rtol=1e-4, atol=1e-6)


def test_grad_steps_is_validated_and_old_recipes_load():
    assert R.Recipe(rollout=16, grad_steps=4).grad_steps == 4
    for bad in (-1, 9):
        with pytest.raises(ValueError, match=r"grad_steps must be in 0..rollout \(8\)") as info:
            R.Recipe(grad_steps=bad)
        assert "\n" not in str(info.value)
    old = dataclasses.asdict(tiny_recipe())
    del old["grad_steps"], old["noise_kind"]               # a checkpoint from before them
    r = R.Recipe.from_dict(json.loads(json.dumps(old)))
    assert (r.grad_steps, r.noise_kind) == (0, "iid") and r == tiny_recipe()


# ------------------------------------------------------------------------------- input noise
def _today(x, std, seed, step):
    """The i.i.d. noise of ``Trainer.batch`` before ``noise_kind`` existed."""
    g = torch.Generator().manual_seed(seed * 1_000_003 + step)
    return x + std * torch.randn(x.shape, generator=g, dtype=x.dtype)


def test_iid_noise_is_todays_bit_for_bit_and_zero_noise_changes_nothing():
    x = torch.from_numpy(np.random.default_rng(0).uniform(0, 1, (16, 4, 30, 2)).astype(np.float32))
    for seed, step in ((0, 0), (3, 17), (11, 9265)):
        assert torch.equal(ST.input_noise(x, 0.01, "iid", seed, step), _today(x, 0.01, seed, step))
    for kind in R.NOISE_KINDS:
        assert ST.input_noise(x, 0.0, kind, 3, 17) is x


def test_walk_noise_is_a_random_walk_over_the_input_frames():
    """Frame i's noise has std S·√((i+1)/m), the last frame S, a step between frames S/√m;
    the same (seed, step) draws the same noise, another step other noise."""
    m, s = 4, 0.01
    x = torch.zeros(4096, m, 30, 2, dtype=torch.float64)
    n = ST.input_noise(x, s, "walk", 3, 17)
    std = n.std(dim=(0, 2, 3)).numpy()
    np.testing.assert_allclose(std, s * np.sqrt((np.arange(m) + 1) / m), rtol=0.01)
    np.testing.assert_allclose(n.diff(dim=1).std(dim=(0, 2, 3)).numpy(), s / math.sqrt(m),
                               rtol=0.01)
    assert torch.equal(n, ST.input_noise(x, s, "walk", 3, 17))
    assert not torch.equal(n, ST.input_noise(x, s, "walk", 3, 18))
    # the same draws as the i.i.d. kind, summed over the frames
    iid = ST.input_noise(x, s, "iid", 3, 17)
    assert torch.allclose(n, iid.cumsum(dim=1) / math.sqrt(m), rtol=1e-12, atol=1e-16)
    with pytest.raises(ValueError, match="noise kind must be 'iid' or 'walk'"):
        ST.input_noise(x, s, "pink", 3, 17)


def test_noise_kind_is_validated():
    with pytest.raises(ValueError, match="noise_kind must be 'iid' or 'walk', got 'pink'") as info:
        R.Recipe(noise_kind="pink")
    assert "\n" not in str(info.value)


# ------------------------------------------------------------------------------- end to end
def test_a_run_with_both_ablations_is_stored_and_resumes_from_an_older_checkpoint(dataset,
                                                                                  tmp_path):
    """`tpnet train run --grad-steps 2 --noise-kind walk` (the curriculum: its shorter rollouts
    are graded whole) trains 20 steps; both reach the checkpoint's recipe; validation scores
    all K predictions; a checkpoint written before the two fields existed resumes as iid noise
    and all steps graded."""
    run = tmp_path / "run"
    argv = ["train", "run", dataset, "-o", str(run), "--size", "tiny", "--batch", "16",
            "--epochs", "4", "--pretrain-epochs", "0.5", "--ramp-epochs", "1", "--rollout", "4",
            "--grad-steps", "2", "--noise", "0.01", "--noise-kind", "walk", "--threads", "1",
            "--val-fraction", "0.2", "--max-steps", "20", "--log-every", "1", "--quiet"]
    assert cli.main(argv) == 0
    st = json.loads((run / C.SIDECAR_NAME).read_text())
    assert st["step"] == 20 and st["stopped"] == "max_steps"
    assert st["recipe"]["grad_steps"] == 2 and st["recipe"]["noise_kind"] == "walk"
    log = [json.loads(s) for s in (run / L.LOG_NAME).read_text().splitlines()]
    train = [rec for rec in log if rec["kind"] == "train"]
    assert {rec["rollout"] for rec in train} == {1, 2, 3, 4}
    assert all(math.isfinite(rec["loss"]) for rec in train)
    assert all("val_cd4" in rec for rec in log if rec["kind"] == "val")
    del st["recipe"]["grad_steps"], st["recipe"]["noise_kind"]
    (run / C.SIDECAR_NAME).write_text(json.dumps(st))
    res = L.train(dataset, run, resume=True, threads=1, progress=False, max_steps=21)
    assert res["step"] == 21 and res["recipe"]["grad_steps"] == 0
    assert res["recipe"]["noise_kind"] == "iid"


# ------------------------------------------------------------------ branches keep Adam's state
def test_init_optimizer_branches_with_the_parents_adam_state(dataset, tmp_path):
    """``--init-from RUN --init-optimizer``: the branch starts from the parent's weights AND
    Adam's moments and step counts (no fresh-Adam jolt), with its own recipe's constants;
    without a run directory's optimizer state it is refused in one line."""
    parent = tmp_path / "parent"
    L.train(dataset, parent, tiny_recipe(epochs=1), threads=1, progress=False, max_steps=3)
    payload, _ = C.load_checkpoint(parent)
    r = tiny_recipe(epochs=1, init_from=str(parent), init_optimizer=True, lr=5e-4, beta1=0.9)
    data = R.WindowData(dataset, r.val_fraction, r.split_seed)
    net, opt = L._build_network(r, "cpu", data, None, {})
    for name, p in net.state_dict().items():
        if isinstance(p, torch.Tensor):          # (the network's extra state is its config)
            assert torch.equal(p, payload["model"][name]), name
    got, want = opt.state_dict(), payload["optimizer"]
    assert got["state"].keys() == want["state"].keys()
    for k, st in want["state"].items():
        for key in ("exp_avg", "exp_avg_sq", "step"):
            assert torch.equal(got["state"][k][key], st[key]), (k, key)
    assert all(g["lr"] == 5e-4 and g["betas"] == (0.9, r.beta2) for g in opt.param_groups)
    _, fresh = L._build_network(dataclasses.replace(r, init_optimizer=False), "cpu", data, None, {})
    assert not fresh.state_dict()["state"]
    # a branch run trains on from there
    assert cli.main(["train", "run", dataset, "-o", str(tmp_path / "b"), "--size", "tiny",
                     "--init-from", str(parent), "--init-optimizer", "--epochs", "1", "--batch", "16",
                     "--max-steps", "2", "--val-fraction", "0.2", "--threads", "1",
                     "--quiet"]) == 0
    st = json.loads((tmp_path / "b" / "checkpoint.json").read_text())
    assert st["recipe"]["init_optimizer"] is True and st["step"] == 2
    with pytest.raises(ValueError, match="needs init_from"):
        tiny_recipe(init_optimizer=True)
    NE.export(parent, tmp_path / "w.h5")
    with pytest.raises(ValueError, match="weights file"):
        C.load_parent_optimizer(tmp_path / "w.h5")

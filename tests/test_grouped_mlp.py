"""The batched path's one-node ReLU MLP (``GroupedMLP.fused_batched``) against autograd's graph of the same products."""

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.noise import NormalActionNoise

from sb3_macb import MACB, MADDPG
from sb3_macb.common.grouped_mlp import GroupedMLP
from sb3_macb.envs.vec_tasks import make_task_vec_env


@pytest.fixture
def unfused():
    """A context that runs the batched path as autograd's graph of products, masks and activations."""

    class Switch:
        def __enter__(self):
            GroupedMLP.fused_batched = False

        def __exit__(self, *exc):
            GroupedMLP.fused_batched = True

    yield Switch()
    GroupedMLP.fused_batched = True


def _net(**kwargs) -> GroupedMLP:
    rng = np.random.default_rng(0)
    in_mask = (rng.random((6, 9)) < 0.6).astype(np.float32)
    out_mask = np.repeat(np.eye(3, dtype=np.float32), 2, axis=0)  # groups write disjoint outputs in pairs
    return GroupedMLP(in_mask, [32, 24], out_mask, generators=[th.Generator().manual_seed(1)], **kwargs)


@pytest.mark.parametrize("sum_groups", [False, True])
@pytest.mark.parametrize("groups", [None, slice(2, 5)])
@pytest.mark.parametrize("detach_params", [False, True])
def test_one_node_forward_and_gradients_equal_autograds_bit_for_bit(unfused, sum_groups, groups, detach_params):
    net = _net(sum_groups=sum_groups)
    n_groups = 6 if groups is None else 3
    x0 = th.randn(n_groups, 17, 9)
    results = []
    for fused in (True, False):
        net.zero_grad()
        x = x0.clone().requires_grad_(True)
        if fused:
            out = net(x, groups=groups, detach_params=detach_params)
        else:
            with unfused:
                out = net(x, groups=groups, detach_params=detach_params)
        assert ("BatchedReluMLP" in type(out.grad_fn).__name__) == fused  # (the switch chose the path)
        (out.square().sum() + out.sum()).backward()
        grads = [p.grad for p in net.parameters()]
        results.append((out.detach(), x.grad, grads))
    (out_f, xg_f, g_f), (out_u, xg_u, g_u) = results
    assert th.equal(out_f, out_u)
    with th.no_grad():  # without autograd the layers run as plain calls, with the same numbers
        plain = net(x0, groups=groups, detach_params=detach_params)
    assert plain.grad_fn is None and th.equal(plain, out_f)
    assert th.equal(xg_f, xg_u)
    if detach_params:
        assert all(g is None for g in g_f + g_u)
    else:
        assert all(a is not None and th.equal(a, b) for a, b in zip(g_f, g_u))
        # masked weights get no gradient on either path
        assert not g_f[0][net.in_mask.expand_as(g_f[0]) == 0].any()


def _pack(n_critics: int) -> MADDPG:
    """A pack of two 48-40 runs (one with MACB) on sparse Communicative Navigation; MATD3's settings with two critics."""
    seeds = [0, 1]
    settings: dict = dict(policy_kwargs=dict(net_arch=[48, 40]))
    if n_critics == 2:
        settings = dict(policy_kwargs=dict(net_arch=[48, 40], n_critics=2), policy_delay=2, target_policy_noise=0.2)
    return MADDPG(
        "MlpPolicy", make_task_vec_env("sb3_macb/CommunicativeNavigation-v0", 2, {"reward": "sparse"}), n_runs=2,
        run_seeds=seeds, exploration=[MACB(beta=0.8, k=16), None], batch_size=32, learning_starts=64, buffer_size=150,
        action_noise=[NormalActionNoise(np.zeros(5), 0.1 * np.ones(5)) for _ in seeds], device="cpu", **settings,
    )  # fmt: skip


@pytest.mark.parametrize("n_critics", [1, 2], ids=["maddpg", "matd3"])
def test_training_with_one_node_equals_training_with_autograds_graph(unfused, n_critics):
    # past the buffer's wrap (150 rows per run, 2 runs x 200 steps) and a count table's growth
    trained = []
    for fused in (True, False):
        model = _pack(n_critics)
        if fused:
            model.learn(400)
        else:
            with unfused:
                model.learn(400)
        assert model.replay_buffer.full
        trained.append([p.detach().clone() for p in model.policy.parameters()])
    assert len(trained[0]) > 10
    assert all(th.equal(a, b) for a, b in zip(*trained))

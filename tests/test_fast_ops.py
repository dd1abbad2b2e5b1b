"""PyTorch's private fast paths (sb3_macb.common.fast_ops) against their public fallbacks: the same numbers."""

import pytest
import torch as th
from toy_envs import Rendezvous
from torch import nn

from sb3_macb import MADDPG
from sb3_macb.common import fast_ops
from sb3_macb.common.block_adam import BlockAdam


def both(fn):  # type: ignore[no-untyped-def]
    """``fn()`` with the private fast paths, then with the public fallbacks."""
    results = []
    for private in (True, False):
        old, fast_ops.use_private = fast_ops.use_private, private
        try:
            results.append(fn())
        finally:
            fast_ops.use_private = old
    return results


def test_this_torch_offers_the_fast_paths():
    # (so that the comparisons below run the fast paths; a PyTorch without one still works, on the fallback;
    # oneDNN is compared with its fallback in test_maddpg.py and may be missing from a build)
    paths = fast_ops.describe()
    assert paths["foreach_lerp"] and paths["fused_adam"] and paths["parameter_dict"], paths


def test_lerp_fast_path_equals_its_fallback():
    def run() -> list[th.Tensor]:
        gen = th.Generator().manual_seed(0)
        targets = [th.randn(7, 5, generator=gen), th.randn(3, generator=gen)]
        sources = [th.randn(7, 5, generator=gen), th.randn(3, generator=gen)]
        fast_ops.lerp_(targets, sources, 0.005)
        return targets

    fast, public = both(run)
    assert all(th.equal(a, b) for a, b in zip(fast, public))
    assert not th.equal(fast[0], th.randn(7, 5, generator=th.Generator().manual_seed(0)))  # it did move


def test_block_adam_fast_path_equals_its_fallback_over_several_steps():
    def run() -> list[th.Tensor]:
        gen = th.Generator().manual_seed(1)
        params = [nn.Parameter(th.randn(4, 6, 5, generator=gen)), nn.Parameter(th.randn(4, 5, generator=gen))]
        optimizer = BlockAdam(params, blocks=[[(0, 2), (2, 4)], [(0, 1), (1, 4)]], lr=1e-2)  # one step counter, two blocks
        for _ in range(5):
            optimizer.zero_grad()
            sum((p**3).sum() for p in params).backward()
            optimizer.step()
        state = optimizer.state[params[0]]
        return [p.detach().clone() for p in params] + [state["exp_avg"], state["exp_avg_sq"], state["step"]]

    fast, public = both(run)
    assert all(th.equal(a, b) for a, b in zip(fast, public))
    assert float(fast[-1]) == 5.0  # counted once per step, not once per block


def test_parameter_values_fast_path_equals_its_fallback():
    plist = nn.ParameterList([nn.Parameter(th.zeros(2)), nn.Parameter(th.ones(3))])
    fast, public = both(lambda: fast_ops.parameter_values(plist))
    assert len(fast) == 2 and all(a is b for a, b in zip(fast, public))


@pytest.mark.parametrize("net_arch", [[32, 32], [128, 96]])
def test_training_with_the_fallbacks_is_bit_identical(net_arch):
    def run() -> list[th.Tensor]:
        model = MADDPG("MlpPolicy", Rendezvous(), seed=2, learning_starts=100, batch_size=32, policy_kwargs=dict(net_arch=net_arch))
        model.learn(300)
        return [t.clone() for t in model.policy.state_dict().values()]

    fast, public = both(run)
    assert len(fast) == len(public) and all(th.equal(a, b) for a, b in zip(fast, public))

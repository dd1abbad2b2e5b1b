"""The private APIs sb3_macb uses (sb3_macb.common.private_apis) against their public fallbacks: the same results."""

import numpy as np
import pytest
import torch as th
from torch import nn

from sb3_macb import MADDPG
from sb3_macb.common import private_apis
from sb3_macb.common.block_adam import BlockAdam
from toy_envs import Rendezvous


def both(fn):  # type: ignore[no-untyped-def]
    """``fn()`` with the private fast paths, then with the public fallbacks."""
    results = []
    for private in (True, False):
        old, private_apis.use_private = private_apis.use_private, private
        try:
            results.append(fn())
        finally:
            private_apis.use_private = old
    return results


def test_this_torch_offers_the_fast_paths():
    # (so that the comparisons below run the fast paths; a PyTorch without one still works, on the fallback;
    # oneDNN is compared with its fallback in test_maddpg.py and may be missing from a build)
    paths = private_apis.describe()
    assert paths["foreach_lerp"] and paths["fused_adam"] and paths["parameter_dict"], paths


def test_lerp_fast_path_equals_its_fallback():
    def run() -> list[th.Tensor]:
        gen = th.Generator().manual_seed(0)
        targets = [th.randn(7, 5, generator=gen), th.randn(3, generator=gen)]
        sources = [th.randn(7, 5, generator=gen), th.randn(3, generator=gen)]
        private_apis.lerp_(targets, sources, 0.005)
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
    fast, public = both(lambda: private_apis.parameter_values(plist))
    assert len(fast) == 2 and all(a is b for a, b in zip(fast, public))


@pytest.mark.parametrize("net_arch", [[32, 32], [128, 96]])
def test_training_with_the_fallbacks_is_bit_identical(net_arch):
    def run() -> list[th.Tensor]:
        model = MADDPG(
            "MlpPolicy", Rendezvous(), seed=2, learning_starts=100, batch_size=32, policy_kwargs=dict(net_arch=net_arch)
        )
        model.learn(300)
        return [t.clone() for t in model.policy.state_dict().values()]

    fast, public = both(run)
    assert len(fast) == len(public) and all(th.equal(a, b) for a, b in zip(fast, public))


def test_optuna_trial_ids_from_the_private_attribute_and_from_the_public_storage_api(tmp_path):
    import optuna

    storage = optuna.storages.RDBStorage(f"sqlite:///{tmp_path / 's.db'}")
    study = optuna.create_study(study_name="s", storage=storage)
    trials = [study.ask() for _ in range(3)]
    fast, public = both(lambda: [private_apis.trial_id(t, storage, "s") for t in trials])
    assert fast == public and len(set(fast)) == 3


def test_each_env_of_a_vec_env_gets_its_own_seed_and_a_missing_attribute_is_named():
    from sb3_macb.envs.vec_tasks import make_task_vec_env

    venv = make_task_vec_env("sb3_macb/CommunicativeNavigation-v0", 3)
    private_apis.set_next_reset_seeds(venv.unwrapped, [7, None, 7])
    assert private_apis.next_reset_seeds(venv.unwrapped) == [7, None, 7]
    obs = venv.reset()
    assert np.array_equal(obs[0], obs[2]) and not np.array_equal(obs[0], obs[1])  # the same seed, the same start
    with pytest.raises(ValueError, match="2 seeds for 3 envs"):
        private_apis.set_next_reset_seeds(venv.unwrapped, [1, 2])
    del venv.unwrapped._seeds  # as if a Stable-Baselines3 version kept them elsewhere
    with pytest.raises(RuntimeError, match="VecEnv._seeds"):
        private_apis.set_next_reset_seeds(venv.unwrapped, [1, 2, 3])

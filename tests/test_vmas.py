import numpy as np
import pytest

pytest.importorskip("vmas")

from sb3_macb import MADDPG  # noqa: E402
from sb3_macb.envs.vmas_env import make_vmas_env  # noqa: E402


@pytest.mark.parametrize("scenario, n_agents, obs_dim", [("navigation", 3, 3 * 18), ("balance", 3, 3 * 16)])
def test_joint_spaces_rewards_and_episode_ends(scenario, n_agents, obs_dim):
    env = make_vmas_env(scenario, n_envs=2, max_steps=4, seed=0, monitor=False, n_agents=n_agents)
    layout = env.get_attr("agent_layout")[0]
    assert layout.n_agents == n_agents and layout.obs_dim == obs_dim == env.observation_space.shape[0]
    assert env.action_space.shape == (2 * n_agents,)
    obs = env.reset()
    assert obs.shape == (2, obs_dim) and obs.dtype == np.float32
    rng = np.random.default_rng(0)
    for step in range(1, 6):
        obs, rewards, dones, infos = env.step(rng.uniform(-1, 1, (2, 2 * n_agents)).astype(np.float32))
        for reward, info in zip(rewards, infos):
            assert info["agent_rewards"].shape == (n_agents,)
            assert reward == pytest.approx(info["agent_rewards"].sum(), rel=1e-6, abs=1e-6)  # team_reward "sum"
        if step == 4:  # the time limit: a truncation, the last observation kept, the env reset
            assert dones.all() and all(info["TimeLimit.truncated"] for info in infos)
            assert all(info["terminal_observation"].shape == (obs_dim,) for info in infos)
            assert not np.array_equal(infos[0]["terminal_observation"], obs[0])
        else:
            assert not dones.any()


def test_same_seed_same_run_and_packs_train():
    def run(seed: int) -> np.ndarray:
        env = make_vmas_env("navigation", n_envs=1, max_steps=25, seed=seed, n_agents=2)
        model = MADDPG("MlpPolicy", env, learning_starts=50, batch_size=16, policy_kwargs=dict(net_arch=[16]), seed=seed)
        model.learn(150)
        return np.concatenate([p.detach().numpy().ravel() for p in model.actor.parameters()])

    np.testing.assert_array_equal(run(3), run(3))
    assert not np.array_equal(run(3), run(4))
    pack = MADDPG("MlpPolicy", make_vmas_env("balance", n_envs=2, max_steps=25, seed=0, n_agents=3), n_runs=2,
                  run_seeds=[0, 1], learning_starts=50, batch_size=16, policy_kwargs=dict(net_arch=[16]))
    pack.learn(100)
    assert pack.num_timesteps == 100 and pack.replay_buffer.pos == 50


def test_bad_settings_are_one_clear_error(monkeypatch):
    with pytest.raises(ValueError, match="team_reward must be one of"):
        make_vmas_env("navigation", team_reward="max")
    with pytest.raises(ValueError, match="n_envs and max_steps must be >= 1"):
        make_vmas_env("navigation", n_envs=0)
    monkeypatch.setitem(__import__("sys").modules, "vmas", None)
    with pytest.raises(ImportError, match=r'pip install "sb3_macb\[vmas\]"'):
        make_vmas_env("navigation")

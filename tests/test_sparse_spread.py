import gymnasium as gym
import numpy as np
import pytest

from sb3_macb import MADDPG
from sb3_macb.envs import sparse_spread_v0
from sb3_macb.envs.vec_spread import SpreadVecEnv
from sb3_macb.envs.vec_tasks import SPREAD_ID, make_task_vec_env


def test_spread_rewards_success_and_spaces():
    env = sparse_spread_v0.parallel_env(n_agents=4)
    obs, _ = env.reset(seed=0)
    assert env.possible_agents == [f"agent_{i}" for i in range(4)] and obs["agent_0"].shape == (18,)
    world = env.task_env.world
    for agent, landmark in zip(world.agents, world.landmarks):
        agent.state.p_pos = landmark.state.p_pos + np.array([0.05, 0.0])
    _, rewards, _, _, infos = env.step({a: np.zeros(2) for a in env.agents})
    assert set(rewards.values()) == {0.0} and infos["agent_0"]["success"]
    world.agents[0].state.p_pos = world.landmarks[0].state.p_pos + np.array([0.5, 0.5])
    _, rewards, _, _, infos = env.step({a: np.zeros(2) for a in env.agents})
    assert set(rewards.values()) == {-1.0} and not infos["agent_0"]["success"] and infos["agent_0"]["is_success"]


def test_spread_gym_id_and_bad_settings():
    env = gym.make(SPREAD_ID, n_agents=3)
    env.reset(seed=1)
    for _ in range(25):
        _, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert truncated and not terminated and reward in (0.0, -1.0) and "is_success" in info
    for bad in ({"n_agents": 1}, {"n_agents": 2.5}, {"cover_radius": 0.0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            SpreadVecEnv(1, **bad)
        with pytest.raises(ValueError, match=next(iter(bad))):
            sparse_spread_v0.parallel_env(**bad)


def test_maddpg_trains_on_the_vectorized_spread():
    model = MADDPG("MlpPolicy", make_task_vec_env(SPREAD_ID, 1, {"n_agents": 3}), learning_starts=50,
                   policy_kwargs=dict(net_arch=[16, 16]), seed=0)  # fmt: skip
    model.learn(200)
    assert model.num_timesteps == 200 and model.predict(np.zeros((1, 42), dtype=np.float32))[0].shape == (1, 6)

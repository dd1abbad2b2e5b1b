import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.env_util import make_vec_env

from sb3_macb import MADDPG
from sb3_macb.envs import sparse_spread_v0
from sb3_macb.envs.vec_spread import SpreadVecEnv, scripted_spread_actions
from sb3_macb.envs.vec_tasks import SPREAD_ID, make_task_vec_env


@pytest.mark.parametrize("kwargs", [{}, {"n_agents": 6}, {"n_agents": 2, "terminate_on_success": True, "cover_radius": 3.0}])
def test_the_vectorized_spread_steps_exactly_as_the_mpe2_based_one(kwargs):
    reference = make_vec_env(SPREAD_ID, n_envs=3, env_kwargs=kwargs)
    vectorized = make_task_vec_env(SPREAD_ID, 3, kwargs)
    assert isinstance(vectorized.unwrapped, SpreadVecEnv)
    reference.seed(7)
    vectorized.seed(7)
    assert np.array_equal(reference.reset(), vectorized.reset())
    rng = np.random.default_rng(0)
    dones, collisions = 0, 0
    for _ in range(60):
        actions = rng.uniform(-1.2, 1.2, (3, reference.action_space.shape[0])).astype(np.float32)
        (o1, r1, d1, i1), (o2, r2, d2, i2) = reference.step(actions), vectorized.step(actions)
        assert np.array_equal(o1, o2) and np.array_equal(r1, r2) and np.array_equal(d1, d2)
        dones += int(d1.sum())
        for a, b in zip(i1, i2):
            assert np.array_equal(a["agent_rewards"], b["agent_rewards"]) and a["is_success"] == b["is_success"]
            assert a.get("TimeLimit.truncated", False) == b["TimeLimit.truncated"]
            first_a, first_b = next(iter(a["agent_infos"].values())), next(iter(b["agent_infos"].values()))
            assert {k: first_a[k] for k in first_b} == first_b
            collisions += first_b["collisions"]
            if "terminal_observation" in a:
                assert np.array_equal(a["terminal_observation"], b["terminal_observation"])
    assert dones >= 3 and collisions > 0  # (episodes ended and the contact forces were exercised)


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


def test_the_scripted_policy_solves_three_agent_spread_and_random_actions_do_not():
    def success_rate(policy):
        venv = make_task_vec_env(SPREAD_ID, 200, {"n_agents": 3})
        venv.seed(0)
        venv.reset()
        for _ in range(25):
            _, _, _, infos = venv.step(policy(venv.unwrapped))
        return np.mean([info["is_success"] for info in infos])

    rng = np.random.default_rng(0)
    assert success_rate(scripted_spread_actions) >= 0.9
    assert success_rate(lambda venv: rng.uniform(-1, 1, (venv.num_envs, 6))) <= 0.05


def test_maddpg_trains_on_the_vectorized_spread():
    model = MADDPG("MlpPolicy", make_task_vec_env(SPREAD_ID, 1, {"n_agents": 3}), learning_starts=50,
                   policy_kwargs=dict(net_arch=[16, 16]), seed=0)  # fmt: skip
    model.learn(200)
    assert model.num_timesteps == 200 and model.predict(np.zeros((1, 42), dtype=np.float32))[0].shape == (1, 6)

import numpy as np
import pytest
from stable_baselines3.common.env_util import make_vec_env

from sb3_macb.envs import communicative_navigation_v0, two_agent_navigation_v0
from sb3_macb.envs.scripted import scripted_actions
from sb3_macb.envs.vec_spread import SpreadVecEnv
from sb3_macb.envs.vec_tasks import SPREAD_ID, TaskVecEnv, make_task_vec_env

COMM = "sb3_macb/CommunicativeNavigation-v0"
NAV = "sb3_macb/TwoAgentNavigation-v0"


@pytest.mark.parametrize(
    "env_id, kwargs",
    [(COMM, {}), (COMM, {"reward": "distance"}), (COMM, {"n_landmarks": 5, "half_width": 2.0, "max_cycles": 30}),
     (NAV, {}), (NAV, {"reward": "success", "success_radius": 0.6}),
     (NAV, {"terminate_on_success": True, "success_radius": 0.6}),
     # every step a success, every step the last: a success at the time limit is a termination in both
     (NAV, {"terminate_on_success": True, "success_radius": 3.0, "max_cycles": 1}),
     (SPREAD_ID, {}), (SPREAD_ID, {"n_agents": 6}),
     (SPREAD_ID, {"n_agents": 2, "terminate_on_success": True, "cover_radius": 3.0})],
)  # fmt: skip
def test_each_vectorized_task_steps_exactly_as_its_mpe2_based_env(env_id, kwargs):
    reference = make_vec_env(env_id, n_envs=3, env_kwargs=kwargs)
    vectorized = make_task_vec_env(env_id, 3, kwargs)
    assert isinstance(vectorized.unwrapped, SpreadVecEnv if env_id == SPREAD_ID else TaskVecEnv)
    reference.seed(7)
    vectorized.seed(7)
    assert np.array_equal(reference.reset(), vectorized.reset())
    rng = np.random.default_rng(0)
    dones, collisions, rewards = 0, 0, set()
    for _ in range(60):
        actions = rng.uniform(-1.2, 1.2, (3, reference.action_space.shape[0])).astype(np.float32)  # (clipped)
        (o1, r1, d1, i1), (o2, r2, d2, i2) = reference.step(actions), vectorized.step(actions)
        assert np.array_equal(o1, o2) and np.array_equal(r1, r2) and np.array_equal(d1, d2)
        dones += int(d1.sum())
        rewards |= set(r2.tolist())
        for a, b in zip(i1, i2):
            assert np.array_equal(a["agent_rewards"], b["agent_rewards"]) and a["is_success"] == b["is_success"]
            assert a.get("TimeLimit.truncated", False) == b["TimeLimit.truncated"]
            assert ("terminal_observation" in a) == ("terminal_observation" in b)
            first_a, first_b = next(iter(a["agent_infos"].values())), next(iter(b["agent_infos"].values()))
            assert {k: first_a[k] for k in first_b} == first_b
            collisions += first_b["collisions"]
            if "terminal_observation" in a:
                assert np.array_equal(a["terminal_observation"], b["terminal_observation"])
    assert dones >= 3
    if env_id == SPREAD_ID:
        assert collisions > 0  # (the contact forces were exercised)
    if kwargs.get("reward") == "success":
        assert rewards == {0.0, -1.0}
    with pytest.raises(ValueError, match="NaN"):
        vectorized.step(np.full((3, reference.action_space.shape[0]), np.nan, dtype=np.float32))


def test_the_success_only_navigation_reward():
    env = two_agent_navigation_v0.parallel_env(reward="success")
    env.reset(seed=0)
    world = env.task_env.world
    for agent, landmark in zip(world.agents, world.landmarks):
        agent.state.p_pos = landmark.state.p_pos + np.array([0.2, 0.0])  # within 0.25, not within the paper's 0.125
        agent.state.p_vel = np.zeros(2)
    _, rewards, _, _, infos = env.step({a: np.zeros(2) for a in env.agents})
    assert set(rewards.values()) == {0.0} and infos["agent_0"]["success"]
    world.agents[0].state.p_pos = world.agents[1].state.p_pos + np.array([0.1, 0.0])  # a collision, one uncovered
    _, rewards, _, _, infos = env.step({a: np.zeros(2) for a in env.agents})
    assert set(rewards.values()) == {-1.0} and infos["agent_0"]["collisions"] == 1


def test_communicative_navigation_with_more_landmarks_in_a_larger_arena():
    env = communicative_navigation_v0.parallel_env(n_landmarks=6, half_width=2.0)
    obs, _ = env.reset(seed=0)
    assert obs["listener_0"].shape == (2 + 12 + 3,) and obs["speaker_0"].shape == (3,)
    colors = np.array([lm.color for lm in env.task_env.world.landmarks])
    assert len({tuple(c.round(3)) for c in colors}) == 6  # every landmark its own colour
    starts = []
    for seed in range(50):
        env.reset(seed=seed)
        starts += [e.state.p_pos for e in env.task_env.world.entities]
    assert np.abs(starts).max() > 1.5 and np.abs(starts).max() <= 2.0
    assert np.array_equal(communicative_navigation_v0.parallel_env().reset(seed=0)[0]["speaker_0"],
                          communicative_navigation_v0.parallel_env(n_landmarks=3).reset(seed=0)[0]["speaker_0"])  # fmt: skip


@pytest.mark.parametrize(
    "task, bad, key",
    [("navigation", {"reward": "distance"}, "reward"), ("navigation", {"n_landmarks": 4}, "n_landmarks"),
     ("communication", {"reward": "success"}, "reward"), ("communication", {"n_landmarks": 1}, "n_landmarks"),
     ("communication", {"n_landmarks": 4.5}, "n_landmarks"), ("communication", {"half_width": 0}, "half_width"),
     ("communication", {"half_width": "2"}, "half_width")],
)  # fmt: skip
def test_bad_task_settings_name_the_key(task, bad, key):
    with pytest.raises(ValueError, match=key):
        TaskVecEnv(task, 1, **bad)
    module = two_agent_navigation_v0 if task == "navigation" else communicative_navigation_v0
    with pytest.raises((ValueError, TypeError), match=key):
        module.parallel_env(**bad)


@pytest.mark.parametrize(
    "env_id, kwargs, steps",
    [(SPREAD_ID, {"n_agents": 3}, 25), (NAV, {"reward": "success"}, 20),
     (COMM, {"n_landmarks": 6, "half_width": 2.0, "max_cycles": 40}, 40)],
)
def test_the_scripted_policy_solves_each_task_and_random_actions_do_not(env_id, kwargs, steps):
    def success_rate(policy):
        venv = make_task_vec_env(env_id, 200, kwargs)
        venv.seed(0)
        venv.reset()
        for _ in range(steps):
            _, _, dones, infos = venv.step(policy(venv))
        assert dones.all()
        return np.mean([info["is_success"] for info in infos])

    rng = np.random.default_rng(0)
    assert success_rate(scripted_actions) >= 0.9
    space = make_task_vec_env(env_id, 1, kwargs).action_space
    low, high = space.low, space.high
    assert success_rate(lambda venv: rng.uniform(low, high, (venv.num_envs, low.shape[0]))) <= 0.1
    with pytest.raises(TypeError, match="SpreadVecEnv or a TaskVecEnv"):
        scripted_actions(make_vec_env("Pendulum-v1", 1))

import gymnasium as gym
import numpy as np
import pytest
from pettingzoo.test import parallel_api_test
from stable_baselines3.common.env_checker import check_env

from sb3_macb.envs import ENV_IDS, communicative_navigation_v0, two_agent_navigation_v0


def raw(par_env):
    return par_env.task_env


def place(world, agents=(), landmarks=()):
    for entity, pos in [*zip(world.agents, agents), *zip(world.landmarks, landmarks)]:
        entity.state.p_pos = np.array(pos, dtype=np.float64)
        entity.state.p_vel = np.zeros(2)


@pytest.mark.parametrize("module", [two_agent_navigation_v0, communicative_navigation_v0])
def test_parallel_api(module):
    parallel_api_test(module.parallel_env(), num_cycles=60)


def test_spaces():
    nav = two_agent_navigation_v0.parallel_env()
    assert nav.possible_agents == ["agent_0", "agent_1"]
    for agent in nav.possible_agents:
        assert nav.observation_space(agent).shape == (10,)
        assert nav.action_space(agent).shape == (2,)
        assert (nav.action_space(agent).low == -1).all() and (nav.action_space(agent).high == 1).all()
    comm = communicative_navigation_v0.parallel_env()
    assert comm.possible_agents == ["speaker_0", "listener_0"]
    assert comm.observation_space("speaker_0").shape == (3,)
    assert comm.observation_space("listener_0").shape == (11,)  # no padding
    assert comm.action_space("speaker_0").shape == (3,) and (comm.action_space("speaker_0").low == 0).all()
    assert comm.action_space("listener_0").shape == (2,) and (comm.action_space("listener_0").low == -1).all()


def test_navigation_rewards_and_success():
    env = two_agent_navigation_v0.parallel_env()
    env.reset(seed=0)
    world, scenario = raw(env).world, raw(env).scenario
    # both landmarks covered within the reward radius: 0
    place(world, agents=[(0.5, 0.5), (-0.5, -0.5)], landmarks=[(0.55, 0.5), (-0.5, -0.4)])
    assert scenario.shared_reward(world) == 0.0 and scenario.success(world) and scenario.collisions(world) == 0
    # one landmark at 0.2: not covered for the reward (0.125), covered for success (0.25)
    place(world, agents=[(0.5, 0.5), (-0.5, -0.5)], landmarks=[(0.7, 0.5), (-0.5, -0.5)])
    assert scenario.shared_reward(world) == -0.5 and scenario.success(world)
    # no landmark covered: -1; plus a collision: -1.5 (the minimum)
    place(world, agents=[(0.0, 0.0), (0.2, 0.0)], landmarks=[(0.9, 0.9), (-0.9, -0.9)])
    assert scenario.collisions(world) == 1
    assert scenario.shared_reward(world) == -1.5 and not scenario.success(world)
    assert two_agent_navigation_v0.parallel_env(collision_penalty=False).task_env.scenario.shared_reward(world) == -1.0


def test_navigation_step_infos_and_observation():
    env = two_agent_navigation_v0.parallel_env(max_cycles=3)
    env.reset(seed=0)
    world = raw(env).world
    place(world, agents=[(0.0, 0.0), (0.2, 0.0)], landmarks=[(0.5, 0.5), (-0.5, 0.5)])
    zero = {agent: np.zeros(2, dtype=np.float32) for agent in env.agents}
    obs, rewards, _, _, infos = env.step(zero)
    assert infos["agent_0"]["collisions"] == 1 and infos["agent_0"]["episode_collisions"] == 1
    assert rewards["agent_0"] == rewards["agent_1"] == -1.5  # shared
    assert not infos["agent_0"]["is_success"]
    a0 = world.agents[0].state
    expected = np.concatenate([a0.p_vel, a0.p_pos, [0.5, 0.5] - a0.p_pos, [-0.5, 0.5] - a0.p_pos,
                               world.agents[1].state.p_pos - a0.p_pos])
    np.testing.assert_allclose(obs["agent_0"], expected, rtol=1e-5, atol=1e-6)
    # success at one step makes the episode a success even if it does not hold at the end
    place(world, agents=[(0.5, 0.5), (-0.5, 0.5)])
    _, _, _, _, infos = env.step(zero)
    assert infos["agent_0"]["success"] and infos["agent_0"]["is_success"]
    place(world, agents=[(0.9, -0.9), (-0.9, -0.9)])
    _, _, _, truncs, infos = env.step(zero)
    assert truncs["agent_0"] and not infos["agent_0"]["success"] and infos["agent_0"]["is_success"]


@pytest.mark.parametrize("reward", ["sparse", "distance"])
def test_communicative_rewards(reward):
    env = communicative_navigation_v0.parallel_env(reward=reward)
    obs, _ = env.reset(seed=1)
    world, scenario = raw(env).world, raw(env).scenario
    goal_index = world.landmarks.index(scenario.goal)
    np.testing.assert_allclose(obs["speaker_0"], scenario.colors[goal_index])  # the speaker sees the goal's colour
    place(world, agents=[(0.0, 0.0), (0.3, 0.3)], landmarks=[(0.3, 0.4), (0.3, 0.4), (0.3, 0.4)])
    assert scenario.success(world)  # distance 0.1 < 0.15
    assert scenario.shared_reward(world) == (0.0 if reward == "sparse" else pytest.approx(-0.01))
    place(world, agents=[(0.0, 0.0), (0.3, 0.3)], landmarks=[(0.3, 0.6), (0.3, 0.6), (0.3, 0.6)])
    assert not scenario.success(world)
    assert scenario.shared_reward(world) == (-1.0 if reward == "sparse" else pytest.approx(-0.09))


def test_listener_hears_the_message():
    env = communicative_navigation_v0.parallel_env()
    env.reset(seed=0)
    message = np.array([0.2, 0.9, 0.4], dtype=np.float32)
    obs, _, _, _, _ = env.step({"speaker_0": message, "listener_0": np.zeros(2, dtype=np.float32)})
    np.testing.assert_allclose(obs["listener_0"][-3:], message, rtol=1e-6)
    assert raw(env).world.agents[0].state.p_pos is not None


def test_terminate_on_success():
    env = communicative_navigation_v0.parallel_env(terminate_on_success=True)
    env.reset(seed=0)
    world, scenario = raw(env).world, raw(env).scenario
    place(world, agents=[(0.0, 0.0), tuple(scenario.goal.state.p_pos)])
    _, _, terms, truncs, infos = env.step({a: env.action_space(a).sample() * 0 for a in env.agents})
    assert terms["listener_0"] and not truncs["listener_0"] and infos["listener_0"]["is_success"]


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_gym_ids_and_determinism(env_id):
    def rollout(seed):
        env = gym.make(env_id)
        env.action_space.seed(0)
        obs, _ = env.reset(seed=seed)
        observations, rewards = [obs], []
        for _ in range(25):  # (20 steps for the paper's tasks, 25 for Sparse Spread)
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
            observations.append(obs)
            rewards.append(reward)
            if truncated:
                break
        assert truncated and not terminated and "is_success" in info and len(rewards) in (20, 25)
        return np.array(observations), np.array(rewards)

    obs1, rew1 = rollout(5)
    obs2, rew2 = rollout(5)
    obs3, _ = rollout(6)
    np.testing.assert_array_equal(obs1, obs2)
    np.testing.assert_array_equal(rew1, rew2)
    assert not np.array_equal(obs1[0], obs3[0])
    assert rew1.min() >= -1.5  # the shared reward, not the number of agents times it
    check_env(gym.make(env_id).unwrapped)


def test_gym_kwargs_pass_through():
    env = gym.make("sb3_macb/CommunicativeNavigation-v0", reward="distance", max_cycles=5)
    env.reset(seed=0)
    results = [env.step(env.action_space.sample()) for _ in range(5)]
    assert results[-1][3] and not any(r[3] for r in results[:-1])
    assert all(r[1] > -9 and r[1] != -1.0 for r in results)  # squared distances, not the sparse reward


def test_render_rgb_array():
    env = gym.make("sb3_macb/TwoAgentNavigation-v0", render_mode="rgb_array")
    env.reset(seed=0)
    env.step(env.action_space.sample())
    frame = env.render()
    assert frame.shape == (700, 700, 3) and frame.dtype == np.uint8 and frame.std() > 0


@pytest.mark.parametrize("module", [two_agent_navigation_v0, communicative_navigation_v0])
def test_aec_version(module):
    from pettingzoo.test import api_test

    api_test(module.env(), num_cycles=30)
    env = module.env()
    env.reset(seed=0)
    assert env.possible_agents == module.parallel_env().possible_agents


def test_actions_are_clipped_and_required():
    env = communicative_navigation_v0.parallel_env()
    env.reset(seed=0)
    start = raw(env).world.agents[1].state.p_pos.copy()
    listener = raw(env).world.agents[1]
    env.step({"speaker_0": np.zeros(3), "listener_0": np.array([50.0, 0.0])})
    # clipped to 1: force 5, dt 0.1 -> velocity 0.5 (MPE moves by the previous step's velocity, so not yet)
    np.testing.assert_allclose(listener.state.p_vel, [0.5, 0.0], atol=1e-9)
    np.testing.assert_allclose(listener.state.p_pos, start, atol=1e-9)
    env.step({"speaker_0": np.zeros(3), "listener_0": np.zeros(2)})
    np.testing.assert_allclose(listener.state.p_pos - start, [0.05, 0.0], atol=1e-9)
    with pytest.raises(KeyError, match="listener_0"):
        env.step({"speaker_0": np.zeros(3)})


def test_both_task_implementations_read_one_set_of_constants():
    """The mpe2-based worlds and the vectorized env take their physics and geometry from task_constants."""
    from mpe2._mpe_utils.core import World

    from sb3_macb.envs import task_constants as c
    from sb3_macb.envs.vec_tasks import TaskVecEnv

    default = World()  # the physics the filed runs had: mpe2's defaults, now set explicitly from the constants
    assert (default.dt, default.damping, default.contact_force, default.contact_margin) == (
        c.DT, c.DAMPING, c.CONTACT_FORCE, c.CONTACT_MARGIN)  # fmt: skip
    for module, task, constants in [(two_agent_navigation_v0, "navigation", c.NAVIGATION),
                                    (communicative_navigation_v0, "communication", c.COMMUNICATION)]:  # fmt: skip
        world = module.parallel_env().task_env.world
        assert (world.dt, world.damping, world.contact_force, world.contact_margin) == (
            c.DT, c.DAMPING, c.CONTACT_FORCE, c.CONTACT_MARGIN)  # fmt: skip
        assert {e.size for e in world.entities} == {constants.size} and len(world.landmarks) == constants.n_landmarks
        venv = TaskVecEnv(task)
        assert (venv.size, venv.n_landmarks, venv.reward_radius, venv.success_radius) == (
            constants.size, constants.n_landmarks, constants.reward_radius, constants.success_radius)  # fmt: skip
    env = communicative_navigation_v0.parallel_env()
    env.reset(seed=0)
    landmarks = env.task_env.world.landmarks
    assert np.array_equal([landmark.color for landmark in landmarks], c.GOAL_COLORS)
    assert not any(np.shares_memory(landmark.color, c.GOAL_COLORS) for landmark in landmarks)  # rendering may edit them

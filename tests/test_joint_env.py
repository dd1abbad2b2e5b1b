import numpy as np
import pytest
from gymnasium import spaces
from mpe2 import simple_speaker_listener_v4, simple_spread_v3
from pettingzoo.utils.conversions import parallel_to_aec
from stable_baselines3.common.env_checker import check_env

from sb3_macb import AgentLayout, make_joint_env
from toy_envs import Rendezvous


def test_layout_spaces_and_bounds():
    env = make_joint_env(Rendezvous())
    assert env.agent_layout == AgentLayout(agents=("a", "b"), obs_dims=(1, 2), action_dims=(1, 2))
    assert env.observation_space.shape == (3,)
    # per-agent bounds kept, in possible_agents order
    np.testing.assert_allclose(env.action_space.low, [-1, -0.5, -0.5])
    np.testing.assert_allclose(env.action_space.high, [1, 0.5, 0.5])
    assert env.agent_layout.obs_slices == [slice(0, 1), slice(1, 3)]
    assert env.agent_layout.action_slices == [slice(0, 1), slice(1, 3)]


@pytest.mark.parametrize(
    "make",
    [
        lambda: Rendezvous(),
        lambda: simple_speaker_listener_v4.parallel_env(continuous_actions=True, max_cycles=5),
        lambda: simple_spread_v3.parallel_env(N=3, continuous_actions=True, max_cycles=5),
    ],
)
def test_check_env(make):
    check_env(make_joint_env(make()))


def test_observation_action_reward_contract():
    par = Rendezvous()
    env = make_joint_env(par)
    obs, info = env.reset(seed=3)
    np.testing.assert_allclose(obs, [par.pos[0], par.pos[1], 0.5], rtol=1e-6)
    start = par.pos.copy()
    obs, reward, terminated, truncated, info = env.step(np.array([1.0, -0.5, 0.3], dtype=np.float32))
    # agent a moved by 0.2 * 1, agent b by 0.4 * -0.5: the joint action was split in agent order
    np.testing.assert_allclose(par.pos, start + [0.2, -0.2], rtol=1e-6)
    expected = -float(np.sum(par.pos**2))
    np.testing.assert_allclose(info["agent_rewards"], [expected, expected], rtol=1e-6)
    assert reward == pytest.approx(2 * expected, rel=1e-6)  # team reward = sum of the agents' rewards
    assert info["agent_rewards"].dtype == np.float32
    assert not terminated and not truncated
    assert "is_success" in info


def test_truncation_and_termination_kept_apart():
    env = make_joint_env(Rendezvous(max_steps=3))
    env.reset(seed=0)
    results = [env.step(np.zeros(3, dtype=np.float32)) for _ in range(3)]
    assert [r[3] for r in results] == [False, False, True]  # truncated at the time limit
    assert not any(r[2] for r in results)

    env = make_joint_env(Rendezvous(max_steps=50, terminate_on_success=True))
    env.reset(seed=0)
    env.unwrapped.par_env.pos[:] = 0.0
    _, _, terminated, truncated, info = env.step(np.zeros(3, dtype=np.float32))
    assert terminated and not truncated and info["is_success"]


def test_aec_env_is_converted():
    env = make_joint_env(parallel_to_aec(simple_speaker_listener_v4.parallel_env(continuous_actions=True, max_cycles=5)))
    assert env.agent_layout.agents == ("speaker_0", "listener_0")
    assert env.agent_layout.obs_dims == (3, 11)  # unequal sizes, no padding
    obs, _ = env.reset(seed=0)
    assert obs.shape == (14,)


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(multi_discrete=True), TypeError, "MultiDiscrete action space"),
        (dict(dict_obs=True), TypeError, "Dict observation space"),
    ],
)
def test_bad_spaces(kwargs, error, match):
    with pytest.raises(error, match=match):
        make_joint_env(Rendezvous(**kwargs))


def test_discrete_agents_act_one_hot_and_the_env_receives_ints():
    env = make_joint_env(Rendezvous(discrete=True))  # agent a: Discrete(3), agent b: Box (mixed)
    layout = env.agent_layout
    assert layout.action_dims == (3, 2) and layout.discrete_agents == (True, False)
    assert list(layout.discrete_action_mask) == [True, True, True, False, False]
    assert np.array_equal(env.action_space.low[:3], [0, 0, 0]) and np.array_equal(env.action_space.high[:3], [1, 1, 1])
    env.reset(seed=0)
    start = env.unwrapped.par_env.pos.copy()
    env.step(np.array([0.0, 0.1, 0.9, 0.0, 0.0], dtype=np.float32))  # argmax 2: +0.2 (the toy env asserts an int)
    assert np.isclose(env.unwrapped.par_env.pos[0], np.clip(start[0] + 0.2, -2, 2))
    spread = make_joint_env(simple_spread_v3.parallel_env(N=2))  # mpe2's default: discrete actions
    assert spread.agent_layout.discrete_agents == (True, True) and spread.action_space.shape == (10,)


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(nan_obs_step=2), ValueError, r"NaN or infinite value in the observation of agent\(s\) \['a'\]"),
        (dict(nan_reward_step=1), ValueError, "NaN or infinite reward"),
        (dict(disappear_step=2), RuntimeError, "disappear"),
        (dict(drop_agent_step=2), RuntimeError, "disappeared mid-episode"),
    ],
)
def test_bad_episodes(kwargs, error, match):
    env = make_joint_env(Rendezvous(**kwargs))
    env.reset(seed=0)
    with pytest.raises(error, match=match):
        for _ in range(5):
            env.step(np.zeros(3, dtype=np.float32))


def test_wrong_action_size():
    env = make_joint_env(Rendezvous())
    env.reset(seed=0)
    with pytest.raises(ValueError, match="joint action of size 3"):
        env.step(np.zeros(2))


def test_not_a_pettingzoo_env():
    import gymnasium as gym

    with pytest.raises(TypeError, match="PettingZoo"):
        make_joint_env(gym.make("Pendulum-v1"))


def test_unbounded_action_space():
    class Unbounded(Rendezvous):
        def action_space(self, agent):
            return spaces.Box(-np.inf, np.inf, (1,), np.float32)

    with pytest.raises(ValueError, match="unbounded action space"):
        make_joint_env(Unbounded())

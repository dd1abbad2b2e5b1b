import gymnasium as gym
import numpy as np
import pytest
import torch as th
from mpe2 import simple_speaker_listener_v4
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise

from sb3_macb import MADDPG, MultiAgentReplayBuffer, make_joint_env
from sb3_macb.common import grouped_mlp
from sb3_macb.common.grouped_mlp import GroupedMLP, onednn_available
from toy_envs import Rendezvous

SMALL = dict(net_arch=[32, 32])


def speaker_listener(max_cycles: int = 20):
    return simple_speaker_listener_v4.parallel_env(continuous_actions=True, max_cycles=max_cycles)


def noise(dim: int = 3, sigma: float = 0.1) -> NormalActionNoise:
    return NormalActionNoise(np.zeros(dim), sigma * np.ones(dim))


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(),
        dict(centralized_critic=False),
        dict(policy_kwargs=dict(net_arch=[32, 32], n_critics=2), policy_delay=2, target_policy_noise=0.2),
        dict(policy_kwargs=dict(net_arch=dict(pi=[16], qf=[32, 32]))),
        dict(action_noise=OrnsteinUhlenbeckActionNoise(np.zeros(8), 0.1 * np.ones(8))),
    ],
)
def test_runs_on_speaker_listener(kwargs):
    kwargs = {"policy_kwargs": SMALL, **kwargs}
    model = MADDPG("MlpPolicy", speaker_listener(5), learning_starts=20, batch_size=16, seed=0, **kwargs)
    model.learn(60)
    assert model.num_timesteps == 60
    assert model._n_updates > 0
    obs = model.env.reset()
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (1, 8)
    assert model.env.action_space.contains(action[0])


def test_n_envs_2():
    env = make_vec_env(lambda: make_joint_env(Rendezvous()), n_envs=2, seed=0)
    model = MADDPG("MlpPolicy", env, learning_starts=10, batch_size=8, policy_kwargs=SMALL, action_noise=noise(), seed=0)
    model.learn(40)
    assert model.num_timesteps == 40
    assert model.replay_buffer.agent_rewards.shape[1:] == (2, 2)
    assert model.replay_buffer.pos == 20


def test_policy_shapes_and_independence():
    model = MADDPG("MlpPolicy", Rendezvous(), policy_kwargs=SMALL, seed=0, centralized_critic=False)
    critic, device = model.critic, model.device  # tensors on the model's device: CUDA where there is one
    obs = th.randn(5, 3, device=device, requires_grad=True)
    act = th.randn(5, 3, device=device, requires_grad=True)
    q = critic(obs, act)
    assert q.shape == (1, 1, 2, 5)  # (critics, runs, agents, batch)
    q[0, 0, 0].sum().backward()  # agent a's independent critic reads only agent a's observation and action
    assert obs.grad[:, 1:].abs().sum() == 0 and act.grad[:, 1:].abs().sum() == 0
    assert obs.grad[:, 0].abs().sum() > 0

    model = MADDPG("MlpPolicy", Rendezvous(), policy_kwargs=SMALL, seed=0)
    obs = th.randn(5, 3, device=device, requires_grad=True)
    model.critic(obs, th.randn(5, 3, device=device))[0, 0, 0].sum().backward()  # centralized: sees everything
    assert (obs.grad.abs().sum(dim=0) > 0).all()
    obs = th.randn(5, 3, device=device, requires_grad=True)
    model.actor(obs)[:, 0].sum().backward()  # agent a's actor reads only its own observation
    assert obs.grad[:, 1:].abs().sum() == 0


def test_masked_weights_stay_zero_after_training():
    model = MADDPG(
        "MlpPolicy", Rendezvous(), policy_kwargs=SMALL, learning_starts=10, batch_size=8, action_noise=noise(), seed=0
    )
    model.learn(60)
    first = model.actor.mu.weights[0].detach()  # (agents, hidden, obs_dim)
    assert first[0, :, 1:].abs().sum() == 0 and first[1, :, :1].abs().sum() == 0
    last = model.actor.mu.weights[-1].detach()  # (agents, action_dim, hidden)
    assert last[0, 1:].abs().sum() == 0 and last[1, :1].abs().sum() == 0
    assert first[0, :, 0].abs().sum() > 0


@pytest.mark.parametrize("onednn_fp32", [True, False], ids=["oneDNN", "MKL"])
def test_onednn_and_bmm_paths_agree(monkeypatch, onednn_fp32):
    # the per-group path is a CPU path; its large float32 products go to oneDNN or to MKL by the CPU (both tested)
    if onednn_fp32 and not onednn_available():
        pytest.skip("this PyTorch build has no oneDNN")
    monkeypatch.setattr(grouped_mlp, "_ONEDNN_FP32", onednn_fp32)
    model = MADDPG("MlpPolicy", Rendezvous(), policy_kwargs=dict(net_arch=[128, 96]), seed=0, device="cpu")
    obs, act = th.randn(7, 3), th.randn(7, 3)
    results = []
    for use in (True, False):
        GroupedMLP.use_onednn = use
        try:
            model.policy.zero_grad()
            q = model.critic(obs, act)
            pi = model.actor(obs)
            (q.square().sum() + pi.square().sum()).backward()
            grads = [p.grad.clone() for p in model.policy.parameters() if p.grad is not None]
            results.append([q.detach(), pi.detach(), *grads])
        finally:
            GroupedMLP.use_onednn = True
    assert len(results[0]) > 2
    for a, b in zip(*results):
        th.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)


def _outputs_and_grads(model: MADDPG, obs: th.Tensor, act: th.Tensor) -> list[th.Tensor]:
    model.policy.zero_grad()
    q = model.critic(obs, act)
    pi = model.actor(obs)
    (q.square().sum() + pi.square().sum()).backward()
    return [q.detach(), pi.detach(), *[p.grad.clone() for p in model.policy.parameters() if p.grad is not None]]


def _close_in_bf16(exact: th.Tensor, low: th.Tensor) -> bool:
    """bfloat16 keeps 8 bits of mantissa: relative errors of ~1e-2 (fp32 paths agree to ~1e-6)."""
    return low.dtype == th.float32 and bool((exact - low).norm() <= 0.05 * exact.norm() + 1e-3)


@pytest.mark.parametrize(
    "net_arch, share, onednn",
    [([128, 96], False, True), ([128, 96], True, True), ([128, 96], False, False), ([128, 96], True, False)],
)
def test_bf16_precision_is_close_to_fp32_with_fp32_master_weights(net_arch, share, onednn):
    from mpe2 import simple_spread_v3

    env_fn = (lambda: simple_spread_v3.parallel_env(N=2, continuous_actions=True)) if share else Rendezvous
    kwargs = dict(share_parameters="all", share_critics=True) if share else {}
    models = {
        precision: MADDPG("MlpPolicy", env_fn(), policy_kwargs=dict(net_arch=net_arch, precision=precision), seed=0,
                          **kwargs)  # fmt: skip
        for precision in ("fp32", "bf16")
    }
    obs_dim, act_dim = models["fp32"].observation_space.shape[0], models["fp32"].action_space.shape[0]
    obs, act = th.randn(64, obs_dim, device=models["fp32"].device), th.randn(64, act_dim, device=models["fp32"].device)
    GroupedMLP.use_onednn = onednn  # False: the batched path, as on other devices
    try:
        exact, low = (_outputs_and_grads(m, obs, act) for m in models.values())
        # acting on one observation: float32 products, the same as a float32 model's
        assert th.equal(models["fp32"].actor(obs[:1]), models["bf16"].actor(obs[:1]))
    finally:
        GroupedMLP.use_onednn = True
    assert len(exact) == len(low) > 2
    assert all(_close_in_bf16(a, b) for a, b in zip(exact, low))
    assert any(not th.equal(a, b) for a, b in zip(exact, low))  # the minibatch products really ran in bfloat16
    assert all(p.dtype == th.float32 for p in models["bf16"].policy.parameters())


def test_bf16_leaves_small_networks_in_fp32():
    models = [MADDPG("MlpPolicy", Rendezvous(), policy_kwargs=dict(net_arch=[32, 32], precision=p), seed=0)
              for p in ("fp32", "bf16")]  # fmt: skip
    obs, act = th.randn(64, 3, device=models[0].device), th.randn(64, 3, device=models[0].device)
    exact, low = (_outputs_and_grads(m, obs, act) for m in models)
    assert all(th.equal(a, b) for a, b in zip(exact, low))


@pytest.mark.parametrize("n_critics", [1, 2], ids=["maddpg", "matd3"])
def test_bf16_follows_every_weight_update(tmp_path, n_critics):
    env = make_joint_env(Rendezvous())
    td3 = dict(policy_delay=2, target_policy_noise=0.2) if n_critics == 2 else {}
    model = MADDPG("MlpPolicy", env, policy_kwargs=dict(net_arch=[128, 96], precision="bf16", n_critics=n_critics),
                   learning_starts=10, batch_size=16, action_noise=noise(), seed=0, **td3)  # fmt: skip
    obs, act = th.randn(16, 3, device=model.device), th.randn(16, 3, device=model.device)
    before = model.critic(obs, act)
    model.learn(40)  # fused Adam and foreach target updates change the weights in place
    exact = MADDPG("MlpPolicy", env, policy_kwargs=dict(net_arch=[128, 96], n_critics=n_critics), seed=1)
    exact.policy.load_state_dict(model.policy.state_dict())
    for net in ("critic", "critic_target", "actor", "actor_target"):
        args = (obs, act) if net.startswith("critic") else (obs,)
        assert _close_in_bf16(getattr(exact, net)(*args), getattr(model, net)(*args)), net
    assert not _close_in_bf16(before, model.critic(obs, act))  # (the weights did move)
    model.save(tmp_path / "bf16")
    loaded = MADDPG.load(tmp_path / "bf16", env=env)
    assert loaded.policy.precision == "bf16" and loaded.actor.mu.precision == "bf16"
    th.testing.assert_close(loaded.critic(obs, act), model.critic(obs, act), rtol=0, atol=0)
    with pytest.raises(ValueError, match="precision must be one of"):
        MADDPG("MlpPolicy", env, policy_kwargs=dict(precision="fp16"))


def test_per_agent_rewards_in_buffer():
    model = MADDPG("MlpPolicy", Rendezvous(), policy_kwargs=SMALL, learning_starts=1000, seed=0)
    model.learn(20)
    buf = model.replay_buffer
    assert isinstance(buf, MultiAgentReplayBuffer)
    np.testing.assert_allclose(buf.agent_rewards[:20, 0].sum(axis=1), buf.rewards[:20, 0], rtol=1e-5)
    assert buf.sample(4).rewards.shape == (4, 2)


def test_time_limit_bootstraps():
    model = MADDPG("MlpPolicy", Rendezvous(max_steps=5), policy_kwargs=SMALL, learning_starts=1000, seed=0)
    model.learn(10)
    buf = model.replay_buffer
    assert buf.dones[:10, 0].sum() == 2 and buf.timeouts[:10, 0].sum() == 2
    samples = buf._get_samples(np.arange(10))
    assert samples.dones.sum() == 0  # truncation is not termination


def test_save_load(tmp_path):
    env = make_joint_env(Rendezvous())
    model = MADDPG("MlpPolicy", env, policy_kwargs=SMALL, learning_starts=10, batch_size=8, action_noise=noise(), seed=0)
    model.learn(50)
    obs = np.stack([env.observation_space.sample() for _ in range(6)])
    expected, _ = model.predict(obs, deterministic=True)
    model.save(tmp_path / "maddpg.zip")
    model.save_replay_buffer(tmp_path / "buffer.pkl")

    loaded = MADDPG.load(tmp_path / "maddpg.zip")  # no env needed
    assert loaded.agent_layout == env.agent_layout
    np.testing.assert_allclose(loaded.predict(obs, deterministic=True)[0], expected, rtol=1e-6)
    for p1, p2 in zip(model.policy.parameters(), loaded.policy.parameters()):
        th.testing.assert_close(p1, p2)

    loaded = MADDPG.load(tmp_path / "maddpg.zip", env=make_joint_env(Rendezvous()))
    loaded.load_replay_buffer(tmp_path / "buffer.pkl")
    assert loaded.replay_buffer.size() == model.replay_buffer.size()
    np.testing.assert_array_equal(loaded.replay_buffer.agent_rewards, model.replay_buffer.agent_rewards)
    updates = loaded._n_updates
    loaded.learn(20, reset_num_timesteps=False)  # continued learning
    assert loaded.num_timesteps == 70 and loaded._n_updates == updates + 20
    assert loaded.replay_buffer.size() == 70


def test_load_with_mismatched_env(tmp_path):
    model = MADDPG("MlpPolicy", Rendezvous(), policy_kwargs=SMALL, seed=0)
    model.save(tmp_path / "m.zip")
    with pytest.raises(ValueError, match="spaces do not match"):
        MADDPG.load(tmp_path / "m.zip", env=speaker_listener())

    class Swapped(Rendezvous):  # same joint spaces, other agent split
        def __init__(self):
            super().__init__()
            self.possible_agents = ["b", "a"]

        def observation_space(self, agent):
            return super().observation_space("a" if agent == "b" else "b")

        def action_space(self, agent):
            return super().action_space("a" if agent == "b" else "b")

    swapped = make_joint_env(Swapped())
    swapped.observation_space = make_joint_env(Rendezvous()).observation_space
    swapped.action_space = make_joint_env(Rendezvous()).action_space
    with pytest.raises(ValueError, match="agents do not match"):
        MADDPG.load(tmp_path / "m.zip", env=swapped)


def test_determinism():
    def run(seed):
        model = MADDPG(
            "MlpPolicy", Rendezvous(), policy_kwargs=SMALL, learning_starts=10, batch_size=8, action_noise=noise(), seed=seed
        )
        model.learn(40)
        return [p.detach().clone() for p in model.policy.parameters()], model.replay_buffer.rewards[:40].copy()

    params1, rewards1 = run(1)
    params2, rewards2 = run(1)
    params3, _ = run(2)
    np.testing.assert_array_equal(rewards1, rewards2)
    for p1, p2 in zip(params1, params2):
        th.testing.assert_close(p1, p2, rtol=0, atol=0)
    assert any(not th.equal(p1, p3) for p1, p3 in zip(params1, params3))


def test_initial_agents_differ():
    # the paper's code re-seeded the RNG per agent, so same-shaped agents started identical
    model = MADDPG("MlpPolicy", Rendezvous(), policy_kwargs=SMALL, seed=0)
    w = model.critic.q_net.weights[1]
    assert not th.equal(w[0], w[1])


def test_bad_inputs():
    with pytest.raises(TypeError, match="multi-agent env"):
        MADDPG("MlpPolicy", gym.make("Pendulum-v1"))
    with pytest.raises(TypeError, match="MultiDiscrete action space"):
        MADDPG("MlpPolicy", Rendezvous(multi_discrete=True))
    with pytest.raises(ValueError, match="centralized_critic to MADDPG itself"):
        MADDPG("MlpPolicy", Rendezvous(), policy_kwargs=dict(centralized_critic=False))
    with pytest.raises(ValueError, match="'pi' and 'qf'"):
        MADDPG("MlpPolicy", Rendezvous(), policy_kwargs=dict(net_arch=dict(pi=[8])))
    with pytest.raises(ValueError, match="n_critics"):
        MADDPG("MlpPolicy", Rendezvous(), policy_kwargs=dict(n_critics=0))
    model = MADDPG("MlpPolicy", Rendezvous(nan_obs_step=3), policy_kwargs=SMALL, seed=0)
    with pytest.raises(ValueError, match="NaN"):
        model.learn(10)


def test_env_id_and_monitor_wrapped_env():
    env = Monitor(make_joint_env(Rendezvous()))
    model = MADDPG("MlpPolicy", env, policy_kwargs=SMALL, seed=0)
    assert model.agent_layout.agents == ("a", "b")


def test_learns_easy_cooperative_task():
    """MADDPG clearly beats a random policy on a small cooperative task within a small budget."""
    env = make_joint_env(Rendezvous())
    model = MADDPG(
        "MlpPolicy",
        env,
        learning_starts=200,
        batch_size=64,
        policy_kwargs=dict(net_arch=[64, 64]),
        action_noise=noise(sigma=0.2),
        seed=0,
    )
    eval_env = Monitor(make_joint_env(Rendezvous()))
    eval_env.reset(seed=123)
    rng = np.random.default_rng(0)

    class RandomPolicy:
        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            return rng.uniform(env.action_space.low, env.action_space.high, (1, 3)).astype(np.float32), None

    random_return, _ = evaluate_policy(RandomPolicy(), eval_env, n_eval_episodes=20)
    model.learn(1500)
    trained_return, _ = evaluate_policy(model, eval_env, n_eval_episodes=20)
    assert trained_return > random_return / 3, (random_return, trained_return)
    assert trained_return > -3.0


@pytest.mark.skipif(not th.cuda.is_available(), reason="no CUDA device on this machine")
def test_cuda_matches_cpu(tmp_path):
    from sb3_macb import MACB

    model = MADDPG(
        "MlpPolicy", Rendezvous(), policy_kwargs=SMALL, learning_starts=10, batch_size=8, action_noise=noise(),
        exploration=MACB(k=32), seed=0, device="cuda",
    )
    model.learn(40)
    assert next(model.policy.parameters()).is_cuda
    model.save(tmp_path / "m.zip")
    cpu = MADDPG.load(tmp_path / "m.zip", device="cpu")
    obs = np.random.default_rng(0).normal(size=(5, 3)).astype(np.float32)
    np.testing.assert_allclose(model.predict(obs, deterministic=True)[0], cpu.predict(obs, deterministic=True)[0], atol=1e-5)
    assert cpu.exploration.total_count == 40


def test_set_env_refuses_other_agents():
    model = MADDPG("MlpPolicy", Rendezvous(), policy_kwargs=SMALL, seed=0)
    env_before = model.env
    with pytest.raises(ValueError, match="spaces do not match|agents do not match"):
        model.set_env(speaker_listener())
    assert model.env is env_before
    model.set_env(make_joint_env(Rendezvous()))
    assert model.env is not env_before


def test_discrete_and_mixed_agents_train_predict_save_load(tmp_path):
    from sb3_macb import MACB

    env = make_vec_env(lambda: make_joint_env(Rendezvous(discrete=True)), n_envs=1)  # a: Discrete(3), b: Box
    model = MADDPG("MlpPolicy", env, exploration=MACB(beta=0.5, k=16), action_noise=noise(5, 0.3), policy_kwargs=SMALL,
                   learning_starts=30, batch_size=16, seed=0)  # fmt: skip
    model.learn(150)
    stored = model.replay_buffer.actions[:150, 0]  # scaled actions: a discrete agent's slice is one-hot (-1/+1)
    assert np.all(np.isin(stored[:, :3], [-1.0, 1.0])) and np.all((stored[:, :3] == 1.0).sum(axis=1) == 1)
    assert len(np.unique(stored[:, :3].argmax(axis=1))) == 3  # warm-up and Gumbel sampling explore every choice
    assert not np.all(np.isin(stored[:, 3:], [-1.0, 1.0]))  # the continuous agent keeps its noise
    obs = env.reset()
    action, _ = model.predict(obs, deterministic=True)
    assert np.isin(action[0, :3], [0.0, 1.0]).all() and action[0, :3].sum() == 1.0
    logits = model.actor.raw(th.as_tensor(obs, device=model.device))[0, :3]
    assert action[0, :3].argmax() == int(logits.argmax())  # the deterministic policy is the argmax
    model.save(tmp_path / "m.zip")
    loaded = MADDPG.load(tmp_path / "m.zip", env=env)
    assert np.array_equal(loaded.predict(obs, deterministic=True)[0], action)
    assert loaded.agent_layout.discrete_agents == (True, False)
    with pytest.raises(ValueError, match="do not match"):
        MADDPG.load(tmp_path / "m.zip", env=make_joint_env(Rendezvous()))  # the same agents, continuous


def test_straight_through_gumbel_softmax_gradient():
    layout = make_joint_env(Rendezvous(discrete=True)).agent_layout
    from sb3_macb.maddpg.policies import MultiAgentActor

    actor = MultiAgentActor(layout, [8])
    obs = th.randn(4, layout.obs_dim)
    raw = actor.raw(obs).detach().requires_grad_(True)
    out = actor.squash(raw, th.zeros(4, 5), straight_through=True)
    assert th.equal(out[:, :3], 2 * th.nn.functional.one_hot(raw[:, :3].argmax(1), 3).float() - 1)  # forward: hard
    out[:, 0].sum().backward()
    soft = th.softmax(raw[:, :3], dim=1).detach()
    expected = 2 * soft[:, 0:1] * ((th.arange(3) == 0).float() - soft)  # backward: d(2 softmax_0 - 1)/d logits
    assert th.allclose(raw.grad[:, :3], expected, atol=1e-6) and th.all(raw.grad[:, 3:] == 0)


def test_shared_critics_with_td3_settings_are_one_network_per_critic_and_all_learn(tmp_path):
    # the README's remedy for shared critics with many agents: twin critics, each shared by all agents
    from mpe2 import simple_spread_v3

    spread = lambda: make_joint_env(simple_spread_v3.parallel_env(N=3, continuous_actions=True, max_cycles=10))  # noqa: E731
    model = MADDPG("MlpPolicy", spread(), share_parameters="all", share_critics=True, policy_delay=2, target_policy_noise=0.2,
                   policy_kwargs=dict(net_arch=[16], n_critics=2), learning_starts=20, batch_size=8, seed=0)  # fmt: skip
    assert [w.shape[0] for w in model.critic.q_net.weights] == [2, 2]  # two critics x one shared group
    before = [w.detach().clone() for w in model.critic.q_net.weights]
    model.learn(60)
    for old, new in zip(before, model.critic.q_net.weights):
        assert not th.equal(old[0], new[0]) and not th.equal(old[1], new[1])  # both critics were trained
    obs = th.as_tensor(model.env.reset(), dtype=th.float32, device=model.device)
    q = model.critic(obs, model.actor(obs))
    assert q.shape == (2, 1, 3, 1) and th.isfinite(q).all() and not th.equal(q[0], q[1])
    model.save(tmp_path / "td3_shared.zip")
    loaded = MADDPG.load(tmp_path / "td3_shared.zip", env=spread())
    assert th.equal(loaded.critic(obs, loaded.actor(obs)), q)


def test_parameter_sharing_groups_ids_save_load_and_errors(tmp_path):
    from mpe2 import simple_spread_v3, simple_tag_v3

    spread = lambda: make_joint_env(simple_spread_v3.parallel_env(N=3, continuous_actions=True, max_cycles=10))  # noqa: E731
    model = MADDPG("MlpPolicy", spread(), share_parameters="all", share_critics=True, policy_kwargs=SMALL,
                   learning_starts=20, batch_size=8, seed=0)  # fmt: skip
    assert model.actor.mu.weights[0].shape[0] == 1 and model.critic.q_net.weights[0].shape[0] == 1
    model.learn(60)
    # agent i's action is the shared network applied to [its own observation, its one-hot id]
    obs = th.as_tensor(model.env.reset(), dtype=th.float32, device=model.device)
    layout, mu = model.agent_layout, model.actor.mu
    for i, sl in enumerate(layout.obs_slices):
        h = th.cat([obs[:, sl], th.nn.functional.one_hot(th.tensor([i], device=model.device), 3).float()], dim=1)
        for k, (w, b) in enumerate(zip(mu.weights, mu.biases)):
            h = h @ w[0].T + b[0]
            h = th.relu(h) if k < len(mu.weights) - 1 else th.tanh(h)
        assert th.allclose(model.actor(obs)[:, layout.action_slices[i]], h, atol=1e-6)
    model.save(tmp_path / "shared.zip")
    loaded = MADDPG.load(tmp_path / "shared.zip", env=spread())
    assert loaded.share_parameters == "all" and th.equal(loaded.actor(obs), model.actor(obs))
    with pytest.raises(ValueError, match="do not match"):
        MADDPG.load(tmp_path / "shared.zip", env=make_joint_env(simple_spread_v3.parallel_env(N=2, continuous_actions=True)))
    tag = simple_tag_v3.parallel_env(continuous_actions=True)  # adversary_0..2 (equal spaces) and agent_0
    grouped = MADDPG("MlpPolicy", tag, share_parameters="prefix", policy_kwargs=SMALL)
    assert grouped.actor.mu.weights[0].shape[0] == 2 and grouped.critic.q_net.weights[0].shape[0] == 4
    named = MADDPG("MlpPolicy", tag, share_parameters=[["adversary_0", "adversary_2"]], policy_kwargs=SMALL)
    assert named.actor.mu.weights[0].shape[0] == 3
    with pytest.raises(ValueError, match=r"cannot share networks.*\(14, 5, False\), \(16, 5, False\)"):
        MADDPG("MlpPolicy", tag, share_parameters="all")
    with pytest.raises(ValueError, match="does not have"):
        MADDPG("MlpPolicy", tag, share_parameters=[["adversary_0", "adversary_9"]])
    with pytest.raises(ValueError, match="give share_parameters too"):
        MADDPG("MlpPolicy", tag, share_critics=True)
    with pytest.raises(ValueError, match="centralized"):
        MADDPG("MlpPolicy", tag, share_parameters="prefix", share_critics=True, centralized_critic=False)


@pytest.mark.slow
def test_learns_discrete_speaker_listener():
    """Discrete MADDPG (straight-through Gumbel-softmax) on mpe2's default (discrete) speaker-listener, 25-step
    episodes: after 3,000 steps its return beats a uniformly random policy's by a wide margin (threshold fixed before
    the run: +15; measured in development: about -27 to -35 against about -70)."""
    from stable_baselines3.common.monitor import Monitor

    def env():
        return Monitor(make_joint_env(simple_speaker_listener_v4.parallel_env(max_cycles=25)))

    model = MADDPG("MlpPolicy", env(), seed=0, learning_starts=500, batch_size=128, policy_kwargs=dict(net_arch=[64, 64]))
    model.learn(3000)
    eval_env = env()
    eval_env.reset(seed=100)
    learned, _ = evaluate_policy(model, eval_env, n_eval_episodes=20)

    class Uniform:
        rng = np.random.default_rng(0)

        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            actions = self.rng.uniform(0, 1, size=(len(obs), 8)).astype(np.float32)
            return model._one_hot(actions), None

    random_env = env()
    random_env.reset(seed=100)
    random_return, _ = evaluate_policy(Uniform(), random_env, n_eval_episodes=20)
    assert learned > random_return + 15, (learned, random_return)


@pytest.mark.parametrize("flush", [True, False])
def test_denormals_are_flushed_during_learn_only_and_the_setting_is_restored(tmp_path, flush):
    from stable_baselines3.common.callbacks import BaseCallback

    from sb3_macb.maddpg.maddpg import flushing_denormals

    class Probe(BaseCallback):
        def _on_step(self) -> bool:
            self.seen = flushing_denormals()
            return True

    if not th.set_flush_denormal(False):
        pytest.skip("this CPU cannot flush denormals")
    model = MADDPG("MlpPolicy", Rendezvous(), policy_kwargs=SMALL, learning_starts=10, batch_size=8, seed=0,
                   flush_denormal=flush)  # fmt: skip
    probe = Probe()
    model.learn(30, callback=probe)
    assert probe.seen is flush and not flushing_denormals()  # on while learning (if asked), off again afterwards
    th.set_flush_denormal(True)  # a user's own setting is left as it was
    try:
        model.learn(20, callback=probe, reset_num_timesteps=False)
        assert probe.seen and flushing_denormals()
    finally:
        th.set_flush_denormal(False)
    model.save(tmp_path / "m.zip")
    assert MADDPG.load(tmp_path / "m.zip").flush_denormal is flush


def test_preactivation_reg_is_each_agents_mean_square_and_pulls_saturated_actors_back(tmp_path):
    for bad in (-1e-3, float("nan"), float("inf"), True, "1e-3"):
        with pytest.raises(ValueError, match="preactivation_reg must be a finite number >= 0"):
            MADDPG("MlpPolicy", Rendezvous(), preactivation_reg=bad)
    model = MADDPG("MlpPolicy", Rendezvous(), preactivation_reg=0.5, policy_kwargs=dict(net_arch=[8]))
    # agent a has 1 action component, b has 2: a's mean square (1 + 9) / 2 = 5, b's (4 + 16 + 0 + 0) / 4 = 5
    raw = th.tensor([[[1.0, 2.0, 4.0], [3.0, 0.0, 0.0]]], device=model.device)  # (1 run, batch 2, joint action)
    assert model._preactivation_penalty(raw).item() == pytest.approx(0.5 * (5 + 5))
    # a mixed pack (agent a Discrete(3): 3 logits, b continuous): only b's components count, and each run's sum
    mixed_env = make_vec_env(lambda: make_joint_env(Rendezvous(discrete=True)), n_envs=2, seed=0)
    mixed = MADDPG("MlpPolicy", mixed_env, preactivation_reg=0.5, n_runs=2,
                   policy_kwargs=dict(net_arch=[8]))  # fmt: skip
    raw = th.tensor([[[9.0, 9.0, 9.0, 2.0, 4.0]], [[9.0, 9.0, 9.0, 1.0, 1.0]]], device=mixed.device)  # (runs, batch, action)
    assert mixed._preactivation_penalty(raw).item() == pytest.approx(0.5 * ((4 + 16) / 2 + (1 + 1) / 2))

    def saturate_then_train(reg: float) -> tuple[float, float]:
        model = MADDPG("MlpPolicy", Rendezvous(), preactivation_reg=reg, seed=0, policy_kwargs=dict(net_arch=[16]),
                       learning_starts=50, batch_size=16)  # fmt: skip
        model.learn(200)
        with th.no_grad():
            for parameter in model.actor.parameters():
                parameter.mul_(5.0)  # drive the actors deep into tanh's flat part
        obs = th.as_tensor(model.replay_buffer.observations[:200, 0], dtype=th.float32, device=model.device)
        with th.no_grad():
            before = model.actor.raw(obs).abs().mean().item()
        model.learn(300, reset_num_timesteps=False)
        with th.no_grad():
            after = model.actor.raw(obs).abs().mean().item()
        if reg:
            model.save(tmp_path / "model.zip")
            assert MADDPG.load(tmp_path / "model.zip").preactivation_reg == reg
        return before, after

    before, after = saturate_then_train(0.0)
    assert after > 0.9 * before  # without the penalty the saturated outputs stay (here they grow)
    before, after = saturate_then_train(1e-2)
    assert after < 0.5 * before


def test_matd3_is_maddpg_with_td3_defaults(tmp_path):
    from sb3_macb import MATD3

    env = make_joint_env(Rendezvous())
    ours = MATD3("MlpPolicy", env, policy_kwargs=SMALL, learning_starts=10, batch_size=16, action_noise=noise(), seed=0)
    assert (ours.policy_delay, ours.target_policy_noise, ours.target_noise_clip, ours.policy.n_critics) == (2, 0.2, 0.5, 2)
    theirs = MADDPG("MlpPolicy", env, policy_kwargs={**SMALL, "n_critics": 2}, policy_delay=2, target_policy_noise=0.2,
                    learning_starts=10, batch_size=16, action_noise=noise(), seed=0)  # fmt: skip
    ours.learn(60)
    theirs.learn(60)
    for a, b in zip(ours.policy.state_dict().values(), theirs.policy.state_dict().values()):
        assert th.equal(a, b)
    ours.save(tmp_path / "matd3")
    loaded = MATD3.load(tmp_path / "matd3", env=env)
    assert type(loaded) is MATD3 and loaded.policy.n_critics == 2 and loaded.policy_delay == 2
    assert MATD3("MlpPolicy", env, policy_kwargs=dict(n_critics=3)).policy.n_critics == 3  # a user's choice is kept


def test_an_intrinsic_critic_keeps_the_bonus_out_of_the_reward_and_learns_its_return():
    from sb3_macb import MACB

    env = make_joint_env(Rendezvous())
    kwargs = dict(policy_kwargs=SMALL, learning_starts=10, batch_size=16, action_noise=noise(), seed=0)
    plain = MADDPG("MlpPolicy", env, **kwargs)
    # with weight 0 in the actors' objective the intrinsic critics change nothing else: the bonus is not a reward
    ours = MADDPG("MlpPolicy", env, exploration=MACB(0.8, 16), intrinsic_critic=True, intrinsic_coef=0.0, **kwargs)
    plain.learn(210)
    ours.learn(210)
    for name in ("actor", "critic"):
        for a, b in zip(getattr(plain, name).state_dict().values(), getattr(ours, name).state_dict().values()):
            assert th.allclose(a, b, atol=1e-6, rtol=0), name
    # a constant bonus of 0.8 with an intrinsic discount of 0: the intrinsic critics learn 0.8 everywhere
    constant = MADDPG("MlpPolicy", env, exploration=MACB(0.8, counts=False), intrinsic_critic=True, intrinsic_gamma=0.0,
                      **{**kwargs, "learning_rate": 3e-3})  # fmt: skip
    constant.learn(410)
    buffer = constant.replay_buffer
    obs = th.as_tensor(buffer.observations[:400, 0])
    actions = th.as_tensor(buffer.actions[:400, 0])
    with th.no_grad():
        values = constant.policy.critic_int(obs, actions)
    assert values.shape[-1] == 400 and float((values - 0.8).abs().mean()) < 0.05
    # shared networks: the intrinsic critics share as the critics do
    from mpe2 import simple_spread_v3

    spread = make_joint_env(simple_spread_v3.parallel_env(N=3, continuous_actions=True, max_cycles=10))
    shared = MADDPG("MlpPolicy", spread, exploration=MACB(0.8, 16), intrinsic_critic=True, share_parameters="all",
                    share_critics=True, policy_kwargs=SMALL, learning_starts=10, batch_size=16, seed=0)  # fmt: skip
    shared.learn(60)
    assert [p.shape for p in shared.policy.critic_int.parameters()] == [p.shape for p in shared.critic.parameters()]
    with pytest.raises(ValueError, match="intrinsic_critic=True learns an exploration bonus"):
        MADDPG("MlpPolicy", env, intrinsic_critic=True)
    with pytest.raises(ValueError, match="intrinsic_gamma must be"):
        MADDPG("MlpPolicy", env, exploration=MACB(), intrinsic_critic=True, intrinsic_gamma=1.5)


@pytest.mark.parametrize("continuous", [True, False], ids=["continuous", "discrete"])
def test_predict_agents_acts_in_a_raw_pettingzoo_loop(continuous):
    raw = lambda: simple_speaker_listener_v4.parallel_env(continuous_actions=continuous, max_cycles=5)  # noqa: E731
    model = MADDPG("MlpPolicy", make_joint_env(raw()), policy_kwargs=SMALL, seed=0)
    env = raw()
    observations, _ = env.reset(seed=0)
    steps = 0
    while env.agents:
        actions = model.predict_agents(observations)
        joint = np.concatenate([observations[a] for a in model.agent_layout.agents]).astype(np.float32)
        expected, _ = model.predict(joint, deterministic=True)
        for agent, sl in zip(model.agent_layout.agents, model.agent_layout.action_slices):
            assert env.action_space(agent).contains(actions[agent])
            if continuous:
                np.testing.assert_array_equal(actions[agent], expected[sl])
            else:
                assert actions[agent] == int(np.argmax(expected[sl]))
        observations, *_ = env.step(actions)
        steps += 1
    assert steps == 5
    with pytest.raises(KeyError, match="No observation for agent"):
        model.predict_agents({})

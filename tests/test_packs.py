"""Packs: K runs in one model, each the same experiment as a solo run with its seed."""

import inspect
import os

import numpy as np
import pytest
import torch as th
from rl_zoo3.utils import linear_schedule
from stable_baselines3.common.noise import NormalActionNoise

from sb3_macb import MACB, MADDPG
from sb3_macb.callbacks import MultiAgentEvalCallback, make_eval_vec_env
from sb3_macb.common.block_adam import BlockAdam
from sb3_macb.envs.vec_tasks import make_task_vec_env

COMM = "sb3_macb/CommunicativeNavigation-v0"
FIELDS = ("timesteps", "results", "successes", "final_successes", "episodes", "num_codes", "count1_fraction")


def train(seeds, explorations, steps, net_arch=(32, 32), sigmas=None, precision="fp32", buffer_size=1_000_000, **policy):
    """A pack (or a solo run, with one seed) on Communicative Navigation, evaluated every episode."""
    n = len(seeds)
    noises = [NormalActionNoise(np.zeros(5), s * np.ones(5)) for s in (sigmas or [0.1] * n)]
    model = MADDPG(
        "MlpPolicy",
        make_task_vec_env(COMM, n),
        n_runs=n,
        run_seeds=seeds,
        exploration=explorations,
        action_noise=noises,
        batch_size=16,
        buffer_size=buffer_size,
        learning_starts=40 * n,
        policy_kwargs=dict(net_arch=list(net_arch), precision=precision, **policy),
    )
    callback = MultiAgentEvalCallback(
        make_eval_vec_env(COMM, 4, seeds), n_eval_episodes=4, eval_freq=20, verbose=0, warn=False
    )
    model.learn(steps * n, callback=callback)
    return model, callback


def settings():
    # the paper's form, none, per-agent counts in narrow sketches normalised, and a constant bonus whose beta falls over
    # training
    return [
        MACB(0.8, 64),
        None,
        MACB(0.8, 512, scope="local", normalize="zscore", table="sketch", sketch_width=101),
        MACB(linear_schedule(0.8), counts=False),
    ]


@pytest.mark.parametrize("net_arch", [(32, 32), (128, 96)], ids=["batched-small-layers", "per-group-large-layers"])
def test_every_run_of_a_pack_is_bit_identical_to_its_solo_run(net_arch):
    seeds, sigmas = [3, 4, 5, 6], [0.1, 0.2, 0.1, 0.3]
    steps = 300 if net_arch == (32, 32) else 120
    buffer_size = steps // 3  # every run's buffer wraps twice: each run keeps buffer_size transitions, as alone
    pack, pack_cb = train(seeds, settings(), steps, net_arch, sigmas, buffer_size=buffer_size)
    assert pack.replay_buffer.full and pack.replay_buffer.buffer_size_per_run == buffer_size
    for k, (seed, exploration) in enumerate(zip(seeds, settings())):
        solo, solo_cb = train([seed], [exploration], steps, net_arch, [sigmas[k]], buffer_size=buffer_size)
        assert solo.replay_buffer.buffer_size == pack.replay_buffer.buffer_size
        for name in FIELDS:
            assert np.array_equal(np.asarray(solo_cb.records[0][name]), np.asarray(pack_cb.records[k][name])), (k, name)
        run = pack.get_run(k)
        for a, b in zip(run.policy.state_dict().values(), solo.policy.state_dict().values()):
            assert th.equal(a, b), k
        for name in ("actor", "critic"):
            ours, theirs = getattr(run, name).optimizer.state_dict(), getattr(solo, name).optimizer.state_dict()
            for i in theirs["state"]:
                assert th.equal(ours["state"][i]["exp_avg_sq"], theirs["state"][i]["exp_avg_sq"])
        assert run.num_timesteps == solo.num_timesteps and run._n_updates == solo._n_updates
        if exploration is not None:
            assert run.exploration.num_codes == solo.exploration.num_codes
            assert run.exploration.total_count == solo.exploration.total_count == steps


def test_a_bf16_pack_is_bit_identical_to_its_solo_runs():
    # large layers run group by group, so bfloat16 rounding does not depend on the other runs either
    seeds = [3, 4]
    pack, pack_cb = train(seeds, [MACB(0.8, 64), None], 100, (128, 96), precision="bf16", buffer_size=60)
    for k, (seed, exploration) in enumerate(zip(seeds, [MACB(0.8, 64), None])):
        solo, solo_cb = train([seed], [exploration], 100, (128, 96), precision="bf16", buffer_size=60)
        for name in FIELDS:
            assert np.array_equal(np.asarray(solo_cb.records[0][name]), np.asarray(pack_cb.records[k][name])), (k, name)
        run = pack.get_run(k)
        assert run.policy.precision == "bf16"
        for a, b in zip(run.policy.state_dict().values(), solo.policy.state_dict().values()):
            assert th.equal(a, b), k


def test_large_layers_on_the_batched_path_keep_packs_bit_identical_to_solo_runs():
    seeds = [3, 4]
    pack, pack_cb = train(seeds, settings()[:2], 100, (128, 96), buffer_size=60, large_layers="batched")
    assert pack.actor.mu.large_layers == pack.critic.q_net.large_layers == "batched"
    default, _ = train(seeds, settings()[:2], 100, (128, 96), buffer_size=60)
    assert not th.equal(pack.critic.q_net.weights[1], default.critic.q_net.weights[1])  # the other path's rounding
    for k, (seed, exploration) in enumerate(zip(seeds, settings()[:2])):
        solo, solo_cb = train([seed], [exploration], 100, (128, 96), buffer_size=60, large_layers="batched")
        for name in FIELDS:
            assert np.array_equal(np.asarray(solo_cb.records[0][name]), np.asarray(pack_cb.records[k][name])), (k, name)
        for a, b in zip(pack.get_run(k).policy.state_dict().values(), solo.policy.state_dict().values()):
            assert th.equal(a, b), k
    with pytest.raises(ValueError, match="large_layers"):
        MADDPG("MlpPolicy", make_task_vec_env(COMM, 1), policy_kwargs=dict(large_layers="fast"))


def test_get_run_carries_every_constructor_setting():
    # each argument of MADDPG.__init__ is either kept as it is (_RUN_SETTINGS) or set for the run by get_run
    per_run = {"policy", "env", "device", "seed", "n_runs", "run_seeds", "exploration", "action_noise",
               "learning_starts", "replay_buffer_class", "stats_window_size", "_init_setup_model"}  # fmt: skip
    arguments = set(inspect.signature(MADDPG.__init__).parameters) - {"self"}
    assert set(MADDPG._RUN_SETTINGS) | per_run == arguments and not set(MADDPG._RUN_SETTINGS) & per_run
    pack = MADDPG("MlpPolicy", make_task_vec_env(COMM, 2), n_runs=2, seed=0, gamma=0.9, tau=0.02, preactivation_reg=0.1,
                  policy_kwargs=dict(net_arch=[8]))  # fmt: skip
    run = pack.get_run(1)
    assert (run.gamma, run.tau, run.preactivation_reg, run.run_seeds, run.seed) == (0.9, 0.02, 0.1, [1], 1)


def test_a_run_handed_out_works_alone(tmp_path):
    pack, _ = train([0, 1], [MACB(0.8, 64), None], 100)
    run = pack.get_run(0)
    obs = make_task_vec_env(COMM, 3).reset()
    action, _ = run.predict(obs, deterministic=True)
    assert action.shape == (3, 5)
    packed_actions, _ = pack.predict(np.concatenate([obs, obs]), deterministic=True)  # run 0's rows, then run 1's
    assert np.array_equal(packed_actions[:3], action) and not np.array_equal(packed_actions[3:], action)
    run.save(tmp_path / "run0.zip")
    loaded = MADDPG.load(tmp_path / "run0.zip")
    assert np.array_equal(loaded.predict(obs, deterministic=True)[0], action)
    assert loaded.exploration.num_codes == run.exploration.num_codes > 0
    run.set_env(make_task_vec_env(COMM, 1))
    run.learn(40, reset_num_timesteps=False)  # it trains on
    assert run.num_timesteps == 140


def test_a_pack_saves_and_loads(tmp_path):
    pack, _ = train([0, 1, 2], [MACB(0.8, 64), None, MACB(0.4, counts=False)], 60)
    pack.save(tmp_path / "pack")
    loaded = MADDPG.load(tmp_path / "pack.zip")
    assert loaded.n_runs == 3 and loaded.run_seeds == [0, 1, 2]
    assert loaded.explorations[0].num_codes == pack.explorations[0].num_codes > 0
    assert loaded.explorations[1] is None and loaded.explorations[2].total_count == 60
    obs = make_task_vec_env(COMM, 6).reset()
    assert np.array_equal(loaded.predict(obs, deterministic=True)[0], pack.predict(obs, deterministic=True)[0])
    with pytest.raises(ValueError, match="3 runs"):
        pack.predict(obs[:4], deterministic=True)


def test_bad_pack_settings_are_named():
    env = make_task_vec_env(COMM, 2)
    with pytest.raises(ValueError, match="n_runs"):
        MADDPG("MlpPolicy", env, n_runs=0)
    with pytest.raises(ValueError, match="run_seeds"):
        MADDPG("MlpPolicy", env, n_runs=2, run_seeds=[1])
    with pytest.raises(ValueError, match="exploration"):
        MADDPG("MlpPolicy", env, n_runs=2, exploration=[MACB()])
    with pytest.raises(ValueError, match="action_noise"):
        MADDPG("MlpPolicy", env, n_runs=2, action_noise=[NormalActionNoise(np.zeros(5), np.ones(5))])
    with pytest.raises(ValueError, match="divisible"):
        MADDPG("MlpPolicy", make_task_vec_env(COMM, 3), n_runs=2)
    with pytest.raises(ValueError, match="counts"):
        MACB(counts="no")
    model = MADDPG("MlpPolicy", env, n_runs=2, seed=0, policy_kwargs=dict(net_arch=[8]))
    assert model.run_seeds == [0, 1]
    with pytest.raises(AttributeError, match="explorations"):
        _ = model.exploration
    with pytest.raises(IndexError):
        model.get_run(2)


def test_constant_bonus_control_adds_beta_and_counts_nothing():
    model, callback = train([0], [MACB(0.5, 512, counts=False)], 80)
    macb = model.exploration
    assert macb.num_codes == 0 and macb.total_count == 80 and not macb.hashes
    batch = model.replay_buffer.sample_runs(32, [np.random.default_rng(0)])
    stored = model.replay_buffer.agent_rewards[: model.replay_buffer.pos, 0]
    assert set(np.unique(batch.rewards.cpu().numpy() - 0.5)) <= set(np.unique(stored))  # reward + beta exactly
    assert repr(macb).endswith("counts=False)")
    assert MACB(**macb.config).counts is False


def test_final_step_success_is_recorded_beside_any_step_success(tmp_path):
    easy = dict(success_radius=100.0)
    env = make_task_vec_env(COMM, 1, easy)
    model = MADDPG("MlpPolicy", env, learning_starts=1000, policy_kwargs=dict(net_arch=[8]), seed=0)
    callback = MultiAgentEvalCallback(make_eval_vec_env(COMM, 3, [0], easy), n_eval_episodes=3, eval_freq=20,
                                      log_path=str(tmp_path), verbose=0, warn=False)  # fmt: skip
    model.learn(40, callback=callback)
    data = np.load(tmp_path / "evaluations.npz")
    assert data["final_successes"].shape == data["successes"].shape == (2, 3)
    assert data["final_successes"].all() and data["episodes"].tolist() == [1, 2]


def test_block_adam_updates_blocks_as_adam_updates_whole_tensors():
    th.manual_seed(0)
    whole = [th.nn.Parameter(th.randn(6, 5, 7)), th.nn.Parameter(th.randn(6, 5))]
    blocks = [th.nn.Parameter(p.detach().clone()) for p in whole]
    adam = th.optim.Adam(whole, lr=1e-2, fused=True)
    block_adam = BlockAdam(blocks, blocks=[[(0, 2), (2, 4), (4, 6)]] * 2, lr=1e-2)
    for _ in range(20):
        grads = [th.randn_like(p) for p in whole]
        for params, opt in ((whole, adam), (blocks, block_adam)):
            for p, g in zip(params, grads):
                p.grad = g.clone()
            opt.step()
    for a, b in zip(whole, blocks):
        th.testing.assert_close(a, b, rtol=1e-6, atol=1e-7)
        assert not th.equal(a, whole[0] * 0)
    state = block_adam.state_dict()
    again = BlockAdam([th.nn.Parameter(p.detach().clone()) for p in blocks], blocks=[[(0, 2), (2, 4), (4, 6)]] * 2, lr=1e-2)
    again.load_state_dict(state)
    assert float(again.state_dict()["state"][0]["step"]) == 20.0


def test_block_adam_is_bit_identical_to_one_fused_adam_per_block():
    # each block is stepped as a tensor of its own: a separate fused Adam on a copy of the block computes the same bits,
    # through steps where a parameter has no gradient, a new parameter group's state, and a reload of the state
    bounds = [(0, 3), (3, 5), (5, 6)]
    gen = th.Generator().manual_seed(1)
    weights = th.nn.Parameter(th.randn(6, 17, 9, generator=gen))
    bias = th.nn.Parameter(th.randn(6, 17, generator=gen))
    optimizer = BlockAdam([weights, bias], blocks=[bounds, bounds], lr=3e-2)
    copies = [[th.nn.Parameter(p.detach()[a:b].clone()) for a, b in bounds] for p in (weights, bias)]
    singles = [[th.optim.Adam([c], lr=3e-2, fused=True) for c in row] for row in copies]
    for step in range(12):
        grads = [th.randn(p.shape, generator=gen) for p in (weights, bias)]
        with_grad = (0,) if step in (3, 4) else (0, 1)  # the bias has no gradient at steps 3 and 4
        for i, p in enumerate((weights, bias)):
            p.grad = grads[i].clone() if i in with_grad else None
            for (a, b), c, opt in zip(bounds, copies[i], singles[i]):
                if i in with_grad:
                    c.grad = grads[i][a:b].clone()
                    opt.step()
        optimizer.step()
        if step == 6:  # a new optimizer that loads the state goes on with the same bits
            state = optimizer.state_dict()
            optimizer = BlockAdam([weights, bias], blocks=[bounds, bounds], lr=3e-2)
            optimizer.load_state_dict(state)
        for i, p in enumerate((weights, bias)):
            for (a, b), c in zip(bounds, copies[i]):
                assert th.equal(p.detach()[a:b], c.detach()), (step, i, a)
    assert float(optimizer.state[weights]["step"]) == 12.0 and float(optimizer.state[bias]["step"]) == 10.0


def test_a_pack_with_discrete_agents_is_bit_identical_to_its_solo_runs():
    from stable_baselines3.common.env_util import make_vec_env

    from sb3_macb import make_joint_env
    from toy_envs import Rendezvous

    def run(seeds):
        env = make_vec_env(lambda: make_joint_env(Rendezvous(discrete=True)), n_envs=len(seeds))
        model = MADDPG("MlpPolicy", env, n_runs=len(seeds), run_seeds=seeds, batch_size=8, learning_starts=20 * len(seeds),
                       buffer_size=50, policy_kwargs=dict(net_arch=[16]),
                       exploration=[MACB(0.5, 16) for _ in seeds])  # fmt: skip
        model.learn(120 * len(seeds))
        assert model.replay_buffer.full
        return model

    pack = run([3, 4])
    for k, seed in enumerate([3, 4]):
        solo, member = run([seed]), pack.get_run(k)
        for a, b in zip(solo.actor.parameters(), member.actor.parameters()):
            assert th.equal(a, b)


def test_a_matd3_pack_is_bit_identical_to_its_solo_runs():
    # target policy noise, delayed actor updates and twin critics: the noise comes from each run's own generator
    def run(seeds):
        model = MADDPG("MlpPolicy", make_task_vec_env(COMM, len(seeds)), n_runs=len(seeds), run_seeds=seeds, batch_size=16,
                       learning_starts=40 * len(seeds), policy_delay=2, target_policy_noise=0.2, buffer_size=60,
                       policy_kwargs=dict(net_arch=[16], n_critics=2), exploration=[MACB(0.8, 64) for _ in seeds])  # fmt: skip
        model.learn(150 * len(seeds))
        assert model.replay_buffer.full
        return model

    pack = run([3, 4])
    for k, seed in enumerate([3, 4]):
        solo, member = run([seed]), pack.get_run(k)
        assert solo._n_updates == member._n_updates > 0
        for a, b in zip(solo.policy.state_dict().values(), member.policy.state_dict().values()):
            assert th.equal(a, b), k


@pytest.mark.parametrize("share_critics", [False, True])
def test_a_pack_with_shared_networks_is_bit_identical_to_its_solo_runs(share_critics):
    from mpe2 import simple_spread_v3
    from stable_baselines3.common.env_util import make_vec_env

    from sb3_macb import make_joint_env

    def run(seeds):
        env = make_vec_env(lambda: make_joint_env(simple_spread_v3.parallel_env(N=3, continuous_actions=True, max_cycles=10)),
                           n_envs=len(seeds))  # fmt: skip
        model = MADDPG("MlpPolicy", env, n_runs=len(seeds), run_seeds=seeds, batch_size=8, learning_starts=20 * len(seeds),
                       buffer_size=30, policy_kwargs=dict(net_arch=[16]), share_parameters="all", share_critics=share_critics,
                       action_noise=[NormalActionNoise(np.zeros(15), 0.1 * np.ones(15)) for _ in seeds])  # fmt: skip
        model.learn(80 * len(seeds))
        assert model.replay_buffer.full
        return model

    pack = run([5, 6])
    for k, seed in enumerate([5, 6]):
        solo, member = run([seed]), pack.get_run(k)
        for a, b in zip(
            [*solo.actor.parameters(), *solo.critic.parameters()], [*member.actor.parameters(), *member.critic.parameters()]
        ):
            assert th.equal(a, b)


def test_each_run_of_a_pack_keeps_buffer_size_transitions_and_its_own_update_count():
    # SB3's ReplayBuffer divides buffer_size by the number of envs; a pack's buffer must not shrink each run's share
    pack = MADDPG("MlpPolicy", make_task_vec_env(COMM, 3), n_runs=3, run_seeds=[0, 1, 2], buffer_size=600,
                  policy_kwargs=dict(net_arch=[8]))  # fmt: skip
    assert pack.replay_buffer.buffer_size == 600 and pack.replay_buffer.buffer_size_per_run == 600
    assert pack.replay_buffer.observations.shape[:2] == (600, 3)
    two_envs = MADDPG("MlpPolicy", make_task_vec_env(COMM, 4), n_runs=2, run_seeds=[0, 1], buffer_size=600,
                      policy_kwargs=dict(net_arch=[8]))  # fmt: skip
    assert two_envs.replay_buffer.buffer_size_per_run == 600 and two_envs.replay_buffer.buffer_size == 300
    # gradient_steps=-1 (as many updates as steps) counts one run's steps, not the pack's
    updates = []
    for n in (1, 3):
        model = MADDPG("MlpPolicy", make_task_vec_env(COMM, n), n_runs=n, run_seeds=list(range(n)), gradient_steps=-1,
                       train_freq=5, learning_starts=20 * n, batch_size=8, policy_kwargs=dict(net_arch=[8]))  # fmt: skip
        model.learn(60 * n)
        updates.append(model._n_updates)
    assert updates[0] == updates[1] > 0
    with pytest.raises(ValueError, match="train_freq"):
        MADDPG("MlpPolicy", make_task_vec_env(COMM, 2), n_runs=2, train_freq=(1, "episode"), policy_kwargs=dict(net_arch=[8]))


def test_one_macb_object_given_for_every_run_is_copied_per_run():
    shared = MACB(0.8, 32)
    model = MADDPG("MlpPolicy", make_task_vec_env(COMM, 2), n_runs=2, run_seeds=[0, 1], exploration=[shared] * 2,
                   learning_starts=20, batch_size=8, policy_kwargs=dict(net_arch=[8]))  # fmt: skip
    first, second = model.explorations
    assert first is not second and first.tables[0] is not second.tables[0]
    assert not np.array_equal(first.hashes[0].matrix_t, second.hashes[0].matrix_t)  # each seeded by its run's seed
    model.learn(2 * 50)
    assert first.total_count == second.total_count == 50  # each counts its own run's 50 transitions
    solo = MADDPG("MlpPolicy", make_task_vec_env(COMM, 1), seed=1, exploration=MACB(0.8, 32), learning_starts=10,
                  batch_size=8, policy_kwargs=dict(net_arch=[8]))  # fmt: skip
    assert np.array_equal(solo.exploration.hashes[0].matrix_t, second.hashes[0].matrix_t)


def test_an_intrinsic_critic_pack_with_matd3_settings_is_bit_identical_to_its_solo_runs(tmp_path):
    def make(seeds, explorations):
        return MADDPG("MlpPolicy", make_task_vec_env(COMM, len(seeds)), n_runs=len(seeds), run_seeds=seeds,
                      exploration=explorations, intrinsic_critic=True, intrinsic_gamma=0.9, intrinsic_coef=0.5,
                      policy_kwargs=dict(net_arch=[32, 32], n_critics=2), policy_delay=2, target_policy_noise=0.2,
                      batch_size=16, buffer_size=50, learning_starts=40 * len(seeds))  # fmt: skip

    settings = [MACB(0.8, 64, normalize="center"), None, MACB(0.8, counts=False)]
    pack = make([3, 4, 5], settings)
    pack.learn(3 * 150)  # the buffer of 50 wraps twice
    for k, (seed, exploration) in enumerate(
        zip([3, 4, 5], [MACB(0.8, 64, normalize="center"), None, MACB(0.8, counts=False)])
    ):
        solo = make([seed], [exploration]) if exploration is not None else None
        if solo is None:  # a run without exploration learns a zero bonus; alone it needs one to have the critic
            continue
        solo.learn(150)
        run = pack.get_run(k)
        for a, b in zip(run.policy.state_dict().values(), solo.policy.state_dict().values()):
            assert th.equal(a, b), k
        ours, theirs = run.policy.critic_int.optimizer.state_dict(), solo.policy.critic_int.optimizer.state_dict()
        for i in theirs["state"]:
            assert th.equal(ours["state"][i]["exp_avg_sq"], theirs["state"][i]["exp_avg_sq"])
    pack.save(tmp_path / "pack")
    loaded = MADDPG.load(tmp_path / "pack", env=make_task_vec_env(COMM, 3))
    for a, b in zip(loaded.policy.state_dict().values(), pack.policy.state_dict().values()):
        assert th.equal(a, b)
    assert loaded.intrinsic_critic and loaded.intrinsic_gamma == 0.9 and loaded.intrinsic_coef == 0.5


def test_a_pack_of_rnd_runs_is_bit_identical_to_its_solo_runs():
    from sb3_macb import RND

    def make(seeds, explorations):
        return MADDPG("MlpPolicy", make_task_vec_env(COMM, len(seeds)), n_runs=len(seeds), run_seeds=seeds,
                      exploration=explorations, policy_kwargs=dict(net_arch=[32, 32]), batch_size=16, buffer_size=60,
                      learning_starts=40 * len(seeds))  # fmt: skip

    settings = lambda: [RND(0.5), RND(0.5, scope="local", normalize=None)]  # noqa: E731
    pack = make([7, 8], settings())
    pack.learn(2 * 150)  # the buffer of 60 wraps twice
    for k, (seed, exploration) in enumerate(zip([7, 8], settings())):
        solo = make([seed], [exploration])
        solo.learn(150)
        run = pack.get_run(k)
        for a, b in zip(run.policy.state_dict().values(), solo.policy.state_dict().values()):
            assert th.equal(a, b), k
        for name, tensor in solo.exploration.state_dict().items():
            assert th.equal(run.exploration.state_dict()[name], tensor), (k, name)


def test_a_pack_saved_by_sb3_macb_0_12_loads():
    # tests/data/pack_v0_12.zip: a pack of two runs (MACB k=16 in run 0, none in run 1, 8-unit layers), 120 steps,
    # saved by sb3_macb 0.12, which held the runs' seeds, generators and explorations as separate model attributes
    data = os.path.join(os.path.dirname(__file__), "data")
    expected = np.load(os.path.join(data, "pack_v0_12_expected.npz"))
    model = MADDPG.load(os.path.join(data, "pack_v0_12.zip"))
    assert model.n_runs == 2 and model.run_seeds == [3, 4] and model.pack.n_runs == 2
    assert not {"n_runs", "run_seeds", "explorations", "_run_rngs"} & set(vars(model))
    assert model.num_timesteps == expected["num_timesteps"] and model.run_timesteps == expected["num_timesteps"] // 2
    assert np.array_equal(model.predict(expected["obs"], deterministic=True)[0], expected["actions"])
    assert model.explorations[0].num_codes == expected["num_codes"] > 0 and model.explorations[1] is None
    assert model.explorations[0].total_count == expected["total_count"]
    run = model.get_run(0)
    assert run.exploration.num_codes == expected["num_codes"] and run._n_updates == expected["n_updates"]
    assert np.array_equal(run.pack.rngs[0].random(3), expected["rng_draw"])  # the generator's state was carried
    model.set_env(make_task_vec_env(COMM, 2))
    model.learn(20, reset_num_timesteps=False)
    assert model.explorations[0].total_count == expected["total_count"] + 10

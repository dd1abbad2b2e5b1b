import warnings
from collections import Counter

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.noise import NormalActionNoise

from sb3_macb import MACB, MADDPG, MACBReplayBuffer, MultiAgentReplayBuffer, make_joint_env
from sb3_macb.exploration import CountTable, SimHash
from toy_envs import Rendezvous

SMALL = dict(net_arch=[32, 32])


def make_model(exploration, env=None, **kwargs):
    kwargs = {"learning_starts": 10, "batch_size": 8, "seed": 0, "policy_kwargs": SMALL, **kwargs}
    noise = NormalActionNoise(np.zeros(3), 0.1 * np.ones(3))
    return MADDPG("MlpPolicy", env or Rendezvous(), exploration=exploration, action_noise=noise, **kwargs)


def add(buffer, obs, action, agent_rewards):
    obs = np.asarray(obs, dtype=np.float32)[None]
    action = np.asarray(action, dtype=np.float32)[None]
    agent_rewards = np.asarray(agent_rewards, dtype=np.float32)
    buffer.add(obs, obs, action, np.array([agent_rewards.sum()]), np.array([0.0]), [{"agent_rewards": agent_rewards}])


# --- count table ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("chunk", [1 << 16, 7], ids=["one-chunk", "many-chunks"])
def test_count_table_matches_a_counter_through_growth(monkeypatch, chunk):
    monkeypatch.setattr(CountTable, "chunk", chunk)  # growth and large batches are probed chunk by chunk
    rng = np.random.default_rng(0)
    table = CountTable(capacity=16)
    reference: Counter = Counter()
    for _ in range(200):
        keys = rng.integers(1, 3000, size=rng.integers(1, 40)).astype(np.uint64)  # repeats within and across batches
        table.add(keys)
        reference.update(keys.tolist())
        # a few keys (probed one by one past their home slot) and many (the vectorized probe), a missing one among them
        for size in (rng.integers(1, 30), 300):
            few = np.append(rng.choice(np.fromiter(reference, dtype=np.uint64), size=size), np.uint64(4000 + size))
            np.testing.assert_array_equal(table.lookup(few), [reference[int(k)] for k in few])
    assert table.num_codes == len(reference)
    assert table.total_count == sum(reference.values())
    assert table.num_count1 == sum(1 for v in reference.values() if v == 1)
    probe = np.array(list(reference)[:500] + [999_999], dtype=np.uint64)
    np.testing.assert_array_equal(table.lookup(probe), [reference[int(k)] for k in probe])
    assert table.capacity >= table.num_codes / CountTable.max_load
    assert table.nbytes / table.num_codes <= 32


def test_count_table_slot_arrays_load_as_they_are_and_are_not_shared():
    table = CountTable()
    table.add(np.arange(1, 200, dtype=np.uint64) * np.uint64(7919))
    table.add(np.array([7919, 7919], dtype=np.uint64))
    arrays = table.arrays()
    loaded = CountTable.from_arrays(arrays["keys"], arrays["counts"], table.total_count)
    assert (loaded.num_codes, loaded.total_count, loaded.num_count1, loaded.capacity) == \
        (table.num_codes, table.total_count, table.num_count1, table.capacity)
    loaded.add(np.array([5], dtype=np.uint64))
    assert table.lookup(np.array([5], dtype=np.uint64))[0] == 0  # its own memory
    with pytest.raises(ValueError, match="power-of-two"):
        CountTable.from_arrays(arrays["keys"][:100], arrays["counts"][:100], 1)


def test_count_table_state_roundtrip():
    table = CountTable()
    table.add(np.array([5, 5, 9, 11, 11, 11], dtype=np.uint64))
    copy = CountTable.from_state(**table.state())
    np.testing.assert_array_equal(copy.lookup(np.array([5, 9, 11, 7], dtype=np.uint64)), [2, 1, 3, 0])
    assert (copy.num_codes, copy.total_count, copy.num_count1) == (3, 6, 1)


def test_simhash_groups_by_angle_and_is_seeded():
    h1 = SimHash(64, 4, np.random.default_rng(3), decimals=None)
    h2 = SimHash(64, 4, np.random.default_rng(3), decimals=None)
    v = np.random.default_rng(0).normal(size=(50, 4)).astype(np.float32)
    np.testing.assert_array_equal(h1.keys(v), h2.keys(v))
    np.testing.assert_array_equal(h1.keys(v), h1.keys(2.5 * v))  # sign(A v) is invariant to scaling
    assert len(np.unique(h1.keys(v))) == 50
    h_short = SimHash(1, 4, np.random.default_rng(3), decimals=None)
    assert len(np.unique(h_short.keys(v))) == 2  # one bit: two codes


# --- MACB settings ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(k=0), "k"),
        (dict(k=2.5), "k"),
        (dict(beta=-0.1), "beta"),
        (dict(beta="x"), "beta"),
        (dict(scope="global"), "unknown scope"),
        (dict(decimals=-1), "decimals"),
    ],
)
def test_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        MACB(**kwargs)


def test_from_dict():
    model = make_model({"beta": 0.4, "k": 16, "scope": "local"})
    assert isinstance(model.exploration, MACB)
    assert (model.exploration.beta, model.exploration.k, model.exploration.scope) == (0.4, 16, "local")
    with pytest.raises(ValueError, match=r"Unknown MACB option\(s\) \['bta'\]"):
        make_model({"bta": 0.4})
    with pytest.raises(TypeError, match="exploration must be"):
        make_model(0.8)


# --- buffer and bonus -----------------------------------------------------------------------------------------------


def test_exact_bonus_values_and_sampling_changes_nothing():
    model = make_model(MACB(beta=0.5, k=32, decimals=None), learning_starts=10_000)
    buffer = model.replay_buffer
    assert isinstance(buffer, MACBReplayBuffer)
    t1 = ([0.1, 0.2, 0.5], [0.3, -0.2, 0.1], [-1.0, -2.0])
    t2 = ([-0.7, 0.4, 0.5], [-0.9, 0.4, 0.2], [0.0, 0.0])
    add(buffer, *t1)
    add(buffer, *t1)
    add(buffer, *t1)
    add(buffer, *t2)
    exploration = model.exploration
    assert exploration.total_count == 4 and exploration.num_codes == 2
    assert exploration.count1_fraction == pytest.approx(0.5)

    rewards_before = buffer.agent_rewards.copy()
    counts_before = exploration.tables[0].counts.copy()
    samples = buffer._get_samples(np.array([0, 1, 2, 3, 3]))
    expected = np.array(
        [
            [-1.0 + 0.5 / np.sqrt(3), -2.0 + 0.5 / np.sqrt(3)],
            [-1.0 + 0.5 / np.sqrt(3), -2.0 + 0.5 / np.sqrt(3)],
            [-1.0 + 0.5 / np.sqrt(3), -2.0 + 0.5 / np.sqrt(3)],
            [0.5, 0.5],
            [0.5, 0.5],
        ]
    )
    np.testing.assert_allclose(samples.rewards.cpu().numpy(), expected, rtol=1e-6)
    for _ in range(5):
        buffer.sample(4)
    np.testing.assert_array_equal(buffer.agent_rewards, rewards_before)  # the bonus is never stored
    np.testing.assert_array_equal(exploration.tables[0].counts, counts_before)  # sampling counts nothing
    assert exploration.total_count == 4


def test_bonus_uses_current_counts():
    model = make_model(MACB(beta=1.0, k=32, decimals=None), learning_starts=10_000)
    t = ([0.1, 0.2, 0.5], [0.3, -0.2, 0.1], [0.0, 0.0])
    add(model.replay_buffer, *t)
    assert model.replay_buffer._get_samples(np.array([0])).rewards[0, 0].item() == pytest.approx(1.0)
    for _ in range(3):
        add(model.replay_buffer, *t)
    assert model.replay_buffer._get_samples(np.array([0])).rewards[0, 0].item() == pytest.approx(0.5)


@pytest.mark.parametrize("scope, n_tables", [("joint", 1), ("state", 1), ("local", 2)])
def test_scopes(scope, n_tables):
    model = make_model(MACB(beta=1.0, k=32, scope=scope, decimals=None), learning_starts=10_000)
    exploration = model.exploration
    assert exploration.n_tables == n_tables
    # same observation, different actions: joint counts two codes, state one
    add(model.replay_buffer, [0.1, 0.2, 0.5], [0.3, -0.2, 0.1], [0.0, 0.0])
    add(model.replay_buffer, [0.1, 0.2, 0.5], [-0.3, 0.2, -0.1], [0.0, 0.0])
    # agent b alone changes: agent a's local code repeats
    add(model.replay_buffer, [0.1, -0.9, 0.5], [0.3, 0.4, 0.4], [0.0, 0.0])
    rewards = model.replay_buffer._get_samples(np.array([0, 1, 2])).rewards.cpu().numpy()
    if scope == "joint":
        assert exploration.num_codes == 3
        np.testing.assert_allclose(rewards, 1.0)
    elif scope == "state":
        assert exploration.num_codes == 2
        np.testing.assert_allclose(rewards[:, 0], [1 / np.sqrt(2), 1 / np.sqrt(2), 1.0], rtol=1e-6)
        np.testing.assert_allclose(rewards[:, 0], rewards[:, 1])  # one bonus shared by all agents
    else:
        assert [t.num_codes for t in exploration.tables] == [2, 3]
        # agent a's code (0.1, 0.3) was seen twice, at transitions 0 and 2: each agent gets its own bonus
        np.testing.assert_allclose(rewards[:, 0], [1 / np.sqrt(2), 1.0, 1 / np.sqrt(2)], rtol=1e-6)
        np.testing.assert_allclose(rewards[:, 1], 1.0)
    assert exploration.total_count == 3


def test_counts_equal_collected_transitions_n_envs_2():
    env = make_vec_env(lambda: make_joint_env(Rendezvous()), n_envs=2, seed=0)
    model = make_model(MACB(beta=0.8, k=64), env=env)
    model.learn(60)
    assert model.exploration.total_count == 60
    keys = model.replay_buffer.hash_keys[:30].reshape(-1)
    assert model.exploration.num_codes == len(np.unique(keys))


def test_exploration_none_uses_plain_buffer():
    model = make_model(None)
    assert type(model.replay_buffer) is MultiAgentReplayBuffer and model.exploration is None


def test_bonus_changes_training_targets():
    """Same seed, same data: the bonus alone moves the critics (it reaches the critic target)."""
    plain = make_model(None)  # (each model seeds the global RNG, used by the action noise, when built)
    plain.learn(40)
    macb = make_model(MACB(beta=5.0, k=16))
    macb.learn(40)
    # identical warm-up data (learning starts at 10), after which the bonus changes the learned policy
    np.testing.assert_array_equal(plain.replay_buffer.observations[:11], macb.replay_buffer.observations[:11])
    zeros = th.zeros(1, 3, device=plain.device)
    q_plain, q_macb = plain.critic(zeros, zeros), macb.critic(zeros, zeros)
    assert (q_macb - q_plain).abs().max() > 1e-3


def test_logged_statistics(tmp_path):
    import pandas as pd
    from stable_baselines3.common.logger import configure

    model = make_model(MACB(beta=0.8, k=64))
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(60, log_interval=1)  # Rendezvous episodes last 10 steps: 6 log dumps
    log = pd.read_csv(tmp_path / "progress.csv")
    assert {"exploration/num_codes", "exploration/count1_percent", "exploration/mean_bonus"} <= set(log.columns)
    assert log["exploration/num_codes"].iloc[-1] == model.exploration.num_codes
    assert log["exploration/count1_percent"].iloc[-1] == pytest.approx(100 * model.exploration.count1_fraction)
    bonus = log["exploration/mean_bonus"].dropna()
    assert len(bonus) > 0 and ((bonus > 0) & (bonus <= 0.8 + 1e-6)).all()


def test_seed_gives_same_matrix():
    a, b, c = make_model(MACB(k=16, seed=7)), make_model(MACB(k=16, seed=7)), make_model(MACB(k=16, seed=8))
    np.testing.assert_array_equal(a.exploration.hashes[0].matrix_t, b.exploration.hashes[0].matrix_t)
    assert not np.array_equal(a.exploration.hashes[0].matrix_t, c.exploration.hashes[0].matrix_t)
    d = make_model(MACB(k=16), seed=3)  # no MACB seed: the model's seed is used
    assert d.exploration.seed == 3


def test_save_load_continue(tmp_path):
    model = make_model(MACB(beta=0.8, k=64, scope="local"))
    model.learn(50)
    codes, total = model.exploration.num_codes, model.exploration.total_count
    matrix = model.exploration.hashes[1].matrix_t.copy()
    model.save(tmp_path / "m.zip")
    model.save_replay_buffer(tmp_path / "rb.pkl")

    loaded = MADDPG.load(tmp_path / "m.zip", env=make_joint_env(Rendezvous()))
    assert loaded.exploration.config == model.exploration.config
    assert (loaded.exploration.num_codes, loaded.exploration.total_count) == (codes, total)
    assert loaded.exploration.count1_fraction == pytest.approx(model.exploration.count1_fraction)
    np.testing.assert_array_equal(loaded.exploration.hashes[1].matrix_t, matrix)
    loaded.load_replay_buffer(tmp_path / "rb.pkl")
    assert loaded.replay_buffer.exploration is loaded.exploration
    loaded.learn(20, reset_num_timesteps=False)
    assert loaded.exploration.total_count == total + 20

    plain = make_model(None)
    with pytest.raises(ValueError, match="saved by a model using MACB"):
        plain.load_replay_buffer(tmp_path / "rb.pkl")

    # models saved before 0.8.0 hold the occupied entries only (keys_i, counts_i): they still load
    old_style = {name: t for name, t in model.exploration.state_dict().items() if name.startswith(("matrix_", "total_"))}
    for i, table in enumerate(model.exploration.tables):
        old_style[f"keys_{i}"] = th.from_numpy(table.state()["keys"].view(np.int64).copy())
        old_style[f"counts_{i}"] = th.from_numpy(table.state()["counts"].astype(np.int64))
    again = make_model(MACB(beta=0.8, k=64, scope="local"))
    again.exploration.load_state_dict(old_style)
    assert (again.exploration.num_codes, again.exploration.total_count) == (codes, total)


def test_memory_per_code_and_table_size():
    model = make_model(MACB(beta=0.8, k=512))
    model.learn(300)
    e = model.exploration
    assert e.total_count == 300
    assert 0 < e.num_codes <= 300
    assert e.nbytes / e.num_codes <= 32  # 12 bytes per slot, at most 3/4 and at least 3/8 of the slots used


# --- how the bonus enters the update: normalisation and schedules ----------------------------------------------------


@pytest.mark.parametrize("normalize", ["center", "zscore"])
def test_a_normalized_constant_bonus_trains_exactly_as_plain_maddpg(normalize):
    plain = make_model(None)
    offset = make_model(MACB(beta=0.8, counts=False, normalize=normalize))
    plain.learn(310)  # 300 updates after 10 steps of random actions
    offset.learn(310)
    assert plain._n_updates == offset._n_updates == 300
    for a, b in zip(plain.policy.state_dict().values(), offset.policy.state_dict().values()):
        assert th.allclose(a, b, atol=1e-6, rtol=0)
    assert offset.exploration.normalizer.mean.tolist() == [1.0]  # exactly: the constant's running mean is itself
    # the same constant without normalisation is a reward offset: its critics part from plain MADDPG's
    shifted = make_model(MACB(beta=0.8, counts=False))
    shifted.learn(310)
    assert not all(
        th.allclose(a, b, atol=1e-3) for a, b in zip(plain.policy.state_dict().values(), shifted.policy.state_dict().values())
    )


def test_normalizer_moving_averages_center_and_scale():
    from sb3_macb.exploration.normalize import BonusNormalizer

    rng = np.random.default_rng(0)
    norm = BonusNormalizer("zscore", rate=0.1, std_floor=0.01)
    mean, square = None, None
    for _ in range(300):
        batch = rng.normal([2.0, 0.5], [0.3, 0.001], size=(100, 2))  # column 1 hardly varies: the floor applies
        out = norm(batch)
        m, q = batch.mean(axis=0), (batch**2).mean(axis=0)
        mean, square = (m, q) if mean is None else (mean + 0.1 * (m - mean), square + 0.1 * (q - square))
        np.testing.assert_allclose(norm.mean, mean, rtol=1e-12)
        np.testing.assert_allclose(out[:, 0], (batch[:, 0] - mean[0]) / np.sqrt(square[0] - mean[0] ** 2), rtol=1e-9)
        np.testing.assert_allclose(out[:, 1], (batch[:, 1] - mean[1]) / 0.01, rtol=1e-9)
    assert norm.updates == 300 and norm.std[0] == pytest.approx(0.3, rel=0.05)
    frozen = norm.mean.copy()
    norm(rng.normal(size=(100, 2)), training=False)  # a diagnostic read changes nothing
    np.testing.assert_array_equal(norm.mean, frozen)
    centre = BonusNormalizer("center")
    assert np.all(centre(np.full((8, 1), 0.8)) == 0.0) and np.all(centre(np.full((8, 1), 0.8)) == 0.0)


def test_normalized_count_bonus_has_no_offset_and_survives_save_and_load(tmp_path):
    model = make_model(MACB(beta=0.8, k=16, normalize="center", normalize_rate=0.05))
    model.learn(200)
    norm = model.exploration.normalizer
    assert norm.updates == 190 and 0 < norm.mean[0] < 1  # repeated codes: 1 / sqrt(n) below 1 on average
    keys = model.replay_buffer.hash_keys[:150, 0, :1]
    bonus = model.exploration.bonus(keys, training=False)
    assert abs(float(bonus.mean())) < 0.2 and bonus.min() < 0 < bonus.max()  # both signs: centred, not shifted
    model.save(tmp_path / "m.zip")
    loaded = MADDPG.load(tmp_path / "m.zip", env=make_joint_env(Rendezvous()))
    assert loaded.exploration.config == model.exploration.config
    assert loaded.exploration.normalizer.updates == 190
    np.testing.assert_array_equal(loaded.exploration.normalizer.mean, norm.mean)
    np.testing.assert_array_equal(loaded.exploration.normalizer.mean_square, norm.mean_square)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(normalize="mean"), "normalize must be one of"),
        (dict(normalize="zscore", normalize_rate=0.0), "normalize_rate"),
        (dict(normalize="zscore", std_floor=-1.0), "std_floor"),
        (dict(normalize_rate="fast"), "normalize_rate must be a number in"),  # named even without normalize
        (dict(beta=lambda progress: progress - 0.5), "a beta schedule must give a finite number >= 0"),
    ],
)
def test_bad_normalisation_and_schedule_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        MACB(**kwargs)


def test_a_scheduled_beta_follows_the_progress_of_training():
    from rl_zoo3.utils import linear_schedule

    model = make_model(MACB(beta=linear_schedule(0.8), counts=False), learning_starts=10)
    seen = []
    original = model.exploration.bonus

    def record(keys, training=True):
        bonus = original(keys, training)
        seen.append(float(bonus[0, 0]))
        return bonus

    model.exploration.bonus = record
    model.learn(110)
    # progress remaining 1 - t / 110 at update t (steps 10..109): beta 0.8 * that
    assert seen[0] == pytest.approx(0.8 * (1 - 11 / 110), abs=1e-6)
    assert seen[-1] == pytest.approx(0.8 * (1 - 110 / 110), abs=1e-6)
    assert all(a > b for a, b in zip(seen, seen[1:]))


# --- the count-min sketch ------------------------------------------------------------------------------------------


def test_count_min_sketch_never_undercounts_and_is_exact_when_wide():
    from sb3_macb.exploration.count_min import CountMinSketch

    rng = np.random.default_rng(0)
    narrow, wide, exact, reference = CountMinSketch(3, 50), CountMinSketch(4, 1 << 20), CountTable(), Counter()
    for _ in range(400):
        keys = rng.integers(1, 2**63, size=rng.integers(1, 4)).astype(np.uint64)
        keys = np.concatenate([keys, keys[:1], rng.choice(np.fromiter(reference, np.uint64), 1)]) if reference else keys
        for table in (narrow, wide, exact):
            table.add(keys)
        reference.update(keys.tolist())
    probe = np.fromiter(reference, dtype=np.uint64)
    truth = np.array([reference[int(k)] for k in probe])
    assert np.all(narrow.lookup(probe) >= truth) and np.any(narrow.lookup(probe) > truth)  # collisions: over, never under
    np.testing.assert_array_equal(wide.lookup(probe), truth)
    assert (wide.num_codes, wide.num_count1, wide.total_count) == (exact.num_codes, exact.num_count1, exact.total_count)
    assert narrow.total_count == exact.total_count and narrow.nbytes == 4 * sum(narrow.widths.tolist())
    assert list(narrow.widths) == [53, 59, 61]  # the next primes at or above the width, all different
    assert wide.lookup(np.array([12345], dtype=np.uint64))[0] == 0


def test_macb_with_a_sketch_gives_at_most_the_exact_bonus_and_saves(tmp_path):
    exact = make_model(MACB(beta=0.8, k=16, decimals=None), learning_starts=10_000)
    sketch = make_model(
        MACB(beta=0.8, k=16, decimals=None, table="sketch", sketch_depth=2, sketch_width=7), learning_starts=10_000
    )
    rng = np.random.default_rng(1)
    for _ in range(200):
        t = (rng.uniform(-1, 1, 3), rng.uniform(-1, 1, 3), [0.0, 0.0])
        add(exact.replay_buffer, *t)
        add(sketch.replay_buffer, *t)
    indices = np.arange(200)
    ours = sketch.replay_buffer._get_samples(indices).rewards.cpu().numpy()
    theirs = exact.replay_buffer._get_samples(indices).rewards.cpu().numpy()
    assert np.all(ours <= theirs + 1e-7) and np.any(ours < theirs - 1e-3)  # narrow: some codes overcounted
    assert sketch.exploration.nbytes == 4 * (7 + 11)
    sketch.save(tmp_path / "m.zip")
    loaded = MADDPG.load(tmp_path / "m.zip", env=make_joint_env(Rendezvous()))
    assert loaded.exploration.config == sketch.exploration.config
    np.testing.assert_array_equal(loaded.exploration.tables[0].counts, sketch.exploration.tables[0].counts)
    assert (loaded.exploration.num_codes, loaded.exploration.total_count) == (sketch.exploration.num_codes, 200)
    with pytest.raises(ValueError, match="sketch_depth must be an integer >= 1"):
        MACB(table="sketch", sketch_depth=0)
    with pytest.raises(ValueError, match="table must be one of"):
        MACB(table="bloom")


def test_a_saturated_sketch_is_measured_logged_and_warned_about():
    from stable_baselines3.common.logger import configure

    from sb3_macb.exploration.count_min import CountMinSketch

    sketch = CountMinSketch(2, 10)  # rows of 11 and 13 counters
    assert sketch.collision_rate == 0.0
    sketch.add(np.array([0, 1, 2], dtype=np.uint64))  # cells 0, 1, 2 of each row
    assert sketch.collision_rate == pytest.approx((3 / 11) * (3 / 13))
    sketch.add(np.arange(3, 1000, dtype=np.uint64))
    assert sketch.collision_rate == 1.0 and sketch.lookup(np.array([5000], dtype=np.uint64))[0] > 0
    assert MACB(beta=0.8, k=16).sketch_collision_rate is None
    for width, saturated in ((7, True), (1_000_003, False)):
        model = make_model(MACB(beta=0.8, k=16, decimals=None, table="sketch", sketch_depth=2, sketch_width=width))
        model.set_logger(configure(None, []))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model.learn(200)
        rate = model.exploration.sketch_collision_rate
        assert (rate > 0.9) if saturated else (rate < 1e-3)
        model.logger.dump = lambda step=0: None  # (keep what dump_logs records)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            model.dump_logs()
        assert model.logger.name_to_value["exploration/sketch_collision_rate"] == rate
        assert any("sketch is saturated" in str(w.message) for w in caught) == saturated


# --- RND --------------------------------------------------------------------------------------------------------------


def test_rnd_bonus_falls_on_trained_states_stays_high_on_new_ones_and_saves(tmp_path):
    from sb3_macb import RND

    model = make_model(RND(beta=0.5, normalize=None, learning_rate=3e-3))
    model.learn(300)
    rnd, obs = model.exploration, model.replay_buffer.observations[:290, 0]
    seen, new = rnd.errors(obs).mean(), rnd.errors(obs * 5 + 3).mean()
    assert new > 20 * seen  # trained on the buffer's states: small errors there, large ones far from them
    keys = np.zeros((len(obs), 1), dtype=np.uint64)
    np.testing.assert_allclose(rnd.bonus(keys, training=False, observations=obs), 0.5 * rnd.errors(obs), rtol=1e-5)
    model.save(tmp_path / "m.zip")
    loaded = MADDPG.load(tmp_path / "m.zip", env=make_joint_env(Rendezvous()))
    np.testing.assert_array_equal(loaded.exploration.errors(obs), rnd.errors(obs))
    assert loaded.exploration.config == rnd.config and loaded.exploration.total_count == 300
    loaded.learn(20, reset_num_timesteps=False)
    assert loaded.exploration.total_count == 320
    local = make_model({"estimator": "rnd", "scope": "local"})  # from a dict, as YAML gives it
    assert isinstance(local.exploration, RND) and local.exploration.n_tables == 2
    with pytest.raises(ValueError, match="exploration estimator must be one of"):
        make_model({"estimator": "icm"})
    with pytest.raises(ValueError, match=r"Unknown RND option\(s\) \['k'\]"):
        make_model({"estimator": "rnd", "k": 16})
    with pytest.raises(ValueError, match="RND: beta must be"):
        RND(beta=-1)

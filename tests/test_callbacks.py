import os
import re

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.callbacks import BaseCallback, EvalCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.noise import NormalActionNoise

from sb3_macb import MACB, MADDPG
from sb3_macb.callbacks import MultiAgentEvalCallback, StopTrainingOnNoSuccessImprovement, StopTrainingOnSuccessRate

COMM = "sb3_macb/CommunicativeNavigation-v0"
NAV = "sb3_macb/TwoAgentNavigation-v0"


def make_model(env_id=COMM, env_kwargs=None, **kwargs):
    env = gym.make(env_id, **(env_kwargs or {}))
    dim = env.action_space.shape[0]
    return MADDPG(
        "MlpPolicy",
        env,
        learning_starts=40,
        batch_size=16,
        policy_kwargs=dict(net_arch=[32, 32]),
        action_noise=NormalActionNoise(np.zeros(dim), 0.1 * np.ones(dim)),
        seed=0,
        **kwargs,
    )


def test_early_stop_fires_on_trivially_easy_task():
    easy = dict(success_radius=100.0)
    model = make_model(env_kwargs=easy)
    callback = MultiAgentEvalCallback(COMM, env_kwargs=easy, n_eval_episodes=4, eval_freq=20, stop_success_rate=0.9,
                                      min_evals=2, seed=1, verbose=0)
    model.learn(2_000, callback=callback)
    assert callback.last_success_rate == 1.0
    assert model.num_timesteps == 40  # two evaluations, then stop


def test_early_stop_does_not_fire_on_the_real_task():
    model = make_model()
    callback = MultiAgentEvalCallback(COMM, n_eval_episodes=4, eval_freq=20, stop_success_rate=0.9, seed=1, verbose=0)
    model.learn(200, callback=callback)
    assert model.num_timesteps == 200
    assert len(callback.evaluations_timesteps) == 10
    assert max(np.mean(s) for s in callback.evaluations_successes) < 0.9


def test_no_improvement_stop():
    easy = dict(success_radius=100.0)
    model = make_model(env_kwargs=easy)
    callback = MultiAgentEvalCallback(COMM, env_kwargs=easy, n_eval_episodes=2, eval_freq=20, stop_patience=3,
                                      min_evals=0, seed=1, verbose=0)
    model.learn(2_000, callback=callback)
    # success is 1.0 from the first evaluation: three more without improvement, then stop
    assert len(callback.evaluations_timesteps) == 4 and model.num_timesteps == 80


def test_with_sb3_eval_callback():
    easy = dict(success_radius=100.0)
    model = make_model(env_kwargs=easy)
    eval_env = make_vec_env(COMM, n_envs=2, env_kwargs=easy, seed=0)
    callback = EvalCallback(eval_env, n_eval_episodes=2, eval_freq=20, verbose=0,
                            callback_after_eval=StopTrainingOnSuccessRate(0.5))
    model.learn(1_000, callback=callback)
    assert model.num_timesteps == 20


def test_stop_callbacks_need_an_eval_callback():
    model = make_model()
    with pytest.raises(TypeError, match="callback_after_eval of an EvalCallback"):
        model.learn(30, callback=StopTrainingOnSuccessRate(0.5))
    with pytest.raises(ValueError, match="threshold"):
        StopTrainingOnSuccessRate(1.5)
    with pytest.raises(ValueError, match="max_no_improvement_evals"):
        StopTrainingOnNoSuccessImprovement(0)


def test_evaluation_file_and_best_model(tmp_path):
    model = make_model(NAV, exploration=MACB(k=32))
    callback = MultiAgentEvalCallback(NAV, n_eval_episodes=3, eval_freq=20, log_path=str(tmp_path),
                                      best_model_save_path=str(tmp_path), save_freq=4, seed=2, verbose=0)
    model.learn(200, callback=callback)
    data = np.load(tmp_path / "evaluations.npz")
    n = 10
    assert set(data.files) >= {"timesteps", "results", "ep_lengths", "successes", "episodes", "agent_returns",
                               "collisions", "num_codes", "count1_fraction", "training_collisions"}
    np.testing.assert_array_equal(data["timesteps"], np.arange(20, 201, 20))
    np.testing.assert_array_equal(data["episodes"], np.arange(1, n + 1))
    assert data["results"].shape == (n, 3) and data["successes"].shape == (n, 3)
    assert data["agent_returns"].shape == (n, 3, 2)
    # each agent's return is the shared reward summed over the episode, equal to the team return here
    np.testing.assert_allclose(data["agent_returns"][..., 0], data["results"], rtol=1e-5)
    assert data["collisions"].shape == (n, 3) and (data["collisions"] >= 0).all()
    # evaluations run in the callback, before SB3 stores that step's transition: one transition behind at the end
    assert model.exploration.num_codes - 1 <= data["num_codes"][-1] <= model.exploration.num_codes
    assert (np.diff(data["num_codes"]) >= 0).all() and data["num_codes"][0] > 0
    assert 0 < data["count1_fraction"][-1] <= 1

    # the best model is the first evaluation with the highest (success rate, mean return)
    scores = [(np.mean(s), np.mean(r)) for s, r in zip(data["successes"], data["results"])]
    best = max(range(n), key=lambda i: (scores[i], -i))
    saved = MADDPG.load(tmp_path / "best_model.zip")
    assert saved.num_timesteps == data["timesteps"][best]


def test_evaluation_file_written_less_often_as_it_grows(tmp_path, monkeypatch):
    """Every save_freq evaluations at first, then every tenth of those held; the file ends complete."""
    from sb3_macb.common import evaluations

    held = []
    write = evaluations.save
    monkeypatch.setattr(evaluations, "save", lambda path, record: (held.append(len(record["timesteps"])), write(path, record)))
    model = make_model(NAV)
    callback = MultiAgentEvalCallback(NAV, n_eval_episodes=1, eval_freq=1, log_path=str(tmp_path), save_freq=2, seed=2,
                                      verbose=0)
    model.learn(120, callback=callback)
    assert held[:10] == list(range(2, 21, 2))  # (20 // 10 = 2: the interval starts growing past 20 evaluations)
    gaps = np.diff(held[:-1])
    assert (gaps >= np.maximum(2, np.array(held[1:-1]) // 10)).all() and gaps[-1] >= 10
    assert len(held) < 120 // 2  # a write every save_freq evaluations would be 60
    assert held[-1] == 120 and len(np.load(tmp_path / "evaluations.npz")["timesteps"]) == 120


@pytest.mark.parametrize("monitored", [True, False])
def test_evaluation_runs_the_episodes_evaluate_policy_runs(monitored):
    """Episode returns and lengths as SB3's evaluate_policy gives them, with episodes of different lengths and more
    episodes than envs (env i runs (n + i) // n_envs of them)."""
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor

    def env():
        vec = DummyVecEnv([lambda: gym.make(NAV, max_episode_steps=7), lambda: gym.make(NAV, max_episode_steps=13)])
        vec.seed(7)
        return VecMonitor(vec) if monitored else vec

    model = make_model(NAV)
    callback = MultiAgentEvalCallback(env(), n_eval_episodes=5, eval_freq=1, verbose=0, warn=False, dump_logs=False)
    model.learn(1, callback=callback)  # one evaluation
    expected_returns, expected_lengths = evaluate_policy(model, env(), n_eval_episodes=5, return_episode_rewards=True,
                                                         warn=False)
    returns, lengths = callback.evaluations_results[0], callback.evaluations_length[0]
    assert len(returns) == 5 and len(set(lengths)) > 1
    # (evaluate_policy lists episodes as they end, the callback env by env)
    assert sorted(zip(returns, lengths)) == sorted(zip(np.float64(expected_returns), expected_lengths))


def test_logger_files_get_every_evaluation_and_the_console_every_log_freq(tmp_path, capsys):
    import json

    from stable_baselines3.common.logger import configure

    model = make_model(NAV)
    model.set_logger(configure(str(tmp_path), ["stdout", "json"]))
    callback = MultiAgentEvalCallback(NAV, n_eval_episodes=2, eval_freq=10, log_freq=4, seed=2, verbose=0)
    model.learn(120, callback=callback, log_interval=None)  # 12 evaluations; no dumps of SB3's own
    rows = [json.loads(line) for line in (tmp_path / "progress.json").read_text().splitlines()]
    evaluated = [row for row in rows if "eval/success_rate" in row]
    assert len(evaluated) == 12
    assert [row["eval/mean_reward"] for row in evaluated] == pytest.approx(
        [float(np.mean(r)) for r in callback.evaluations_results])
    # the console table: evaluations 4, 8 and 12
    assert len(re.findall(r"\|\s+success_rate\s", capsys.readouterr().out)) == 3


def test_training_collisions_counted():
    class CountCollisions(BaseCallback):
        total = 0

        def _on_step(self):
            for info in self.locals["infos"]:
                self.total += info["agent_infos"]["agent_0"]["collisions"]
            return True

    from stable_baselines3.common.callbacks import CallbackList

    model = make_model(NAV, env_kwargs=dict(reward_radius=0.125))
    counter = CountCollisions()
    callback = MultiAgentEvalCallback(NAV, n_eval_episodes=2, eval_freq=100, seed=0, verbose=0)
    model.learn(400, callback=CallbackList([counter, callback]))
    assert callback.training_collisions == counter.total
    assert callback.evaluations_training_collisions[-1] == counter.total


def test_a_full_disk_while_writing_the_monitor_file_is_one_error_naming_it(tmp_path, monkeypatch):
    import errno

    import sb3_macb.callbacks as callbacks_module
    from sb3_macb.common.atomic import AtomicWriteError

    class FullDisk:
        def __init__(self, path, mode):
            self.file = open(path, mode)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.file.close()

        def write(self, text):
            self.file.write(text[: len(text) // 2])  # part of the line reaches the file, then the disk is full
            self.file.flush()
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    callback = MultiAgentEvalCallback(NAV, n_eval_episodes=1, eval_freq=1000, log_path=str(tmp_path), monitor=True,
                                      verbose=0)
    model = make_model(NAV)
    model.learn(40, callback=callback)  # two episodes written
    written = (tmp_path / "monitor.csv").read_text()
    assert written.count("\n") == 4
    monkeypatch.setattr(callbacks_module, "open", FullDisk, raising=False)
    with pytest.raises(AtomicWriteError, match=r"cannot write .*monitor.csv: No space left on device"):
        model.learn(20, callback=callback, reset_num_timesteps=False)
    assert (tmp_path / "monitor.csv").read_text() == written  # no part of a line left behind


def test_moving_average_edge_rules():
    from sb3_macb.common.evaluations import moving_average

    values = np.array([1.0, 0.0, 2.0, 4.0, 3.0])
    full = [1.0, 2.0, 3.0]  # means of [1, 0, 2], [0, 2, 4], [2, 4, 3]
    assert np.allclose(moving_average(values, 3, head="drop"), full)
    assert np.allclose(moving_average(values, 3), [1.0, 0.5, *full])  # "partial": the first points average what is there
    nan = moving_average(values, 3, head="nan")
    assert np.isnan(nan[:2]).all() and np.allclose(nan[2:], full)
    assert np.array_equal(moving_average(values, 1), values)
    assert len(moving_average(values[:2], 3, head="drop")) == 0 and np.allclose(moving_average(values[:2], 3), [1.0, 0.5])
    with pytest.raises(ValueError, match="head"):
        moving_average(values, 3, head="valid")
    with pytest.raises(ValueError, match="window"):
        moving_average(values, 0)

"""Checkpoints and resume, atomic files, safe hyperparameter strings, the vectorized task env."""

import json
import os
import pickle
import signal
import subprocess
import sys
import time
import zipfile

import numpy as np
import pytest
import torch as th

import sb3_macb
from sb3_macb import MADDPG
from sb3_macb.envs.vec_tasks import make_task_vec_env
from sb3_macb.zoo.experiment import (
    Experiment,
    ExperimentConfig,
    ExperimentError,
    RunConfig,
    load_checkpoint,
    load_experiment,
    load_hyperparams,
    safe_eval,
)

COMM = "sb3_macb/CommunicativeNavigation-v0"
NAV = "sb3_macb/TwoAgentNavigation-v0"

# A script that runs a small two-run pack with checkpoints; argv: root tag steps [resume]
PACK_SCRIPT = f"""
import sys, torch as th
th.set_num_threads(1)
from sb3_macb.zoo.experiment import Experiment, ExperimentConfig, RunConfig, load_hyperparams
root, tag, steps = sys.argv[1], sys.argv[2], int(sys.argv[3])
hp = [load_hyperparams("{COMM}", variants=v) for v in (["fast"], ["maddpg", "fast"])]
for h in hp:  # (a buffer of 300: it wraps before and after the checkpoint a kill resumes from)
    h.update(policy_kwargs="dict(net_arch=[32, 32])", batch_size=16, buffer_size=300)
hp[0]["exploration"] = dict(beta="lin_0.8", k=16, normalize="zscore", table="sketch", sketch_width=101)  # all state
hp[1]["exploration"] = dict(estimator="rnd", beta=0.3)  # networks, Adam state and statistics
for h in hp:
    h["intrinsic_critic"] = True  # (and both runs learn their bonus with intrinsic critics)
runs = [RunConfig(seed=s, folder=f"{{root}}/{{tag}}/run_{{s}}", hyperparams=h) for s, h in zip((0, 1), hp)]
config = ExperimentConfig("{COMM}", runs, n_timesteps=steps)
Experiment(config, f"{{root}}/{{tag}}", checkpoint_freq=100, verbose=0, monitor=True).run(resume=len(sys.argv) > 4)
"""


def run_pack(tmp_path, tag, steps, resume=False, kill_at_checkpoint=None):
    script = tmp_path / "pack.py"
    script.write_text(PACK_SCRIPT)
    args = [sys.executable, str(script), str(tmp_path), tag, str(steps)] + (["resume"] if resume else [])
    if kill_at_checkpoint is None:
        subprocess.run(args, check=True, timeout=300)
        return
    process = subprocess.Popen(args)
    latest = tmp_path / tag / "checkpoint" / "LATEST"
    deadline = time.time() + 240
    while time.time() < deadline and process.poll() is None:
        if latest.exists() and latest.read_text() == f"step_{kill_at_checkpoint}":
            break
        time.sleep(0.05)
    process.send_signal(signal.SIGKILL)
    process.wait()


@pytest.mark.slow
def test_a_run_killed_and_resumed_gives_the_same_evaluations(tmp_path):
    run_pack(tmp_path, "whole", 1200)
    run_pack(tmp_path, "cut", 1200, kill_at_checkpoint=500)
    assert not (tmp_path / "cut" / "run_0" / "run.json").exists()
    with open(tmp_path / "cut" / "run_0" / "monitor.csv", "a") as file:  # as if rows came after the checkpoint
        file.write("-20.0,20,1.0\n-20.0,2")
    run_pack(tmp_path, "cut", 1200, resume=True)
    for run in ("run_0", "run_1"):
        whole, cut = np.load(tmp_path / "whole" / run / "evaluations.npz"), np.load(tmp_path / "cut" / run / "evaluations.npz")
        assert sorted(whole.files) == sorted(cut.files) and "final_successes" in whole.files
        assert len(whole["timesteps"]) == 60
        for name in whole.files:
            assert np.array_equal(whole[name], cut[name]), name
        assert json.loads((tmp_path / "cut" / run / "run.json").read_text())["complete"]
        # the training episodes in SB3's Monitor format: the same rows (wall times aside), none written twice
        from stable_baselines3.common.monitor import load_results

        whole_eps, cut_eps = load_results(str(tmp_path / "whole" / run)), load_results(str(tmp_path / "cut" / run))
        assert len(whole_eps) == 60 and list(whole_eps["l"]) == [20] * 60
        assert np.array_equal(whole_eps["r"].to_numpy(), cut_eps["r"].to_numpy())
    assert not (tmp_path / "cut" / "checkpoint").exists()  # deleted when the experiment ends


def small_config(tmp_path, steps=200, seed=0):
    hp = load_hyperparams(COMM, variants=["maddpg", "fast"])
    hp.update(policy_kwargs="dict(net_arch=[16])", batch_size=8)
    return ExperimentConfig(COMM, [RunConfig(seed=seed, folder=str(tmp_path / "run"), hyperparams=hp)], n_timesteps=steps)


def test_resume_refuses_what_it_cannot_continue(tmp_path, monkeypatch):
    folder = str(tmp_path / "exp")
    with pytest.raises(ExperimentError, match="experiment.json does not exist"):
        Experiment(small_config(tmp_path), folder).run(resume=True)
    # killed before its first checkpoint: no silent fresh start
    os.makedirs(folder)
    Experiment(small_config(tmp_path), folder)._write_experiment_file(done=False)
    with pytest.raises(ExperimentError, match="holds no complete checkpoint"):
        Experiment(small_config(tmp_path), folder).run(resume=True)
    with pytest.raises(ExperimentError, match="already holds an experiment"):
        Experiment(small_config(tmp_path), folder).run()

    folder = str(tmp_path / "exp2")
    Experiment(small_config(tmp_path), folder, checkpoint_freq=50, keep_checkpoint=True, verbose=0).run()
    os.remove(os.path.join(folder, "experiment.json"))
    Experiment(small_config(tmp_path), folder)._write_experiment_file(done=False)  # as if stopped after a checkpoint
    with pytest.raises(ExperimentError, match=r"differ from those in .*experiment.json: n_timesteps: 200 -> 400\. Resume"):
        Experiment(small_config(tmp_path, steps=400), folder).run(resume=True)
    with pytest.raises(ExperimentError, match=r"runs\[0\]\.seed: 0 -> 1"):
        Experiment(small_config(tmp_path, seed=1), folder).run(resume=True)
    checkpoint = os.path.join(folder, "checkpoint", "step_150")
    state = os.path.join(checkpoint, "state.pkl")
    with open(state, "rb") as file:
        data = pickle.load(file)
    with open(state, "wb") as file:
        file.write(b"garbage")
    with pytest.raises(ExperimentError, match="state.pkl is missing or damaged"):
        Experiment(small_config(tmp_path), folder).run(resume=True)
    with open(state, "wb") as file:
        pickle.dump(data, file)
    with open(os.path.join(checkpoint, "model.zip"), "wb") as file:
        file.write(b"PK")
    with pytest.raises(ExperimentError, match="model.zip is missing or damaged"):
        Experiment(small_config(tmp_path), folder).run(resume=True)
    monkeypatch.setattr(sb3_macb, "__version__", "9.9.9")
    with pytest.raises(ExperimentError, match="written by sb3_macb"):
        Experiment(small_config(tmp_path), folder).run(resume=True)
    # the diagnosis may read another version's checkpoint: past the version check, to the damaged model
    with pytest.raises(ExperimentError, match="model.zip is missing or damaged"):
        load_checkpoint(checkpoint, allow_other_version=True)


@pytest.mark.slow
def test_a_mixed_pack_through_the_runner_equals_its_solo_runs_past_the_buffer(tmp_path):
    def hyperparams(variants):
        hp = load_hyperparams(COMM, variants=variants)
        hp.update(policy_kwargs="dict(net_arch=[16])", batch_size=8, buffer_size=100)
        return hp

    plan = [(0, ["maddpg", "fast"]), (1, ["fast"]), (2, ["macb_constant", "fast"])]  # seeds and variants mixed
    runs = [
        RunConfig(seed, str(tmp_path / "pack" / f"run_{seed}"), variants, hyperparams(variants)) for seed, variants in plan
    ]
    Experiment(ExperimentConfig(COMM, runs, n_timesteps=300), str(tmp_path / "pack"), checkpoint_freq=150, verbose=0).run()
    for seed, variants in plan:
        alone = RunConfig(seed, str(tmp_path / f"alone_{seed}"), variants, hyperparams(variants))
        Experiment(ExperimentConfig(COMM, [alone], n_timesteps=300), str(tmp_path / f"alone_{seed}"), verbose=0).run()
        a = np.load(tmp_path / "pack" / f"run_{seed}" / "evaluations.npz")
        b = np.load(tmp_path / f"alone_{seed}" / "evaluations.npz")
        assert all(np.array_equal(a[name], b[name]) for name in b.files), seed
        info = json.loads((tmp_path / "pack" / f"run_{seed}" / "run.json").read_text())
        assert info["buffer_size_per_run"] == 100 and info["pack_size"] == 3


def test_keep_models_keeps_every_checkpoints_model(tmp_path):
    folder = str(tmp_path / "exp")
    experiment = Experiment(small_config(tmp_path), folder, checkpoint_freq=50, keep_models=True, verbose=0)
    experiment.run()
    models = sorted(os.listdir(os.path.join(folder, "models")), key=lambda name: int(name[5:-4]))
    assert models == ["step_50.zip", "step_100.zip", "step_150.zip"]  # the checkpoints (none at the end)
    assert not os.path.exists(os.path.join(folder, "checkpoint"))  # the checkpoint itself goes as before
    for name in models:
        model = MADDPG.load(os.path.join(folder, "models", name))
        assert model.num_timesteps == int(name[5:-4])  # one run: steps per run = steps
    final = MADDPG.load(str(tmp_path / "run" / "model.zip"))
    kept = MADDPG.load(os.path.join(folder, "models", "step_150.zip"))
    assert not th.equal(next(iter(final.actor.parameters())), next(iter(kept.actor.parameters())))


def test_resume_from_the_folder_alone_and_a_finished_experiment(tmp_path):
    folder = str(tmp_path / "exp")
    Experiment(small_config(tmp_path), folder, verbose=0).run()
    assert Experiment(small_config(tmp_path), folder).status() == "done"
    experiment = load_experiment(folder, verbose=0)
    assert experiment.config.comparable() == small_config(tmp_path).comparable()
    assert experiment.run(resume=True) == [str(tmp_path / "run")]  # nothing left to do


def test_run_or_resume_starts_new_and_stopped_experiments_and_continues_checkpointed_ones(tmp_path, monkeypatch):
    from sb3_macb.zoo.experiment import run_or_resume

    calls = []
    real_run = Experiment.run
    monkeypatch.setattr(Experiment, "run", lambda self, resume=False: (calls.append(resume), real_run(self, resume))[1])
    folder = str(tmp_path / "exp")
    os.makedirs(os.path.join(folder, "checkpoint"))
    Experiment(small_config(tmp_path), folder)._write_experiment_file(done=False)  # killed before its first checkpoint
    run_or_resume(Experiment(small_config(tmp_path), folder, checkpoint_freq=50, keep_checkpoint=True, verbose=0))
    assert calls == [False] and Experiment(small_config(tmp_path), folder).status() == "done"
    whole = np.load(tmp_path / "run" / "evaluations.npz")
    os.remove(os.path.join(folder, "experiment.json"))
    Experiment(small_config(tmp_path), folder)._write_experiment_file(done=False)  # as if stopped after step 150
    run_or_resume(Experiment(small_config(tmp_path), folder, checkpoint_freq=50, verbose=0))
    assert calls == [False, True]
    resumed = np.load(tmp_path / "run" / "evaluations.npz")
    assert all(np.array_equal(whole[key], resumed[key]) for key in whole.files)
    run_or_resume(Experiment(small_config(tmp_path), folder, verbose=0))  # finished: returns at once
    assert calls == [False, True, True]
    with pytest.raises(ExperimentError, match="n_timesteps: 200 -> 400"):
        run_or_resume(Experiment(small_config(tmp_path, steps=400), folder, verbose=0))


def test_packs_refuse_runs_that_differ_in_more_than_exploration_and_noise(tmp_path):
    a = load_hyperparams(COMM, variants=["fast"])
    b = load_hyperparams(COMM, variants=["maddpg"])  # 400-300 networks
    runs = [RunConfig(0, str(tmp_path / "a"), hyperparams=a), RunConfig(1, str(tmp_path / "b"), hyperparams=b)]
    with pytest.raises(ExperimentError, match="differs in \\['policy_kwargs'\\]"):
        ExperimentConfig(COMM, runs, n_timesteps=100)
    # runs share the pack's env: YAML env kwargs that differ are refused, not merged into both
    plain = load_hyperparams(COMM, variants=["maddpg", "fast"])
    refcode = load_hyperparams(COMM, variants=["maddpg", "refcode", "fast"])
    runs = [RunConfig(0, str(tmp_path / "a"), hyperparams=plain), RunConfig(0, str(tmp_path / "b"), hyperparams=refcode)]
    with pytest.raises(ExperimentError, match="share one env, but their env_kwargs differ"):
        ExperimentConfig(COMM, runs, n_timesteps=100)


def test_the_refcode_variant_ends_episodes_on_success_and_stores_time_limits_as_terminal(tmp_path):
    from sb3_macb.zoo.experiment import model_kwargs

    hyperparams = load_hyperparams(COMM, variants=["maddpg", "refcode", "fast"])
    env_kwargs = hyperparams.pop("env_kwargs")
    assert env_kwargs == {"terminate_on_success": True}
    kwargs = model_kwargs({**hyperparams, "learning_starts": 2000})
    model = MADDPG("MlpPolicy", make_task_vec_env(COMM, 1, env_kwargs), seed=0, **kwargs)
    model.learn(2000)  # random actions throughout (learning starts at 2,000): some listeners reach the goal
    buffer = model.replay_buffer
    ends = np.flatnonzero(buffer.dones[:2000, 0])
    lengths = np.diff(np.concatenate([[-1], ends]))
    assert buffer.timeouts[:2000].sum() == 0  # time limits are not marked as such: they are terminal
    assert lengths.max() == 20 and lengths.min() < 20  # time-limit ends, and episodes ended early by a success
    plain_kwargs = model_kwargs({**load_hyperparams(COMM, variants=["maddpg", "fast"]), "learning_starts": 400})
    plain = MADDPG("MlpPolicy", make_task_vec_env(COMM, 1), seed=0, **plain_kwargs)
    plain.learn(400)
    assert plain.replay_buffer.timeouts[:400, 0].sum() == 20  # the default: every episode runs 20 steps, bootstrapped


def test_the_timeout_terminal_variant_stores_the_20_step_cut_as_terminal_and_never_ends_on_success():
    from sb3_macb.zoo.experiment import model_kwargs

    hyperparams = load_hyperparams(COMM, variants=["maddpg", "timeout_terminal", "fast"])
    assert "env_kwargs" not in hyperparams  # the plain env: episodes are never ended on success
    kwargs = model_kwargs({**hyperparams, "learning_starts": 2000})
    model = MADDPG("MlpPolicy", make_task_vec_env(COMM, 1), seed=0, **kwargs)
    model.learn(2000)
    buffer = model.replay_buffer
    assert buffer.timeouts[:2000].sum() == 0  # not marked as time limits: the target does not bootstrap there
    assert np.array_equal(np.flatnonzero(buffer.dones[:2000, 0]), np.arange(19, 2000, 20))  # every 20th step, only


SAVE_LOOP = f"""
import sys
from sb3_macb import MADDPG
from sb3_macb.envs.vec_tasks import make_task_vec_env
model = MADDPG("MlpPolicy", make_task_vec_env("{COMM}", 1), policy_kwargs=dict(net_arch=[256, 256]), seed=0)
print("ready", flush=True)
while True:
    model.save(sys.argv[1])
    model.save_replay_buffer(sys.argv[2])
"""


@pytest.mark.slow
def test_a_save_killed_at_any_moment_leaves_the_previous_file(tmp_path):
    script = tmp_path / "loop.py"
    script.write_text(SAVE_LOOP)
    model_path, buffer_path = tmp_path / "model.zip", tmp_path / "buffer.pkl"
    rng = np.random.default_rng(0)
    for _ in range(4):
        process = subprocess.Popen([sys.executable, str(script), str(model_path), str(buffer_path)], stdout=subprocess.PIPE)
        assert process.stdout.readline().strip() == b"ready"
        while not buffer_path.exists():
            time.sleep(0.01)
        time.sleep(float(rng.uniform(0.0, 0.5)))
        process.send_signal(signal.SIGKILL)
        process.wait()
        with zipfile.ZipFile(model_path) as archive:
            assert archive.testzip() is None
        MADDPG.load(model_path)
    leftovers = [name for name in os.listdir(tmp_path) if name.endswith(".tmp")]
    assert len(leftovers) <= 8  # a killed write leaves its temporary file, never a damaged target


def test_hyperparameter_strings_are_parsed_without_running_code(tmp_path):
    import torch.nn as nn

    assert safe_eval("dict(net_arch=[400, 300], activation_fn=nn.Tanh)", "x") == {
        "net_arch": [400, 300],
        "activation_fn": nn.Tanh,
    }
    assert safe_eval("{'a': (1, -2.5), 'b': None}", "x") == {"a": (1, -2.5), "b": None}
    marker = tmp_path / "pwned"
    for text in (f"__import__('os').system('touch {marker}')", f"dict(a=open('{marker}', 'w'))", "().__class__"):
        with pytest.raises(ExperimentError, match="hyperparameter 'policy_kwargs'.*not allowed"):
            safe_eval(text, "hyperparameter 'policy_kwargs'")
    assert not marker.exists()
    with pytest.raises(ExperimentError, match="cannot parse"):
        safe_eval("dict(", "x")


def test_train_command_checkpoints_and_resumes(tmp_path, capsys):
    from sb3_macb.cli import main

    common = ["--env", COMM, "-n", "300", "--seed", "2", "-f", str(tmp_path),
              "-c", load_hyperparams.__globals__["DEFAULT_CONFIG"], "--variant", "maddpg,fast",
              "-params", "batch_size:16", "policy_kwargs:dict(net_arch=[16])"]  # fmt: skip
    assert main(["train", *common, "--checkpoint-freq", "100", "--verbose", "0"]) == 0
    folder = tmp_path / "maddpg" / "sb3_macb-CommunicativeNavigation-v0_1"
    assert json.loads((folder / "run.json").read_text())["complete"]
    assert len(np.load(folder / "evaluations.npz")["timesteps"]) == 15
    assert main(["train", *common, f"--resume={folder}"]) == 0  # finished: nothing to do
    changed = [a if a != "300" else "600" for a in common]
    assert main(["train", *changed, "--resume", str(folder)]) == 2
    assert "differ from those in" in capsys.readouterr().err
    assert main(["train", *common, "-params", "batch_size:__import__('os')", "--checkpoint-freq", "100"]) == 2
    assert "not allowed" in capsys.readouterr().err


def test_early_stopping_counters_travel_in_the_checkpoint():
    from sb3_macb.callbacks import MultiAgentEvalCallback, StopTrainingOnNoSuccessImprovement

    def callback():
        stop = StopTrainingOnNoSuccessImprovement(5)
        return MultiAgentEvalCallback(COMM, n_eval_episodes=2, callback_after_eval=stop, verbose=0, warn=False), stop

    first, stop = callback()
    stop.n_evals, stop.no_improvement_evals, stop.best_success_rate = 7, 3, 0.4
    second, other = callback()
    second.set_state(first.get_state())
    assert (other.n_evals, other.no_improvement_evals, other.best_success_rate) == (7, 3, 0.4)

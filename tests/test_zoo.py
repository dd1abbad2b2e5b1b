import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import optuna
import pytest
import yaml
from optuna.trial import TrialState

from sb3_macb import MADDPG
from sb3_macb.zoo import sweep as sweep_module
from sb3_macb.zoo.plots import main as plot
from sb3_macb.zoo.sweep import load_config, make_storage
from sb3_macb.zoo.train import DEFAULT_CONFIG, train

COMM = "sb3_macb/CommunicativeNavigation-v0"
TINY = ["--eval-freq", "50", "--eval-episodes", "2", "--no-progress", "--verbose", "0"]


def run_train(tmp_path, *args, **kwargs):
    return train(["--env", COMM, "-f", str(tmp_path / "logs"), "--seed", "0", *TINY, *args], **kwargs)


def test_yaml_holds_the_papers_settings():
    with open(DEFAULT_CONFIG) as file:
        config = yaml.safe_load(file)
    paper = config[COMM]
    assert paper["policy_kwargs"] == "dict(net_arch=[400, 300])"
    assert (paper["batch_size"], paper["learning_rate"], paper["gamma"], paper["tau"]) == (100, 0.001, 0.99, 0.005)
    assert (paper["buffer_size"], paper["learning_starts"], paper["noise_std"]) == (1_000_000, 100, 0.1)
    assert paper["exploration"] == {"beta": 0.8, "k": 512, "scope": "joint"}
    assert config["sb3_macb/TwoAgentNavigation-v0"] == paper
    assert {"maddpg", "ddpg", "macb_local", "macb_joint", "fast"} <= set(config["variants"])


def test_tiny_train_run_from_yaml(tmp_path):
    folder = run_train(tmp_path, "-n", "100", "--variant", "fast", "-params", "exploration.beta:0.3", "--save-replay-buffer")
    assert folder is not None and Path(folder).parent.name == "maddpg"
    model = MADDPG.load(Path(folder) / "model.zip")
    assert model.num_timesteps == 100
    assert model.exploration.beta == 0.3 and model.exploration.k == 512  # dotted override on the YAML's dict
    assert model.actor.mu.weights[1].shape[1:] == (64, 64)  # the fast variant
    assert model.batch_size == 100 and model.lr_schedule(1) == 0.001
    data = np.load(Path(folder) / "evaluations.npz")
    assert list(data["timesteps"]) == [50, 100] and "successes" in data.files
    saved = yaml.safe_load(open(Path(folder) / "config.yml"))
    assert saved is not None
    model.load_replay_buffer(Path(folder) / "replay_buffer.pkl")  # --save-replay-buffer: the run's 100 transitions
    assert model.replay_buffer.pos == 100 and model.replay_buffer.exploration is model.exploration


def test_a_negative_eval_freq_turns_evaluation_off_and_yaml_schedules_reach_the_model(tmp_path):
    folder = run_train(tmp_path, "-n", "150", "--variant", "fast", "--eval-freq", "-1",
                       "-params", "exploration.beta:'lin_0.5'", "exploration.normalize:'center'",
                       "--env-kwargs", "reward:'distance'")  # fmt: skip
    assert not (Path(folder) / "evaluations.npz").exists()  # rl_zoo3's -1: no evaluation
    saved = yaml.safe_load(open(Path(folder) / "config.yml"))
    assert saved["env_kwargs"] == {"reward": "distance"} and saved["exploration"]["beta"] == "lin_0.5"
    args = yaml.safe_load(open(Path(folder) / "args.yml"))  # the command's options, as rl_zoo3 keeps them
    assert args["env"] == COMM and args["eval_freq"] == 0 and args["variant"] == "fast"
    assert not (Path(folder) / "replay_buffer.pkl").exists()  # only on request
    model = MADDPG.load(Path(folder) / "model.zip")
    assert model.exploration.beta(1.0) == 0.5 and model.exploration.beta(0.0) == 0.0
    assert model.exploration.normalize == "center" and model.exploration.normalizer.updates == 50  # (learning starts at 100)


def test_variants_plain_maddpg_and_ddpg(tmp_path):
    folder = run_train(tmp_path, "-n", "60", "--variant", "ddpg,fast")
    model = MADDPG.load(Path(folder) / "model.zip")
    assert model.exploration is None and model.centralized_critic is False


def test_early_stop_from_yaml_callback(tmp_path):
    config = yaml.safe_load(open(DEFAULT_CONFIG))
    config[COMM]["callback"] = [{"sb3_macb.callbacks.StopTrainingOnSuccessRate": {"threshold": 0.9}}]
    config[COMM]["policy_kwargs"] = "dict(net_arch=[32])"
    path = tmp_path / "easy.yml"
    path.write_text(yaml.safe_dump(config))
    folder = run_train(tmp_path, "-n", "1000", "-conf", str(path), "--env-kwargs", "success_radius:100")
    data = np.load(Path(folder) / "evaluations.npz")
    assert list(data["timesteps"]) == [50]  # stopped after the first evaluation
    model = MADDPG.load(Path(folder) / "model.zip")
    assert model.num_timesteps == 50


def test_unknown_yaml_key(tmp_path):
    config = yaml.safe_load(open(DEFAULT_CONFIG))
    config[COMM]["learnin_rate"] = 0.01
    path = tmp_path / "bad.yml"
    path.write_text(yaml.safe_dump(config))
    with pytest.raises(ValueError, match=r"'learnin_rate' \(did you mean 'learning_rate'\?\)"):
        run_train(tmp_path, "-n", "20", "-conf", str(path))


def test_unknown_env_id_and_variant(tmp_path):
    with pytest.raises(ValueError, match="not found in gym registry"):
        train(["--env", "sb3_macb/CommunicativNavigation-v0", "-f", str(tmp_path), *TINY])
    with pytest.raises(ValueError, match="Unknown variant 'fastest'"):
        run_train(tmp_path, "-n", "20", "--variant", "fastest")


# --- sweeps ---------------------------------------------------------------------------------------------------------


def sweep_config(tmp_path, n_timesteps=60, betas=(0.2, 0.8), ks=(16, 32), seeds=(0,)):
    config = {
        "env": COMM,
        "n_timesteps": n_timesteps,
        "variant": "fast",
        "hyperparams": {"learning_starts": 20, "batch_size": 16},
        "eval_freq": 20,
        "eval_episodes": 2,
        "grid": {"exploration.beta": list(betas), "exploration.k": list(ks)},
        "seeds": list(seeds),
    }
    path = tmp_path / "sweep.yml"
    path.write_text(yaml.safe_dump(config))
    return path


def start_worker(config, storage, name, log_folder, heartbeat=30):
    cmd = [sys.executable, "-m", "sb3_macb", "sweep", "--config", str(config), "--storage", storage,
           "--study-name", name, "-f", str(log_folder), "--heartbeat", str(heartbeat)]  # fmt: skip
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def check_grid_done_once(storage, name, n_points):
    study = optuna.load_study(study_name=name, storage=storage)
    done = [t for t in study.get_trials() if t.state == TrialState.COMPLETE]
    points = [tuple(sorted(t.params.items())) for t in done]
    assert len(points) == n_points and len(set(points)) == n_points, points
    for trial in done:
        assert 0.0 <= trial.user_attrs["success_rate"] <= 1.0
        assert 0.0 < trial.user_attrs["count1_fraction"] <= 1.0
        assert os.path.isfile(os.path.join(trial.user_attrs["run_folder"], "evaluations.npz"))
    return study


def run_two_workers(tmp_path, storage, name):
    config = sweep_config(tmp_path)
    workers = [start_worker(config, storage, name, tmp_path / "logs") for _ in range(2)]
    outputs = [w.communicate(timeout=300)[0] for w in workers]
    assert all(w.returncode == 0 for w in workers), outputs
    study = check_grid_done_once(storage, name, 4)
    results = (tmp_path / "logs" / name / "results.csv").read_text().splitlines()
    assert len(results) == 5 and results[0].startswith("trial,exploration.beta,exploration.k,seed,success_rate")
    return study


def test_sweep_two_workers_sqlite(tmp_path):
    run_two_workers(tmp_path, f"sqlite:///{tmp_path / 'sweep.db'}", "grid")


def test_sweep_waits_for_a_locked_sqlite_database(tmp_path):
    """A worker that finds the database locked by another writer for longer than SQLite's default 5 s still joins."""
    import sqlite3
    import threading

    url = f"sqlite:///{tmp_path / 'sweep.db'}"
    make_storage(url, heartbeat_interval=30)  # the tables exist, as when another worker got there first
    holder = sqlite3.connect(tmp_path / "sweep.db", check_same_thread=False)
    holder.execute("BEGIN EXCLUSIVE")
    release = threading.Timer(6.0, holder.commit)
    release.start()
    try:
        start = time.time()
        storage = make_storage(url, heartbeat_interval=30)
        study = sweep_module._with_retries(lambda: optuna.create_study(study_name="locked", storage=storage))
        waited = time.time() - start
    finally:
        release.join()
        holder.close()
    assert study.study_name == "locked"
    assert waited >= 5.0  # it did wait for the lock rather than find the database free


def test_sweep_postgresql(tmp_path):
    url = os.environ.get("SB3_MACB_TEST_POSTGRES_URL")
    if not url:
        pytest.skip(
            "SB3_MACB_TEST_POSTGRES_URL is not set: no PostgreSQL server (.ci/run starts one with .ci/start-postgres.sh)"
        )
    try:
        import sqlalchemy

        sqlalchemy.create_engine(url).connect().close()
    except Exception as exc:  # noqa: BLE001
        pytest.skip(f"PostgreSQL at {url} cannot be reached: {exc}")
    run_two_workers(tmp_path, url, f"grid_{os.getpid()}_{int(time.time())}")


class FreezingProxy:
    """A loopback TCP proxy to a server that, once frozen, keeps every connection open and forwards nothing."""

    def __init__(self, host: str, port: int):
        import socket
        import threading

        self.upstream = (host, port)
        self.frozen = threading.Event()
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        import socket
        import threading

        while True:
            try:
                client, _ = self.server.accept()
            except OSError:
                return
            upstream = socket.create_connection(self.upstream)
            for a, b in ((client, upstream), (upstream, client)):
                threading.Thread(target=self._pump, args=(a, b), daemon=True).start()

    def _pump(self, source, target) -> None:
        while True:
            if self.frozen.is_set():  # a server that has stopped: nothing is read or answered, nothing is closed
                time.sleep(0.1)
                continue
            try:
                data = source.recv(65536)
                if not data:
                    return
                if self.frozen.is_set():
                    continue  # (dropped: the frozen server never answers it)
                target.sendall(data)
            except OSError:
                return


def test_a_postgresql_server_that_stops_answering_mid_sweep_is_reported_at_once(tmp_path):
    from urllib.parse import urlsplit

    url = os.environ.get("SB3_MACB_TEST_POSTGRES_URL")
    if not url:
        pytest.skip(
            "SB3_MACB_TEST_POSTGRES_URL is not set: no PostgreSQL server (.ci/run starts one with .ci/start-postgres.sh)"
        )
    parts = urlsplit(url)
    proxy = FreezingProxy(parts.hostname, parts.port or 5432)
    proxied = url.replace(
        parts.netloc, f"{parts.username}@127.0.0.1:{proxy.port}" if parts.username else f"127.0.0.1:{proxy.port}"
    )
    name = f"frozen_{os.getpid()}_{int(time.time())}"
    config = sweep_config(tmp_path, n_timesteps=100_000, betas=(0.5,), ks=(16,))
    cmd = [sys.executable, "-X", "faulthandler", "-m", "sb3_macb", "sweep", "--config", str(config), "--storage", proxied,
           "--study-name", name, "-f", str(tmp_path / "logs"), "--heartbeat", "1", "--storage-timeout", "5"]  # fmt: skip
    worker = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while time.time() < deadline:  # until its trial runs (read through the real server)
        try:
            if any(t.state == TrialState.RUNNING for t in optuna.load_study(study_name=name, storage=url).get_trials()):
                break
        except KeyError:
            pass
        time.sleep(0.5)
    else:
        worker.kill()
        pytest.fail("the worker never started its trial")
    time.sleep(2)  # training, heartbeats going
    proxy.frozen.set()
    frozen_at = time.time()
    try:
        _, err = worker.communicate(timeout=90)
    except subprocess.TimeoutExpired:
        worker.send_signal(signal.SIGABRT)  # its threads' stacks, for the failure message
        pytest.fail(f"the worker still runs 90 s after the server froze:\n{worker.communicate(timeout=30)[1][-6000:]}")
    finally:
        worker.kill()
    elapsed = time.time() - frozen_at
    print(f"reported {elapsed:.1f} s after the server froze: {err.strip().splitlines()[-1] if err.strip() else err}")
    assert worker.returncode == 2 and elapsed < 60, (worker.returncode, elapsed, err)
    lines = err.strip().splitlines()
    assert "Traceback" not in err and "did not answer within 5 s" in lines[-1] and "127.0.0.1" in lines[-1], err


@pytest.mark.slow
def test_killed_workers_trial_is_run_again(tmp_path):
    storage = f"sqlite:///{tmp_path / 'sweep.db'}"
    config = sweep_config(tmp_path, n_timesteps=4000, betas=(0.5,), ks=(16, 32))
    victim = start_worker(config, storage, "kill", tmp_path / "logs", heartbeat=1)
    deadline = time.time() + 120
    while time.time() < deadline:  # wait until the victim has claimed a trial
        try:
            study = optuna.load_study(study_name="kill", storage=storage)
            running = [t for t in study.get_trials() if t.state == TrialState.RUNNING]
            if running and (tmp_path / "logs" / "kill" / f"trial_{running[0].number}" / "experiment.json").exists():
                break  # (killed while it trains)
        except KeyError:
            pass
        time.sleep(0.5)
    else:
        victim.kill()
        pytest.fail("the first worker never started a trial")
    victim.send_signal(signal.SIGKILL)
    victim.wait()
    time.sleep(4)  # let its heartbeat go stale (grace period: 3 heartbeats)
    rescuer = start_worker(config, storage, "kill", tmp_path / "logs", heartbeat=1)
    output = rescuer.communicate(timeout=300)[0]
    assert rescuer.returncode == 0, output
    study = check_grid_done_once(storage, "kill", 2)
    failed = [t for t in study.get_trials() if t.state == TrialState.FAIL]
    assert len(failed) == 1  # the killed trial, failed and run again from the queue


def test_sweep_config_errors(tmp_path):
    path = tmp_path / "bad.yml"
    path.write_text(yaml.safe_dump({"env": COMM, "grid": {"exploration.beta": [0.1]}, "seeds": [0], "n_timestep": 5}))
    with pytest.raises(ValueError, match=r"unknown sweep config key\(s\) \['n_timestep'\]"):
        load_config(str(path))
    path.write_text(yaml.safe_dump({"env": COMM, "grid": {"exploratio.beta": [0.1]}, "seeds": [0]}))
    with pytest.raises(ValueError, match="'exploratio.beta' is not a hyperparameter"):
        load_config(str(path))


# --- plots ----------------------------------------------------------------------------------------------------------


def test_plots_from_a_small_run(tmp_path):
    for seed in (0, 1):
        train(["--env", "sb3_macb/TwoAgentNavigation-v0", "-f", str(tmp_path / "group" / f"seed_{seed}"), "--seed",
               str(seed), "-n", "100", "--variant", "fast", *TINY[:2], "--eval-episodes", "2", "--no-progress",
               "--verbose", "0", "--eval-freq", "20"])  # fmt: skip
    outputs = {name: tmp_path / f"{name}.png" for name in ("curves", "collisions", "simhash")}
    plot(["curves", str(tmp_path / "group"), "--smooth", "2", "-o", str(outputs["curves"])])
    plot(["collisions", str(tmp_path / "group"), "-o", str(outputs["collisions"])])
    plot(["simhash", "--points", "300", "-o", str(outputs["simhash"])])
    results = tmp_path / "results.csv"
    results.write_text(
        "trial,exploration.beta,exploration.k,seed,success_rate,count1_fraction,run_folder\n"
        "0,0.2,32,0,0.5,0.9,a\n1,0.2,32,1,0.7,0.8,b\n2,0.8,32,0,1.0,1.0,c\n"
    )
    plot(["table", str(results), "-o", str(tmp_path / "table")])
    outputs["table"] = tmp_path / "table.png"
    for path in outputs.values():
        assert path.stat().st_size > 10_000 and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    table = (tmp_path / "table.md").read_text()
    assert "| 32 | 0.60, 85% (n=2) | 1.00, 100% (n=1) |" in table
    assert table.startswith(f"{tmp_path.name}: seeds per cell 1/2\n")  # a results.csv is named by its folder
    other = tmp_path / "grid.csv"
    other.write_text(results.read_text())
    plot(["table", str(other), "-o", str(tmp_path / "grid"), "--title", "4e4 episodes"])
    assert (tmp_path / "grid.md").read_text().startswith("grid: seeds per cell 1/2, 4e4 episodes\n")


def test_sweep_pack_trains_queued_points_together_as_they_would_run_alone(tmp_path):
    from sb3_macb.zoo.experiment import Experiment, ExperimentConfig, RunConfig, load_hyperparams
    from sb3_macb.zoo.sweep import main as sweep

    config = tmp_path / "grid.yml"
    config.write_text(
        "env: sb3_macb/CommunicativeNavigation-v0\nn_timesteps: 120\nvariant: fast\n"
        "hyperparams: {batch_size: 16, policy_kwargs: 'dict(net_arch=[16])'}\n"
        "grid: {exploration.k: [16, 512], exploration.beta: [0.5]}\nseeds: [0, 1]\n"
    )
    sweep(["--config", str(config), "--study-name", "p", "-f", str(tmp_path / "sw"), "--pack", "3"])
    rows = (tmp_path / "sw" / "p" / "results.csv").read_text().strip().splitlines()[1:]
    assert len(rows) == 4
    packs = sorted(p.name for p in (tmp_path / "sw" / "p").iterdir() if p.name.startswith("pack_"))
    assert packs == ["pack_0", "pack_3"]  # three points together, then the last one
    row = next(r.split(",") for r in rows if r.split(",")[0] == "1")
    params = dict(zip(["exploration.beta", "exploration.k", "seed"], row[1:4]))
    hp = load_hyperparams("sb3_macb/CommunicativeNavigation-v0", variants=["fast"],
                          overrides={"batch_size": 16, "policy_kwargs": "dict(net_arch=[16])",
                                     "exploration.k": int(params["exploration.k"]),
                                     "exploration.beta": float(params["exploration.beta"])})  # fmt: skip
    alone = ExperimentConfig(
        "sb3_macb/CommunicativeNavigation-v0", [RunConfig(int(params["seed"]), str(tmp_path / "alone"), hyperparams=hp)], 120
    )
    Experiment(alone, str(tmp_path / "alone_exp"), verbose=0).run()
    a, b = np.load(tmp_path / "alone" / "evaluations.npz"), np.load(tmp_path / "sw" / "p" / "trial_1" / "evaluations.npz")
    assert all(np.array_equal(a[name], b[name]) for name in a.files)
    bad = tmp_path / "bad.yml"
    bad.write_text(config.read_text().replace("exploration.beta: [0.5]", "learning_rate: [0.001, 0.01]"))
    with pytest.raises(ValueError, match="only MACB's settings"):
        sweep(["--config", str(bad), "--study-name", "q", "-f", str(tmp_path / "sw2"), "--pack", "2"])


@pytest.mark.parametrize("spelling", ["-c", "--conf", "-conf", "--conf-file", "--conf-file=", "--conf="])
def test_every_spelling_of_the_config_option_is_used(tmp_path, spelling):
    conf = tmp_path / "tiny.yml"
    entry = yaml.safe_load(Path(DEFAULT_CONFIG).read_text())["sb3_macb/CommunicativeNavigation-v0"]
    small = {"n_timesteps": 40, "policy_kwargs": "dict(net_arch=[8])", "learning_starts": 10, "batch_size": 4}
    conf.write_text(yaml.safe_dump({"sb3_macb/CommunicativeNavigation-v0": {**entry, **small}}))
    option = [spelling + str(conf)] if spelling.endswith("=") else [spelling, str(conf)]
    folder = train(["--env", "sb3_macb/CommunicativeNavigation-v0", "-f", str(tmp_path / "logs"), "--no-progress",
                    "--verbose", "0", *option])  # fmt: skip
    assert len(np.load(os.path.join(folder, "evaluations.npz"))["timesteps"]) == 2  # the file's 40 steps, not 800k


def test_hyperparameter_strings_cannot_run_code(tmp_path):
    from sb3_macb.cli import main
    from sb3_macb.zoo.experiment import ExperimentError

    marker = tmp_path / "pwned"
    attack = f"__import__('os').system('touch {marker}')"
    entry = yaml.safe_load(Path(DEFAULT_CONFIG).read_text())["sb3_macb/CommunicativeNavigation-v0"]
    env = ["--env", "sb3_macb/CommunicativeNavigation-v0", "-f", str(tmp_path / "logs"), "--no-progress", "-n", "40"]
    for name, value in (("policy_kwargs", attack), ("callback", [{"os.system": {"command": f"touch {marker}"}}])):
        conf = tmp_path / f"{name}.yml"
        conf.write_text(yaml.safe_dump({"sb3_macb/CommunicativeNavigation-v0": {**entry, name: value}}))
        with pytest.raises(ExperimentError, match=f"'{name}'.*--unsafe-eval"):
            train([*env, "-conf", str(conf)])
    with pytest.raises(ExperimentError, match="-params policy_kwargs.*not allowed"):
        train([*env, "-params", f"policy_kwargs:{attack}"])
    assert main(["train", *env, "--env-kwargs", f"reward:{attack}"]) == 2  # one line on stderr, no traceback
    with pytest.raises(ExperimentError, match="not a .yml"):
        train([*env, "-conf", "os"])  # rl_zoo3 would import a Python module of that name
    sweep_config = tmp_path / "sweep.yml"
    sweep_config.write_text(yaml.safe_dump({"env": "sb3_macb/CommunicativeNavigation-v0", "n_timesteps": 40,
                                            "hyperparams": {"policy_kwargs": attack}, "grid": {"exploration.k": [8]},
                                            "seeds": [0]}))  # fmt: skip
    with pytest.raises(ExperimentError, match="policy_kwargs"):
        sweep_module.run_trial(
            sweep_module.load_config(str(sweep_config)), {"exploration.k": 8, "seed": 0}, str(tmp_path / "t")
        )
    assert not marker.exists()
    with pytest.raises(ExperimentError, match="-params.*'learning_rat'.*did you mean 'learning_rate'"):
        train([*env, "-params", "learning_rat:0.1"])
    # asked for explicitly, strings are Python again
    folder = train([*env, "--verbose", "0", "--unsafe-eval", "-params", "policy_kwargs:dict(net_arch=[int('8')])",
                    "learning_starts:10", "batch_size:4"])  # fmt: skip
    assert MADDPG.load(os.path.join(folder, "model.zip")).policy.net_arch == [8]


def test_policy_alone_saves_and_loads(tmp_path):
    from sb3_macb import MADDPGPolicy
    from sb3_macb.envs.vec_tasks import make_task_vec_env

    model = MADDPG(
        "MlpPolicy", make_task_vec_env("sb3_macb/CommunicativeNavigation-v0", 1), policy_kwargs=dict(net_arch=[8]), seed=0
    )
    model.policy.save(tmp_path / "policy.pth")
    policy = MADDPGPolicy.load(tmp_path / "policy.pth")
    obs = make_task_vec_env("sb3_macb/CommunicativeNavigation-v0", 4).reset()
    assert np.array_equal(policy.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0])


def test_console_is_quiet_and_shows_the_effective_hyperparameters(tmp_path, capsys):
    folder = train(["--env", "sb3_macb/CommunicativeNavigation-v0", "-n", "2100", "-f", str(tmp_path), "--no-progress",
                    "--variant", "maddpg,fast", "-params", "batch_size:16"])  # fmt: skip
    out = capsys.readouterr().out
    assert out.count("rollout/ ") <= 2 and out.count("eval/ ") <= 2  # not a table every evaluation or 4 episodes
    assert "variants: maddpg, fast" in out and "'batch_size': 16" in out and "net_arch=[64, 64]" in out
    assert "Default hyperparameters" not in out  # rl_zoo3's print of the file's entry, before variants
    assert out.count("Eval num_timesteps=") == 1  # one summary line per 100 evaluations
    config = yaml.safe_load(Path(folder, "config.yml").read_text())
    assert dict(config)["n_timesteps"] == 2100


def test_a_sweep_repairs_a_partial_queue_retries_failures_and_reports_them(tmp_path):
    import csv as csv_module

    from sb3_macb.zoo.sweep import grid_points, point_key, work

    storage_url = f"sqlite:///{tmp_path / 'sweep.db'}"
    config = sweep_config(tmp_path, n_timesteps=40, betas=(0.5,), ks=(16, 32))
    points = grid_points(load_config(str(config)))
    storage = make_storage(storage_url, 30)
    # a first worker died while queueing the grid: its marker exists, one of the two points is queued
    study = optuna.create_study(study_name="partial", storage=storage, direction="maximize")
    optuna.create_study(study_name="partial.grid", storage=storage)
    study.enqueue_trial(points[0], user_attrs={"grid_point": True, "point": point_key(points[0])})
    assert work(str(config), storage_url, "partial", str(tmp_path / "logs"), enqueue_wait=0.5) == 0
    check_grid_done_once(storage_url, "partial", 2)
    rows = list(csv_module.DictReader(open(tmp_path / "logs" / "partial" / "results.csv")))
    assert [r["status"] for r in rows] == ["done", "done"]

    broken = sweep_config(tmp_path, n_timesteps=40, betas=(0.5,), ks=(16,))
    data = yaml.safe_load(broken.read_text())
    data["hyperparams"]["env_kwargs"] = {"reward": "bogus"}  # every run of it fails
    broken.write_text(yaml.safe_dump(data))
    assert work(str(broken), storage_url, "broken", str(tmp_path / "logs"), max_attempts=2) == 1
    failed = [
        t for t in optuna.load_study(study_name="broken", storage=storage_url).get_trials() if t.state == TrialState.FAIL
    ]
    assert len(failed) == 2 and "bogus" in failed[0].user_attrs["error"]
    rows = list(csv_module.DictReader(open(tmp_path / "logs" / "broken" / "results.csv")))
    assert rows[0]["status"] == "failed" and "bogus" in rows[0]["error"]


def test_a_storage_that_never_answers_fails_fast_with_a_clear_error():
    import socket
    import threading

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    accepted = []
    threading.Thread(target=lambda: [accepted.append(server.accept()) for _ in range(8)], daemon=True).start()
    port = server.getsockname()[1]
    start = time.time()
    with pytest.raises(ConnectionError, match=rf"postgresql://user:\*\*\*@127.0.0.1:{port}/db .*gave up"):
        make_storage(f"postgresql://user:secret@127.0.0.1:{port}/db", 30, connect_timeout=1, deadline=3)
    assert time.time() - start < 30 and accepted  # it connected, then gave up instead of hanging
    server.close()


def test_a_storage_whose_database_driver_is_missing_names_the_extra_at_once(monkeypatch):
    for driver in ("psycopg", "psycopg2"):
        monkeypatch.setitem(sys.modules, driver, None)  # as if not installed
    start = time.time()
    with pytest.raises(
        ConnectionError, match=r"postgresql://user:\*\*\*@127.0.0.1:1/db: .*pip install 'sb3_macb\[postgres\]'"
    ):
        make_storage("postgresql://user:secret@127.0.0.1:1/db", 30, connect_timeout=1, deadline=20)
    assert time.time() - start < 10  # no retries: a missing driver does not come back


def test_train_help_lists_the_packages_options_and_optimize_runs_without_argv(tmp_path, capsys):
    from sb3_macb.zoo.train import make_parser

    text = make_parser().format_help()
    for option in ("--variant", "--no-progress", "--unsafe-eval", "--checkpoint-freq", "--resume", "--optimize"):
        assert option in text
    argv = list(sys.argv)
    train(["--env", COMM, "-n", "60", "-f", str(tmp_path), "--seed", "0", "--variant", "fast", "--optimize", "--n-trials",
           "2", "--n-startup-trials", "2", "--n-evaluations", "1", "--eval-episodes", "2", "--eval-freq", "30",
           "-params", "learning_starts:10", "--verbose", "0", "--no-progress"])  # fmt: skip
    assert sys.argv == argv  # the command line of the process is left alone
    reports = list((tmp_path / "maddpg").glob("report_*.csv"))
    assert len(reports) == 1 and len(reports[0].read_text().splitlines()) == 3  # header + 2 trials
    # the trials' value is the success rate of their last evaluation (a sparse return would be <= -1 here)
    with open(reports[0], newline="") as file:
        values = [float(row["value"]) for row in csv.DictReader(file)]
    assert all(0.0 <= v <= 1.0 for v in values), values
    import rl_zoo3.exp_manager
    from rl_zoo3.callbacks import TrialEvalCallback

    assert rl_zoo3.exp_manager.TrialEvalCallback is TrialEvalCallback  # rl_zoo3 left as it was


def test_optimize_keeps_its_trials_in_a_journal_file(tmp_path):
    journal = tmp_path / "optuna.log"
    for _ in range(2):  # a second worker (here: after the first) adds to the same study
        train(["--env", COMM, "-n", "40", "-f", str(tmp_path), "--seed", "0", "--variant", "fast", "--optimize",
               "--n-trials", "1", "--n-startup-trials", "2", "--n-evaluations", "1", "--eval-episodes", "2",
               "--eval-freq", "20", "-params", "learning_starts:10", "--verbose", "0", "--no-progress",
               "--storage", str(journal), "--study-name", "s"])  # fmt: skip
    storage = optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(str(journal)))
    study = optuna.load_study(study_name="s", storage=storage)
    assert [t.state for t in study.trials] == [TrialState.COMPLETE] * 2


def test_optimize_warns_when_parallel_jobs_share_sqlite(tmp_path, capsys, monkeypatch):
    import rl_zoo3.exp_manager

    monkeypatch.setattr(rl_zoo3.exp_manager.ExperimentManager, "hyperparameters_optimization", lambda self: None)
    common = ["--env", COMM, "-n", "40", "-f", str(tmp_path), "--seed", "0", "--variant", "fast", "--optimize",
              "--verbose", "0", "--no-progress"]  # fmt: skip
    train([*common, "--n-jobs", "2", "--storage", f"sqlite:///{tmp_path / 'o.db'}"])
    assert "2 jobs share the SQLite storage" in capsys.readouterr().err
    train([*common, "--n-jobs", "2", "--storage", str(tmp_path / "o.log")])
    train([*common, "--storage", f"sqlite:///{tmp_path / 'o.db'}"])
    assert "SQLite" not in capsys.readouterr().err


def test_rl_zoo3_keys_the_runs_cannot_restore_are_refused_before_anything_is_written(tmp_path):
    from sb3_macb.zoo.experiment import ExperimentError

    for params in (["normalize:True"], ["env_wrapper:'gymnasium.wrappers.ClipAction'"]):
        with pytest.raises(ExperimentError, match="do not support"):
            run_train(tmp_path, "-n", "40", "-params", *params)
    assert not (tmp_path / "logs").exists()
    folder = run_train(tmp_path, "-n", "100", "--variant", "fast", "-params", "n_envs:2", "learning_starts:10")
    assert list(np.load(Path(folder) / "evaluations.npz")["timesteps"]) == [50, 100]  # every 50 steps over both envs
    assert MADDPG.load(Path(folder) / "model.zip").n_envs == 2


@pytest.mark.parametrize("pack", [0, 1])
def test_a_trial_failed_by_another_worker_while_it_ran_is_run_again(tmp_path, monkeypatch, pack):
    from sb3_macb.zoo.sweep import work

    storage_url = f"sqlite:///{tmp_path / 'sweep.db'}"
    config = sweep_config(tmp_path, n_timesteps=40, betas=(0.5,), ks=(16,))
    calls = []

    def fail_the_running_trial():  # what fail_stale_trials does in another worker when a heartbeat comes late
        if not calls:
            study = optuna.load_study(study_name="late", storage=storage_url)
            running = study.get_trials(states=(TrialState.RUNNING,))
            study._storage.set_trial_state_values(running[0]._trial_id, TrialState.FAIL)
        calls.append(1)

    real_trial, real_pack = sweep_module.run_trial, sweep_module.run_pack
    monkeypatch.setattr(sweep_module, "run_trial", lambda *a, **k: (real_trial(*a, **k), fail_the_running_trial())[0])
    monkeypatch.setattr(sweep_module, "run_pack", lambda *a, **k: (real_pack(*a, **k), fail_the_running_trial())[0])
    assert work(str(config), storage_url, "late", str(tmp_path / "logs"), pack=pack, enqueue_wait=0.5) == 0
    assert len(calls) == 2  # the point ran again after its first result was refused
    check_grid_done_once(storage_url, "late", 1)


@pytest.mark.parametrize("pack", [0, 2])
def test_the_retry_of_a_dead_workers_point_resumes_from_its_checkpoint_and_ends_as_if_never_stopped(
    tmp_path, monkeypatch, pack
):
    from sb3_macb.zoo.experiment import Experiment
    from sb3_macb.zoo.sweep import work

    config = tmp_path / "grid.yml"  # a buffer of 100 wraps before and after the checkpoints (every 100 steps)
    config.write_text(
        f"env: {COMM}\nn_timesteps: 1000\nvariant: fast\neval_freq: 100\neval_episodes: 2\n"
        "hyperparams: {batch_size: 16, learning_starts: 20, buffer_size: 100, policy_kwargs: 'dict(net_arch=[16])'}\n"
        f"grid: {{exploration.k: [16]}}\nseeds: {[0, 1] if pack else [0]}\n"
    )
    first = "pack_0" if pack else "trial_0"
    url = f"sqlite:///{tmp_path / 'cut.db'}"
    cmd = [sys.executable, "-m", "sb3_macb", "sweep", "--config", str(config), "--storage", url, "--study-name", "s",
           "-f", str(tmp_path / "cut"), "--heartbeat", "1", "--checkpoint-freq", "100", "--pack", str(pack)]  # fmt: skip
    worker = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    latest = tmp_path / "cut" / "s" / first / "checkpoint" / "LATEST"
    deadline = time.time() + 240
    while not latest.exists() and worker.poll() is None and time.time() < deadline:
        time.sleep(0.01)
    worker.send_signal(signal.SIGKILL)
    worker.wait(timeout=60)
    assert latest.exists() and '"done": false' in (latest.parent.parent / "experiment.json").read_text()  # killed mid-run

    resumed = []
    real_run = Experiment.run
    monkeypatch.setattr(
        Experiment, "run", lambda self, resume=False: (resumed.append((self.folder, resume)), real_run(self, resume))[1]
    )
    assert work(str(config), url, "s", str(tmp_path / "cut"), heartbeat=1, pack=pack, checkpoint_freq=100, poll=0.5) == 0
    assert resumed == [(str(tmp_path / "cut" / "s" / first), True)]  # one experiment, continued from its checkpoint
    assert (
        work(str(config), f"sqlite:///{tmp_path / 'whole.db'}", "s", str(tmp_path / "whole"), pack=pack, checkpoint_freq=100)
        == 0
    )
    study = optuna.load_study(study_name="s", storage=url)
    done = [t for t in study.get_trials() if t.state == TrialState.COMPLETE]
    assert len(done) == (2 if pack else 1) and all(t.number >= len(done) for t in done)  # the retries of the dead trials
    for trial in done:
        name = os.path.basename(trial.user_attrs["run_folder"])
        assert name in ("trial_0", "trial_1")  # the dead attempt's folder
        cut, whole = (np.load(tmp_path / r / "s" / name / "evaluations.npz") for r in ("cut", "whole"))
        assert list(cut["timesteps"]) == list(range(100, 1001, 100))
        assert all(np.array_equal(cut[key], whole[key]) for key in whole.files)


def test_a_retry_whose_folder_is_still_being_trained_starts_again_in_its_own(tmp_path):
    """A worker failed for a late heartbeat still trains (and holds its folder's lock): its retry keeps out."""
    from contextlib import nullcontext

    from sb3_macb.zoo.sweep import _folder_lock, grid_points, point_key, work

    lock = str(tmp_path / "x.lock")
    with _folder_lock(lock) as first, _folder_lock(lock) as second:
        assert first and not second  # (a second open file description: the lock is the first's)
    with _folder_lock(lock) as again:
        assert again  # released with the first
    config = sweep_config(tmp_path, n_timesteps=40, betas=(0.5,), ks=(16,))
    [point] = grid_points(load_config(str(config)))
    for name, busy in (("busy", True), ("free", False)):
        url = f"sqlite:///{tmp_path / name}.db"
        study = optuna.create_study(study_name=name, storage=make_storage(url, 30), direction="maximize")
        optuna.create_study(study_name=f"{name}.grid", storage=url).set_user_attr("n_points", 1)
        # the retry of trial 5, as Optuna's RetryFailedTrialCallback queues it (the user attributes copied)
        attrs = {"grid_point": True, "point": point_key(point), "run_name": "trial_5", "pack_name": ""}
        study.enqueue_trial(point, user_attrs=attrs)
        held = _folder_lock(str(tmp_path / "logs" / name / "locks" / "trial_5.lock")) if busy else nullcontext(True)
        with held as holding:
            assert holding
            assert work(str(config), url, name, str(tmp_path / "logs"), checkpoint_freq=20, enqueue_wait=0.5) == 0
        [done] = [t for t in optuna.load_study(study_name=name, storage=url).get_trials() if t.state == TrialState.COMPLETE]
        expected = "trial_0" if busy else "trial_5"  # its own number's folder, or the dead attempt's
        assert os.path.basename(done.user_attrs["run_folder"]) == expected and done.user_attrs["run_name"] == expected
        assert os.path.isfile(tmp_path / "logs" / name / expected / "evaluations.npz")


def test_a_dead_workers_pack_is_claimed_whole_and_waited_for_while_its_runs_go_stale_one_by_one(tmp_path):
    from sb3_macb.zoo.experiment import Experiment, ExperimentConfig, RunConfig, load_hyperparams
    from sb3_macb.zoo.sweep import _claim_pack_to_resume, _folder_lock

    folder = tmp_path / "logs" / "s"
    hp = load_hyperparams(COMM, variants=["fast"])
    runs = [RunConfig(seed, str(folder / f"trial_{seed}"), hyperparams=hp) for seed in (0, 1)]
    os.makedirs(folder / "pack_0")
    Experiment(ExperimentConfig(COMM, runs, n_timesteps=100), str(folder / "pack_0"))._write_experiment_file(done=False)
    url = f"sqlite:///{tmp_path / 's.db'}"
    storage = make_storage(url, 30)
    study = optuna.create_study(study_name="s", storage=storage, direction="maximize")
    for run in ("trial_1", "trial_0"):  # (as the dead worker's trials are retried: user attributes copied)
        study.enqueue_trial({"seed": int(run[-1])}, user_attrs={"grid_point": True, "run_name": run, "pack_name": "pack_0"})
    with pytest.warns(UserWarning):
        study.ask()  # trial_1's: still running (its heartbeat not stale yet), trial_0's retry waiting
    assert _claim_pack_to_resume(study, storage, str(folder)) == (None, [], True)  # wait for trial_1's retry
    with _folder_lock(str(folder / "locks" / "pack_0.lock")):  # unless the pack's worker is alive: then the queue has them
        assert _claim_pack_to_resume(study, storage, str(folder)) == (None, [], False)
    study.enqueue_trial({"seed": 1}, user_attrs={"grid_point": True, "run_name": "trial_1", "pack_name": "pack_0"})
    # both waiting: a worker that cannot reach the pack's folder leaves them to the queue; one that can claims both
    assert _claim_pack_to_resume(study, storage, str(tmp_path / "elsewhere")) == (None, [], False)
    assert len(study.get_trials(states=(TrialState.WAITING,))) == 2
    name, claimed, wait = _claim_pack_to_resume(study, storage, str(folder))
    assert name == "pack_0" and not wait and sorted(t.user_attrs["run_name"] for t in claimed) == ["trial_0", "trial_1"]
    assert not study.get_trials(states=(TrialState.WAITING,))


def test_a_folder_name_inherited_from_the_storage_never_reaches_outside_the_sweeps_folder():
    from types import SimpleNamespace

    from sb3_macb.zoo.sweep import _inherited_name, _run_name

    def trial(**attrs):
        return SimpleNamespace(user_attrs=attrs, number=7)

    for bad in ("../trial_1", "/tmp/trial_1", "trial_1/../..", "trial_", "pack_1", 3, None):
        assert _inherited_name(trial(run_name=bad), "run_name", "trial_") is None
        assert _run_name(trial(run_name=bad), resume=True) == "trial_7"
    assert _run_name(trial(run_name="trial_3"), resume=True) == "trial_3"
    assert _run_name(trial(run_name="trial_3"), resume=False) == "trial_7"  # without checkpoints: a new folder
    assert _run_name(trial(run_name="trial_3", pack_name="pack_2"), resume=True) == "trial_7"  # a pack's run: not alone


def test_sweep_pack_a_point_refused_at_setup_fails_alone(tmp_path):
    import csv

    from sb3_macb.zoo.sweep import main as sweep

    config = tmp_path / "grid.yml"
    config.write_text(
        "env: sb3_macb/CommunicativeNavigation-v0\nn_timesteps: 60\nvariant: fast\n"
        "hyperparams: {batch_size: 8, policy_kwargs: 'dict(net_arch=[8])'}\n"
        "grid: {exploration.beta: [0.5, -1.0]}\nseeds: [0]\n"
    )
    assert sweep(["--config", str(config), "--study-name", "p", "-f", str(tmp_path / "sw"), "--pack", "2",
                  "--max-attempts", "1"]) == 1  # fmt: skip
    with open(tmp_path / "sw" / "p" / "results.csv") as file:
        rows = {row["exploration.beta"]: row for row in csv.DictReader(file)}
    assert rows["0.5"]["status"] == "done" and os.path.isfile(os.path.join(rows["0.5"]["run_folder"], "evaluations.npz"))
    assert rows["-1.0"]["status"] == "failed" and "beta must be a finite number >= 0" in rows["-1.0"]["error"]


def test_curve_titles_name_the_task_and_the_smoothing_applied_and_unequal_runs_are_announced(tmp_path):
    from sb3_macb.zoo import plots

    def run(folder, n):
        folder.mkdir(parents=True)
        np.savez(folder / "evaluations.npz", timesteps=20 * np.arange(1, n + 1), episodes=np.arange(1, n + 1),
                 successes=np.ones((n, 2), dtype=bool), results=np.zeros((n, 2)))  # fmt: skip

    group = tmp_path / "Task-sparse" / "maddpg"
    run(group / "seed_0", 10)
    title = plots.plot_curves([str(group)], str(tmp_path / "a.png"), window=50)
    assert title.startswith("Task-sparse: ") and "moving average of 10 evaluations, 10 training episodes" in title
    run(group / "seed_1", 4)
    with pytest.warns(UserWarning, match="its runs have 4 to 10 evaluations; its curve ends at the shortest"):
        title = plots.plot_curves([str(group)], str(tmp_path / "b.png"), window=2)
    assert "moving average of 2 evaluations, 4 training episodes" in title
    assert plots._label(str(group), 1) == "maddpg (1 seed)" and plots._label(str(group), 3) == "maddpg (3 seeds)"


def test_enjoy_plays_a_run_folder_and_names_what_is_missing(tmp_path, capsys):
    from sb3_macb.cli import main as cli
    from sb3_macb.zoo.enjoy import enjoy

    folder = run_train(tmp_path, "-n", "120", "--variant", "fast", "--env-kwargs", "max_cycles:10")
    records = enjoy([folder, "-n", "3", "--seed", "1"])
    out = capsys.readouterr().out
    assert len(records) == 3 and all(r["returns"].shape == (2,) for r in records)
    assert "episode 3: success" in out and "speaker_0" in out and "success rate" in out
    assert "{'max_cycles': 10}" in out  # the run's own env kwargs, from its config.yml
    again = enjoy([folder, "-n", "3", "--seed", "1", "--model", "final"])
    assert len(again) == 3
    # recorded on the mpe2-based env: the same episodes, one mp4 each
    recorded = enjoy([folder, "-n", "3", "--seed", "1", "--record", str(tmp_path / "videos")])
    assert [r["success"] for r in recorded] == [r["success"] for r in records]
    assert all(np.allclose(a["returns"], b["returns"], atol=1e-5) for a, b in zip(recorded, records))
    assert len(list((tmp_path / "videos").glob("episode-episode-*.mp4"))) == 3
    (tmp_path / "a_file").write_text("")
    assert cli(["enjoy", folder, "--record", str(tmp_path / "a_file" / "videos")]) == 2
    assert "not a writable folder" in capsys.readouterr().err
    assert cli(["enjoy", folder, "--record", str(tmp_path / "videos")]) == 2  # the videos there are kept
    assert "already holds episode videos" in capsys.readouterr().err
    assert len(list((tmp_path / "videos").glob("episode-episode-*.mp4"))) == 3
    assert cli(["enjoy", str(tmp_path / "nowhere")]) == 2
    assert "no such run folder" in capsys.readouterr().err
    (Path(folder) / "config.yml").write_text("env_id: os.system\n")
    assert cli(["enjoy", folder]) == 2
    assert "'env_id' must name a registered env" in capsys.readouterr().err


def test_save_freq_keeps_the_model_every_n_steps(tmp_path):
    folder = Path(run_train(tmp_path, "-n", "100", "--variant", "fast", "--save-freq", "50"))
    assert sorted(p.name for p in (folder / "models").glob("*.zip")) == ["step_50.zip"]  # (the last: model.zip)
    assert MADDPG.load(folder / "models" / "step_50.zip").num_timesteps == 50
    assert MADDPG.load(folder / "model.zip").num_timesteps == 100
    from stable_baselines3.common.monitor import load_results  # and the training episodes, as rl_zoo3 keeps them

    assert list(load_results(str(folder))["l"]) == [20] * 5


def test_tensorboard_folder_is_named_like_the_run_and_gets_every_evaluation(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    tb = tmp_path / "tb"
    folder = Path(run_train(tmp_path, "-n", "200", "--variant", "fast", "-tb", str(tb)))
    assert [p.name for p in tb.iterdir()] == [folder.name]
    events = EventAccumulator(str(tb / folder.name)).Reload()
    assert [e.step for e in events.Scalars("eval/success_rate")] == list(range(50, 201, 50))  # (--eval-freq 50)
    other = Path(run_train(tmp_path, "-n", "100", "--variant", "fast", "-tb", str(tb)))  # the next run, its own folder
    assert other.name != folder.name and sorted(p.name for p in tb.iterdir()) == sorted([folder.name, other.name])

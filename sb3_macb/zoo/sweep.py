"""
``sb3-macb sweep``: a grid of settings x seeds run as the trials of one Optuna study.

Any number of workers, on one machine or many, started with the same ``--storage`` and ``--study-name`` share the
grid:

- the first worker to create the study's marker (``NAME.grid``, an atomic create in the storage) puts every grid
  point in the study's queue of waiting trials; a waiting trial is claimed by exactly one worker, so each point
  runs once;
- workers send heartbeats; the trial of a worker that dies is failed by the next worker that looks at the study
  and put back in the queue (Optuna's ``RetryHeartbeatStaleTrialCallback``), where another worker picks it up;
  with ``--checkpoint-freq N`` it resumes from the dead worker's last checkpoint (a pack resumes whole) where it can
  reach it (the same machine or a shared file system), and otherwise starts again; every worker holds a lock on the
  folder it trains (``NAME/locks/trial_N.lock``, ``pack_N.lock``), so that the retry of a worker that is alive but was
  failed for a late heartbeat starts again in folders of its own instead of writing into the running one;
- every worker checks the study against the grid and queues what is missing (a worker killed while queueing the
  grid, a point whose trial failed); a point that failed ``--max-attempts`` times is given up;
- a worker leaves when nothing is waiting or running, writes ``results.csv`` (every point with its status: done,
  failed with its error, missing) and exits non-zero if any point is not done;
- with ``--pack K`` a worker claims up to K waiting points at once and trains them together in one process (one
  set of stacked tensors; each point is the run it would be alone), which pays the per-step fixed cost once. Only
  MACB's settings (``exploration.*``) and ``noise_std`` may vary in such a grid (network shapes must be equal).

Storage: a SQLite file by default (``sqlite:///LOGDIR/sweeps.db``); a PostgreSQL URL spreads the workers over
machines. Each trial records its success rate (mean over the last ``final_evals`` evaluations), the count-1
fraction of its MACB table, and its run folder; ``LOGDIR/NAME/results.csv`` lists the finished trials.

Config (YAML)::

    algo: maddpg
    env: sb3_macb/CommunicativeNavigation-v0
    n_timesteps: 800000
    variant: fast                       # optional, see zoo/hyperparams/maddpg.yml
    hyperparams: {batch_size: 100}      # optional, rl_zoo3 style, on top of the YAML entry
    grid:
      exploration.beta: [0.05, 0.2, 0.4, 0.8]
      exploration.k: [32, 64, 256, 512]
    seeds: [0, 1, 2]
"""

import argparse
import csv
import itertools
import os
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from copy import deepcopy
from typing import Any, TypeVar

import optuna
import yaml
from optuna.trial import TrialState

from sb3_macb.common import evaluations
from sb3_macb.common.private_apis import trial_id

T = TypeVar("T")

CONFIG_KEYS = {
    "algo", "env", "n_timesteps", "variant", "hyperparams", "grid", "seeds", "eval_freq", "eval_episodes",
    "conf_file", "final_evals",
}  # fmt: skip


def load_config(path: str) -> dict[str, Any]:
    """Read and check a sweep config (unknown keys and missing ones are errors that name them)."""
    config = _read_yaml_mapping(path, "sweep config")
    if not isinstance(config, dict):
        raise ValueError(f"{path}: a sweep config is a mapping of keys {sorted(CONFIG_KEYS)}")
    unknown = sorted(set(config) - CONFIG_KEYS)
    if unknown:
        raise ValueError(f"{path}: unknown sweep config key(s) {unknown}; known keys: {sorted(CONFIG_KEYS)}")
    missing = [key for key in ("env", "grid", "seeds") if key not in config]
    if missing:
        raise ValueError(f"{path}: missing sweep config key(s) {missing}")
    if config.get("algo", "maddpg") != "maddpg":
        raise ValueError(f"{path}: algo must be 'maddpg', got {config['algo']!r}")
    grid = config["grid"]
    if not isinstance(grid, dict) or not grid or not all(isinstance(v, list) and v for v in grid.values()):
        raise ValueError(f"{path}: grid maps parameter names to non-empty lists of values")
    if "seed" in grid:
        raise ValueError(f"{path}: give seeds under 'seeds', not in the grid")
    if not isinstance(config["seeds"], list) or not config["seeds"]:
        raise ValueError(f"{path}: seeds is a non-empty list of integers")
    conf_file = config.get("conf_file")
    if conf_file is not None:
        if not isinstance(conf_file, str) or not conf_file.endswith((".yml", ".yaml")):
            raise ValueError(f"{path}: conf_file must be the path of a .yml/.yaml hyperparameter file, got {conf_file!r}")
        _read_yaml_mapping(conf_file, "conf_file")
    from sb3_macb.zoo.experiment import MODEL_KEYS, ZOO_KEYS

    for name in grid:
        if name.split(".")[0] not in ZOO_KEYS | MODEL_KEYS:
            raise ValueError(f"{path}: grid parameter '{name}' is not a hyperparameter of MADDPG or rl_zoo3")
    return config


def _read_yaml_mapping(path: str, what: str) -> dict[str, Any]:
    """A YAML file holding a mapping; anything else is a ValueError naming ``path`` (not its contents)."""
    try:
        with open(path, "rb") as file:
            data = yaml.safe_load(file.read().decode("utf-8"))
    except OSError as exc:
        raise ValueError(f"cannot read the {what} {path}: {exc.strerror}") from None
    except (UnicodeDecodeError, yaml.YAMLError) as exc:
        raise ValueError(f"the {what} {path} is not valid YAML ({type(exc).__name__})") from None
    data = {} if data is None else data
    if not isinstance(data, dict):
        raise ValueError(f"the {what} {path} is not a YAML mapping (of keys to settings)")
    return data


def grid_points(config: dict[str, Any]) -> list[dict[str, Any]]:
    """Every combination of the grid's values and the seeds."""
    names = list(config["grid"])
    points = []
    for values in itertools.product(*(config["grid"][n] for n in names)):
        for seed in config["seeds"]:
            points.append({**dict(zip(names, values)), "seed": int(seed)})
    return points


def _with_retries(action: Callable[[], T], attempts: int = 10, deadline: float | None = None) -> T:
    """
    Run a storage action, retrying transient database errors.

    Workers that start together on a new database race to create its tables and studies; on SQLite a writer may
    also find the file locked by another. The losers retry after a short random pause. Optuna's own outcomes, such
    as ``DuplicatedStudyError``, are not retried.
    """
    import random

    from sqlalchemy.exc import SQLAlchemyError

    start = time.monotonic()
    for attempt in range(attempts):
        try:
            return action()
        except (SQLAlchemyError, optuna.exceptions.StorageInternalError):
            if attempt == attempts - 1 or (deadline is not None and time.monotonic() - start > deadline):
                raise
            time.sleep(0.2 + random.random())
    raise AssertionError("unreachable")


def _redacted(url: str) -> str:
    """The storage URL without its password."""
    import re

    return re.sub(r"://([^:/@]+):[^@]*@", r"://\1:***@", url)


def make_storage(
    url: str,
    heartbeat_interval: int,
    attempts: int = 10,
    connect_timeout: int = 10,
    deadline: float = 45.0,
    timeout: float = 30.0,
) -> optuna.storages.RDBStorage:
    """
    An RDB storage (SQLite or PostgreSQL URL) with heartbeats and retry of the trials of dead workers.

    On SQLite, a worker waits up to a minute for another's write lock (Python's default is 5 s, which a busy
    machine exceeds). On a network database every storage call must finish within ``timeout`` seconds: the server
    is asked for statement and idle-transaction timeouts, TCP keepalives and a TCP user timeout find a dead
    peer, and a call that still hangs (a server that accepts data but never answers, e.g. a stopped process) has
    its connections shut down and raises a :class:`ConnectionError` naming the server.

    :param url: ``sqlite:///...`` or ``postgresql://...``.
    :param heartbeat_interval: Seconds between heartbeats; a trial silent for 3 intervals is failed and retried.
    :param attempts: Tries at connecting (and creating the tables) before giving up.
    :param connect_timeout: Seconds a PostgreSQL connection attempt may take (a server that accepts the connection
        but never answers would otherwise hang the worker).
    :param deadline: Seconds after which connecting is given up with an error that names the server (with the
        last attempt's ``connect_timeout``, the error comes within a minute).
    :param timeout: Seconds a storage call on a network database may take before it is broken off.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        retry = optuna.storages.RetryHeartbeatStaleTrialCallback(max_retry=3)
    if url.startswith("sqlite"):
        engine_kwargs: dict[str, Any] | None = {"connect_args": {"timeout": 60}}
    elif url.startswith("postgresql"):
        ms = int(timeout * 1000)
        engine_kwargs = {
            "connect_args": {
                "connect_timeout": connect_timeout,
                "keepalives": 1, "keepalives_idle": 10, "keepalives_interval": 5, "keepalives_count": 3,
                "tcp_user_timeout": ms,
                "options": f"-c statement_timeout={ms} -c idle_in_transaction_session_timeout={2 * ms}",
            },
            "pool_pre_ping": True,
        }  # fmt: skip
    else:
        engine_kwargs = None
    try:
        storage = _with_retries(
            lambda: optuna.storages.RDBStorage(
                url, engine_kwargs=engine_kwargs, heartbeat_interval=heartbeat_interval,
                grace_period=3 * heartbeat_interval, heartbeat_stale_trial_callback=retry,
            ),
            attempts,
            deadline=deadline,
        )  # fmt: skip
        return storage if url.startswith("sqlite") else _guard_storage(storage, _redacted(url), timeout)
    except ImportError as exc:  # no driver for the URL's database: no use retrying
        hint = " (PostgreSQL: pip install 'sb3_macb[postgres]')" if url.startswith("postgresql") else ""
        raise ConnectionError(f"Cannot use the sweep storage {_redacted(url)}: {exc}{hint}") from None
    except Exception as exc:  # noqa: BLE001 (every way of failing to connect gets the same clear message)
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ConnectionError(
            f"Cannot use the sweep storage {_redacted(url)} (gave up after {deadline:.0f} s): {message}"
        ) from None


class StorageTimeout(ConnectionError):
    """A storage call on a network database did not finish in time (its connections were shut down)."""


def _guard_storage(storage: optuna.storages.RDBStorage, name: str, timeout: float) -> optuna.storages.RDBStorage:
    """
    ``storage`` with every public method bounded by ``timeout`` seconds: a call that takes longer has the
    storage's database connections shut down (the blocked read returns at once) and raises :class:`StorageTimeout`.
    The methods are replaced on the instance, so it stays an ``RDBStorage`` (heartbeats, Optuna's caching).
    """
    import functools
    import socket
    import threading

    from sqlalchemy import event

    connections: dict[int, Any] = {}
    lock = threading.Lock()

    def remember(dbapi_connection: Any, record: Any) -> None:
        with lock:
            connections[id(dbapi_connection)] = dbapi_connection

    def forget(dbapi_connection: Any, record: Any) -> None:
        with lock:
            connections.pop(id(dbapi_connection), None)

    event.listen(storage.engine, "connect", remember)
    event.listen(storage.engine, "close", forget)
    storage.engine.dispose()  # the connections made while creating the storage are replaced by tracked ones

    def shut_down(fired: threading.Event, done: threading.Event) -> None:
        fired.set()
        while not done.is_set():  # (until the call gives up: also the connections it makes meanwhile)
            with lock:
                live = list(connections.values())
            for connection in live:
                try:
                    duplicate = socket.socket(fileno=os.dup(connection.fileno()))
                    duplicate.shutdown(socket.SHUT_RDWR)  # acts on the shared socket: the blocked read ends
                    duplicate.close()
                except Exception:  # noqa: BLE001 (a connection already closed)
                    pass
            done.wait(0.5)

    def bounded(method: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(method)
        def call(*args: Any, **kwargs: Any) -> Any:
            fired, done = threading.Event(), threading.Event()
            timer = threading.Timer(timeout, shut_down, args=(fired, done))
            timer.daemon = True
            timer.start()
            try:
                return method(*args, **kwargs)
            except Exception:
                if fired.is_set():
                    raise StorageTimeout(f"the sweep storage {name} did not answer within {timeout:.0f} s "
                                         f"({method.__name__}); is the server running?") from None  # fmt: skip
                raise
            finally:
                done.set()
                timer.cancel()

        return call

    for attribute in dir(optuna.storages.RDBStorage):
        if not attribute.startswith("_") and callable(getattr(optuna.storages.RDBStorage, attribute)):
            setattr(storage, attribute, bounded(getattr(storage, attribute)))
    return storage


def point_key(point: dict[str, Any]) -> str:
    """A grid point's identity (its parameters and seed), as stored in its trials' ``point`` attribute."""
    import json

    return json.dumps(point, sort_keys=True, default=str)


def _enqueue_once(storage: optuna.storages.RDBStorage, study: optuna.Study, name: str, points: list[dict],
                  wait: float = 60.0) -> None:  # fmt: skip
    """
    The first worker (the one that creates the marker study ``NAME.grid``) queues every point; the others wait for
    it to finish. If it died while queueing (no ``n_points`` on the marker after ``wait`` seconds), the waiting
    worker goes on: :func:`repair_queue` queues what is missing.
    """
    marker_name = f"{name}.grid"
    try:
        marker = _with_retries(lambda: optuna.create_study(study_name=marker_name, storage=storage))
        first = True
    except optuna.exceptions.DuplicatedStudyError:
        first = False
    if first:
        for point in points:
            study.enqueue_trial(point, user_attrs={"grid_point": True, "point": point_key(point)})
        marker.set_user_attr("n_points", len(points))
        return
    deadline = time.monotonic() + wait
    while time.monotonic() < deadline:  # another worker is putting the grid in the queue
        marker = optuna.load_study(study_name=marker_name, storage=storage)
        if "n_points" in marker.user_attrs:
            break
        time.sleep(0.1)
    if marker.user_attrs.get("n_points") not in (None, len(points)):
        raise ValueError(f"Study '{name}' was started with another grid ({marker.user_attrs['n_points']} points)")


def point_states(study: optuna.Study, points: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """For each grid point: its trials' states, failures and the last error message."""
    states: dict[str, dict[str, Any]] = {
        point_key(p): {"point": p, "active": 0, "complete": [], "failed": 0, "error": ""} for p in points
    }
    for trial in study.get_trials(deepcopy=False):
        entry = states.get(trial.user_attrs.get("point", ""))
        if entry is None:
            continue
        if trial.state in (TrialState.WAITING, TrialState.RUNNING):
            entry["active"] += 1
        elif trial.state == TrialState.COMPLETE:
            entry["complete"].append(trial)
        elif trial.state == TrialState.FAIL:
            entry["failed"] += 1
            entry["error"] = trial.user_attrs.get("error", entry["error"]) or "the worker running it died"
    return states


def repair_queue(study: optuna.Study, points: list[dict[str, Any]], max_attempts: int) -> int:
    """
    Queue every grid point that has no finished, running or queued trial and has failed fewer than
    ``max_attempts`` times (a worker that died while queueing the grid, a point that failed). Returns how many.
    """
    queued = 0
    for key, entry in point_states(study, points).items():
        if not entry["active"] and not entry["complete"] and entry["failed"] < max_attempts:
            study.enqueue_trial(entry["point"], user_attrs={"grid_point": True, "point": key})
            queued += 1
    return queued


def run_trial(
    config: dict[str, Any],
    params: dict[str, Any],
    run_folder: str,
    callbacks: list[Any] | None = None,
    checkpoint_freq: int | None = None,
) -> tuple[float, float, str]:
    """
    Train one grid point (:func:`~sb3_macb.zoo.experiment.run_experiment`); return (success rate, count-1, folder).

    :param config: The sweep config.
    :param params: The point's parameters, with ``seed``.
    :param run_folder: The run's folder. With ``checkpoint_freq``, a folder that holds this point's checkpoint
        (a dead worker's) is resumed from it.
    :param callbacks: Callbacks run at every step (a worker's check of its storage).
    :param checkpoint_freq: Steps between checkpoints (None: none).
    """
    from sb3_macb.zoo.experiment import make_run, run_experiment

    variants = [v for v in str(config.get("variant") or "").split(",") if v]
    overrides = {**config.get("hyperparams", {}), **{k: v for k, v in params.items() if k != "seed"}}
    run, n_timesteps = make_run(config["env"], int(params["seed"]), run_folder, variants, overrides,
                                config.get("conf_file"), config.get("n_timesteps") or None)  # fmt: skip
    run_experiment(
        config["env"], run.hyperparams, run.seed, n_timesteps, run_folder, variants,
        eval_freq=int(config.get("eval_freq", 20)), eval_episodes=int(config.get("eval_episodes", 10)), callbacks=callbacks,
        checkpoint_freq=checkpoint_freq, resume=checkpoint_freq is not None,
    )  # fmt: skip
    return _trial_result(config, run_folder)


def _trial_result(config: dict[str, Any], run_folder: str) -> tuple[float, float, str]:
    """(success rate over the last ``final_evals`` evaluations, last count-1 fraction, folder) of a finished run."""
    run = evaluations.load(run_folder)
    n_final = int(config.get("final_evals", 10))
    success_rate = evaluations.final_level(run, window=n_final) if evaluations.SUCCESSES in run else 0.0
    count1 = float(run[evaluations.COUNT1_FRACTION][-1]) if evaluations.COUNT1_FRACTION in run else float("nan")
    return success_rate, count1, run_folder


def _check_packable(config: dict[str, Any]) -> None:
    from sb3_macb.zoo.experiment import PACKABLE

    bad = [name for name in config["grid"] if name.split(".")[0] not in PACKABLE]  # (the runner's own rule)
    if bad:
        raise ValueError(
            f"--pack trains several grid points in one process, which needs equal network shapes and training settings: "
            f"only MACB's settings (exploration.*) and noise_std may vary in the grid, not {bad}. Run without --pack."
        )


def run_pack(config: dict[str, Any], points: list[tuple[str, dict[str, Any]]], log_folder: str,
             callbacks: list[Any] | None = None, pack_name: str | None = None,
             checkpoint_freq: int | None = None) -> list[tuple[float, float, str] | Exception]:  # fmt: skip
    """
    Train several grid points as one pack (:mod:`sb3_macb.zoo.experiment`); each is the run it would be alone. A point
    whose settings are refused (checked alone first) fails alone: the others of the pack run without it.

    :param config: The sweep config.
    :param points: (run folder name, parameters with ``seed``) of each point.
    :param log_folder: The sweep's folder, which holds the runs' folders and the pack's.
    :param callbacks: Callbacks run at every step (a worker's check of its storage).
    :param pack_name: The pack's folder (its ``experiment.json`` and checkpoints) in ``log_folder``; by default
        ``pack_N`` for the first run ``trial_N``. With ``checkpoint_freq``, a pack folder that holds this pack's
        checkpoint (a dead worker's) is resumed from it.
    :param checkpoint_freq: Steps per run between checkpoints (None: none).
    :return: For each point, (success rate, count-1 fraction, run folder), or the error that refused it.
    """
    from sb3_macb.zoo.experiment import Experiment, ExperimentConfig, make_run, run_or_resume

    variants = [v for v in str(config.get("variant") or "").split(",") if v]
    eval_freq, eval_episodes = int(config.get("eval_freq", 20)), int(config.get("eval_episodes", 10))
    env_kwargs = dict(config.get("env_kwargs") or {})
    outcomes: list[Any] = []
    for name, params in points:
        overrides = {**config.get("hyperparams", {}), **{k: v for k, v in params.items() if k != "seed"}}
        try:
            folder = os.path.join(log_folder, name)
            run, n_timesteps = make_run(config["env"], int(params["seed"]), folder, variants, overrides,
                                        config.get("conf_file"), config.get("n_timesteps") or None)  # fmt: skip
            ExperimentConfig(config["env"], [deepcopy(run)], n_timesteps=n_timesteps, eval_freq=eval_freq,
                             eval_episodes=eval_episodes, env_kwargs=env_kwargs)  # fmt: skip
            outcomes.append((run, n_timesteps))
        except Exception as exc:  # noqa: BLE001 (this point's own error, reported for it alone)
            outcomes.append(exc)
    runs = [o[0] for o in outcomes if not isinstance(o, Exception)]
    if runs:
        n_timesteps = next(o[1] for o in outcomes if not isinstance(o, Exception))
        experiment_config = ExperimentConfig(config["env"], runs, n_timesteps=n_timesteps, eval_freq=eval_freq,
                                             eval_episodes=eval_episodes, env_kwargs=env_kwargs)  # fmt: skip
        pack_name = pack_name or "pack_" + points[0][0].removeprefix("trial_")
        experiment = Experiment(experiment_config, os.path.join(log_folder, pack_name), checkpoint_freq=checkpoint_freq,
                                verbose=0, callbacks=callbacks)  # fmt: skip
        run_or_resume(experiment)  # (a new pack's folder is new: it starts)
    return [o if isinstance(o, Exception) else _trial_result(config, o[0].folder) for o in outcomes]


class _Heartbeats:
    """
    Heartbeats for claimed trials. When the storage stops answering, :meth:`watchdog`'s callback raises the storage's
    error at the training's next step, so that the worker reports the lost server at once instead of at the end of
    its trial.
    """

    def __init__(self, storage: optuna.storages.RDBStorage, trial_ids: list[int], interval: int):
        import threading

        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat, args=(storage, trial_ids, interval), daemon=True)
        self.error: Exception | None = None

    def _beat(self, storage: optuna.storages.RDBStorage, trial_ids: list[int], interval: int) -> None:
        while True:
            try:
                for trial_id in trial_ids:
                    storage.record_heartbeat(trial_id)
            except Exception as exc:  # noqa: BLE001 (the storage is gone: stop the trial and say so)
                self.error = (
                    exc
                    if isinstance(exc, ConnectionError)
                    else ConnectionError(
                        "the sweep storage failed while the trial ran: "
                        f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
                    )
                )
                return
            if self._stop.wait(interval):
                return

    def __enter__(self) -> "_Heartbeats":
        self._thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self._stop.set()
        self._thread.join()

    def watchdog(self) -> Any:
        """An SB3 callback that raises the heartbeats' storage error (a ConnectionError) at the next step."""
        from stable_baselines3.common.callbacks import BaseCallback

        beats = self

        class _StorageWatchdog(BaseCallback):
            def _on_step(self) -> bool:
                if beats.error is not None:
                    raise beats.error
                return True

        return _StorageWatchdog()


def write_results(study: optuna.Study, path: str, points: list[dict[str, Any]] | None = None) -> int:
    """
    The grid as CSV: parameters, success rate, count-1 fraction, run folder and status (``done``, ``failed`` with the
    error, ``missing``) of every point. Returns 0 if every point is done, else 1 (and says which on stderr).
    """
    import json

    trials = [t for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)) if t.user_attrs.get("grid_point")]
    states = point_states(study, points) if points is not None else {}
    names = sorted({name for t in trials for name in t.params} | {n for p in points or [] for n in p})
    rows, problems, seen = [], [], set()
    for t in sorted(trials, key=lambda t: t.number):
        key = t.user_attrs.get("point") or point_key(t.params)
        if key in seen:
            continue  # (a point run twice, after a repair race: the first result counts)
        seen.add(key)
        rows.append([t.number, *[t.params.get(n) for n in names], t.user_attrs.get("success_rate"),
                     t.user_attrs.get("count1_fraction"), t.user_attrs.get("run_folder"), "done", ""])  # fmt: skip
    for key, entry in states.items():
        if key in seen or entry["complete"]:
            continue
        status = "failed" if entry["failed"] else "missing"
        problems.append(f"{status}: {json.loads(key)} {entry['error']}".strip())
        rows.append(["", *[entry["point"].get(n) for n in names], "", "", "", status, entry["error"]])
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    with open(path, "w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(["trial", *names, "success_rate", "count1_fraction", "run_folder", "status", "error"])
        writer.writerows(rows)
    for line in problems:
        print(f"sb3-macb sweep: {line}", file=sys.stderr)
    return 1 if problems else 0


def work(
    config_path: str,
    storage_url: str,
    study_name: str,
    log_folder: str,
    heartbeat: int = 30,
    poll: float = 5.0,
    pack: int = 0,
    max_attempts: int = 3,
    enqueue_wait: float = 60.0,
    num_threads: int = 1,
    storage_timeout: float = 30.0,
    checkpoint_freq: int | None = None,
) -> int:
    """
    Join the sweep as a worker and run grid points until none is waiting or running.

    :param config_path: The sweep config (YAML).
    :param storage_url: Optuna RDB storage URL (``sqlite:///...`` or ``postgresql://...``).
    :param study_name: Study shared by all workers of this sweep.
    :param log_folder: Where the trials' run folders go (``LOG/NAME/trial_N``).
    :param heartbeat: Heartbeat interval in seconds; a trial silent for 3 intervals is retried elsewhere.
    :param poll: Seconds between looks at the study while other workers' trials run.
    :param pack: Claim up to this many waiting grid points at once and train them together in one process;
        0: one point at a time. Either way through :mod:`sb3_macb.zoo.experiment`.
    :param max_attempts: A point that fails this many times is given up and reported.
    :param enqueue_wait: Seconds to wait for the worker that queues the grid before repairing the queue.
    :param num_threads: Torch threads of this worker (one per worker, as many workers as cores, is fastest).
    :param storage_timeout: Seconds a call to a network storage may take (see :func:`make_storage`).
    :param checkpoint_freq: Steps per run between checkpoints (None: none). A point whose worker died is then
        resumed from its last checkpoint by the worker that takes up its retry, when that worker reaches the same
        log folder (the same machine, or a shared file system); otherwise it starts again from step 0.
    :return: 0 when every grid point finished; 1 when some failed ``max_attempts`` times or are missing
        (``results.csv`` lists them with their status and error).
    """
    import torch as th

    th.set_num_threads(num_threads)
    config = load_config(config_path)
    if pack > 0:
        _check_packable(config)
    points = grid_points(config)
    storage = make_storage(storage_url, heartbeat, timeout=storage_timeout)
    study = _with_retries(
        lambda: optuna.create_study(study_name=study_name, storage=storage, direction="maximize", load_if_exists=True)
    )
    _enqueue_once(storage, study, study_name, points, wait=enqueue_wait)

    while True:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            optuna.storages.fail_stale_trials(study)
        repair_queue(study, points, max_attempts)
        trials = study.get_trials(deepcopy=False, states=(TrialState.WAITING, TrialState.RUNNING))
        waiting = sum(t.state == TrialState.WAITING for t in trials)
        if waiting:
            size = min(pack, waiting) if pack > 0 else 1
            try:  # a failing point is failed (then retried, then reported); the worker goes on
                if not _work_on_pack(study, storage, config, size, os.path.join(log_folder, study_name), heartbeat,
                                     alone=pack == 0, checkpoint_freq=checkpoint_freq):  # fmt: skip
                    time.sleep(poll)  # (waiting for the rest of a dead worker's pack to be queued)
            except ConnectionError:
                raise
            except Exception as exc:  # noqa: BLE001
                print(
                    f"sb3-macb sweep: {'a pack' if pack else 'a trial'} failed: {type(exc).__name__}: {exc}", file=sys.stderr
                )
        elif trials:
            time.sleep(poll)
        else:
            break
    return write_results(study, os.path.join(log_folder, study_name, "results.csv"), points)


def _work_on_pack(
    study: optuna.Study,
    storage: optuna.storages.RDBStorage,
    config: dict[str, Any],
    size: int,
    folder: str,
    heartbeat: int,
    alone: bool = False,
    checkpoint_freq: int | None = None,
) -> bool:
    """
    Claim up to ``size`` waiting grid points, train them as one pack (``alone``: one point, in its own trial folder,
    as :func:`run_trial` runs it) and report each. With ``checkpoint_freq``, the points of a dead worker's
    checkpointed pack are claimed together first and resumed (see :func:`_claim_pack_to_resume`), and a point run
    alone resumes its dead attempt's run folder. Returns whether it claimed any point.
    """
    claimed: list[tuple[optuna.Trial, dict[str, Any]]] = []
    pack_name = None
    if checkpoint_freq is not None and not alone:
        pack_name, trials, wait = _claim_pack_to_resume(study, storage, folder)
        if wait:
            return False
        claimed = [(t, _grid_params(t, config)) for t in trials]
    for _ in range(size - len(claimed) if not claimed else 0):
        with warnings.catch_warnings():  # (heartbeats are sent by _Heartbeats below, not by study.optimize)
            warnings.simplefilter("ignore", UserWarning)
            trial = study.ask()  # takes a waiting (queued) trial when there is one
        # a heartbeat at once: Optuna never finds a RUNNING trial stale before its first heartbeat, so a worker
        # killed before that would leave its point running for ever
        storage.record_heartbeat(trial_id(trial, storage, study.study_name))
        if not trial.user_attrs.get("grid_point"):
            study.tell(trial, state=TrialState.PRUNED)  # another worker took the last queued point
            break
        claimed.append((trial, _grid_params(trial, config)))
    if not claimed:
        return False
    if pack_name is not None:  # a dead worker's pack, resumed in its own folders
        names = [str(trial.user_attrs["run_name"]) for trial, _ in claimed]
    else:
        names = [_run_name(trial, resume=checkpoint_freq is not None and alone) for trial, _ in claimed]
    if not alone:
        pack_name = pack_name or "pack_" + names[0].removeprefix("trial_")
    # the folder a retry would continue may still be trained by a worker that is alive but was failed for a late
    # heartbeat: every worker holds its experiment folder's lock while it trains, and a retry that finds it held starts
    # again in new folders
    folders = ExitStack()
    if not folders.enter_context(_folder_lock(os.path.join(folder, "locks", f"{pack_name or names[0]}.lock"))):
        names = [f"trial_{trial.number}" for trial, _ in claimed]
        pack_name = None if alone else "pack_" + names[0].removeprefix("trial_")
        folders.enter_context(_folder_lock(os.path.join(folder, "locks", f"{pack_name or names[0]}.lock")))
    try:
        with folders, _Heartbeats(storage, [trial_id(t, storage, study.study_name) for t, _ in claimed], heartbeat) as beats:
            for (trial, _), name in zip(claimed, names):  # (inherited by the trial's retry if this worker dies)
                trial.set_user_attr("run_name", name)
                trial.set_user_attr("pack_name", pack_name or "")
            if alone:
                [(_, params)] = claimed
                results: list[Any] = [
                    run_trial(config, params, os.path.join(folder, names[0]), [beats.watchdog()], checkpoint_freq)
                ]
            else:
                results = run_pack(config, [(n, p) for n, (_, p) in zip(names, claimed)], folder, [beats.watchdog()],
                                   pack_name=pack_name, checkpoint_freq=checkpoint_freq)  # fmt: skip
    except ConnectionError:
        raise
    except Exception as exc:
        for trial, _ in claimed:
            trial.set_user_attr("error", f"{type(exc).__name__}: {exc}"[:500])
            study.tell(trial, state=TrialState.FAIL)
        raise
    for (trial, _), result in zip(claimed, results):
        if isinstance(result, Exception):  # refused at setup: this point alone fails (and is retried, then reported)
            trial.set_user_attr("error", f"{type(result).__name__}: {result}"[:500])
            study.tell(trial, state=TrialState.FAIL)
            continue
        success_rate, count1, run_folder = result
        try:
            trial.set_user_attr("success_rate", success_rate)
            trial.set_user_attr("count1_fraction", count1)
            trial.set_user_attr("run_folder", run_folder)
            study.tell(trial, success_rate)
        except (ValueError, RuntimeError) as exc:
            if not _finished_elsewhere(exc):
                raise
            print(f"sb3-macb sweep: trial {trial.number}: {_LATE}", file=sys.stderr)
    return True


def _grid_params(trial: optuna.Trial, config: dict[str, Any]) -> dict[str, Any]:
    """A claimed trial's grid point: its parameters and ``seed``."""
    params = {name: trial.suggest_categorical(name, values) for name, values in config["grid"].items()}
    params["seed"] = trial.suggest_categorical("seed", [int(s) for s in config["seeds"]])
    return params


def _inherited_name(trial: Any, key: str, prefix: str) -> str | None:
    """
    The folder name ``key`` that a trial inherited from its dead attempt (Optuna's retry copies the user attributes),
    when it is one this sweep makes (``trial_N`` / ``pack_N``): names from the storage never reach outside the sweep's
    folder.
    """
    name = trial.user_attrs.get(key)
    if isinstance(name, str) and name.startswith(prefix) and name.removeprefix(prefix).isdigit():
        return name
    return None


def _run_name(trial: optuna.Trial, resume: bool) -> str:
    """The run folder of a claimed trial: its dead attempt's when ``resume`` (and it ran alone), else ``trial_N``."""
    if resume and not trial.user_attrs.get("pack_name"):
        inherited = _inherited_name(trial, "run_name", "trial_")
        if inherited is not None:
            return inherited
    return f"trial_{trial.number}"


def _claim_pack_to_resume(
    study: optuna.Study, storage: optuna.storages.RDBStorage, folder: str
) -> tuple[str | None, list[optuna.Trial], bool]:
    """
    Claim together the waiting retries of a dead worker's pack whose checkpoint this worker can reach (its pack folder
    in ``folder``), when all its runs are waiting: (the pack's folder name, the claimed trials, False). Another worker
    may claim one of them first; the ones claimed then run as a new pack (name None). The trials of a pack go stale
    one by one (their heartbeats were sent one after another), so while some of a pack's runs are waiting and the
    others still running, nothing is claimed and the third value is True: wait, rather than let the queue hand out
    the waiting ones alone. ``(None, [], False)`` when there is no such pack.
    """
    from sb3_macb.zoo.experiment import ExperimentError, read_experiment_file

    groups: dict[str, list[Any]] = {}
    running: dict[str, set[str]] = {}
    for frozen in study.get_trials(deepcopy=False, states=(TrialState.WAITING, TrialState.RUNNING)):
        pack, run = _inherited_name(frozen, "pack_name", "pack_"), _inherited_name(frozen, "run_name", "trial_")
        if pack is not None and run is not None:
            if frozen.state == TrialState.WAITING:
                groups.setdefault(pack, []).append(frozen)
            else:
                running.setdefault(pack, set()).add(run)
    wait = False
    for pack, members in groups.items():
        try:
            saved = read_experiment_file(os.path.join(folder, pack, "experiment.json"))
        except ExperimentError:  # not reachable from here (another machine's disk), or stopped before it was written
            continue
        runs = {os.path.basename(str(r.get("folder", ""))) for r in saved["config"]["runs"] if isinstance(r, dict)}
        waiting = {str(m.user_attrs["run_name"]) for m in members}
        if waiting != runs:
            # wait for the others while they are still running in a dead worker (they will be failed and queued
            # too); gone, or running in a live worker (its lock held), they leave the waiting ones to the queue
            if waiting < runs and runs - waiting <= running.get(pack, set()):
                with _folder_lock(os.path.join(folder, "locks", f"{pack}.lock")) as free:
                    wait = wait or free
            continue
        claimed = [trial for trial in (_claim(study, storage, m) for m in members) if trial is not None]
        if claimed:
            return (pack if len(claimed) == len(members) else None), claimed, False
    return None, [], wait


@contextmanager
def _folder_lock(path: str) -> Iterator[bool]:
    """
    Hold an exclusive advisory lock (``flock``) on the lock file ``path`` while no other process holds it; yields
    whether it does. Where ``fcntl`` is missing (Windows) it yields True without a lock.

    :param path: The lock file (created if missing, never deleted).
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover (not on POSIX)
        yield True
        return
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    descriptor = os.open(path, os.O_CREAT | os.O_RDWR, 0o644)
    try:
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            yield False
            return
        yield True
    finally:
        os.close(descriptor)  # (releases the lock)


def _claim(study: optuna.Study, storage: optuna.storages.RDBStorage, frozen: Any) -> optuna.Trial | None:
    """Claim one given waiting trial, as :meth:`optuna.Study.ask` claims the oldest; None when another worker did."""
    storage_id = trial_id(frozen, storage, study.study_name)
    try:
        if not storage.set_trial_state_values(storage_id, state=TrialState.RUNNING):
            return None
    except optuna.exceptions.UpdateFinishedTrialError:
        return None
    storage.record_heartbeat(storage_id)  # (as for a trial that study.ask claims: see _work_on_pack)
    return optuna.Trial(study, storage_id)


_LATE = (
    "a trial was failed by another worker while it ran (its heartbeat came late, e.g. on an overloaded machine); "
    "its result is dropped and its grid point queued again"
)


def _finished_elsewhere(exc: Exception) -> bool:
    """Whether ``exc`` is Optuna refusing to report a trial that another worker has already finished (failed)."""
    return isinstance(exc, optuna.exceptions.UpdateFinishedTrialError) or str(exc).startswith("Cannot tell a")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="sb3-macb sweep", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--config", required=True, help="sweep config (YAML)")
    parser.add_argument("--storage", default=None, help="Optuna storage URL (default: sqlite:///LOGDIR/sweeps.db)")
    parser.add_argument("--study-name", required=True)
    parser.add_argument("-f", "--log-folder", default="logs/sweeps")
    parser.add_argument("--heartbeat", type=int, default=30, help="seconds between a worker's heartbeats")
    parser.add_argument("--max-attempts", type=int, default=3, help="tries of a failing point before it is reported")
    parser.add_argument("--num-threads", type=int, default=1, help="torch threads of this worker")
    parser.add_argument(
        "--storage-timeout",
        type=float,
        default=30.0,
        help="seconds a call to a network storage (PostgreSQL) may take before the worker reports it",
    )
    parser.add_argument("--checkpoint-freq", type=int, default=None, metavar="N",
                        help="steps per run between checkpoints; the retry of a point whose worker died resumes from its "
                        "last one (on a machine that reaches the same log folder)")  # fmt: skip
    parser.add_argument("--pack", type=int, default=0, metavar="K",
                        help="claim up to K queued grid points at once and train them together in one process")  # fmt: skip
    args = parser.parse_args(argv)
    if args.pack < 0:
        parser.error("--pack must be >= 0")
    if args.checkpoint_freq is not None and args.checkpoint_freq < 1:
        parser.error("--checkpoint-freq must be >= 1 step")
    if not args.storage_timeout > 0 or args.heartbeat < 1 or args.max_attempts < 1 or args.num_threads < 1:
        parser.error("--storage-timeout must be > 0 and --heartbeat, --max-attempts, --num-threads >= 1")
    os.makedirs(args.log_folder, exist_ok=True)
    storage = args.storage or f"sqlite:///{os.path.abspath(os.path.join(args.log_folder, 'sweeps.db'))}"
    from sqlalchemy.exc import SQLAlchemyError

    try:
        return work(
            args.config,
            storage,
            args.study_name,
            args.log_folder,
            heartbeat=args.heartbeat,
            pack=args.pack,
            max_attempts=args.max_attempts,
            num_threads=args.num_threads,
            storage_timeout=args.storage_timeout,
            checkpoint_freq=args.checkpoint_freq,
        )
    except (SQLAlchemyError, optuna.exceptions.StorageInternalError) as exc:  # the server went away mid-sweep
        message = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ConnectionError(f"the sweep storage {_redacted(storage)} failed: {message}") from None

"""Evaluation as the paper does it (success rate after every training episode), and early stopping on success."""

import json
import os
import time
import warnings
from contextlib import suppress
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, EvalCallback
from stable_baselines3.common.logger import HumanOutputFormat
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import VecEnv, VecMonitor, is_vecenv_wrapped, sync_envs_normalization

from sb3_macb.common import evaluations
from sb3_macb.common.atomic import AtomicWriteError
from sb3_macb.common.private_apis import set_next_reset_seeds


class _SuccessRateStop(BaseCallback):
    """Base of the early-stopping rules: reads the success rate of the evaluation that just ran."""

    parent: EvalCallback

    def __init__(self, min_evals: int, verbose: int):
        super().__init__(verbose=verbose)
        self.min_evals = min_evals
        self.n_evals = 0

    def _should_stop(self, success_rate: float) -> bool:
        raise NotImplementedError

    def _on_step(self) -> bool:
        if not isinstance(self.parent, EvalCallback):
            raise TypeError(
                f"{type(self).__name__} must be used as callback_after_eval of an EvalCallback (e.g. MultiAgentEvalCallback)"
            )
        self.n_evals += 1
        buffer = self.parent._is_success_buffer  # filled by the evaluation from the episodes' info["is_success"]
        return not buffer or not self._should_stop(float(np.mean(buffer)))


class StopTrainingOnSuccessRate(_SuccessRateStop):
    """
    Stop training once the evaluation success rate reaches a threshold.

    Use it as ``callback_after_eval`` of SB3's ``EvalCallback`` or of :class:`MultiAgentEvalCallback` (the env must
    report ``info["is_success"]`` at episode ends).

    :param threshold: Success rate (0 to 1) at which to stop.
    :param min_evals: Do not stop before this many evaluations.
    :param verbose: Verbosity level: 0 no output, 1 a message when stopping.
    """

    def __init__(self, threshold: float, min_evals: int = 1, verbose: int = 0):
        super().__init__(min_evals=min_evals, verbose=verbose)
        if not 0.0 <= threshold <= 1.0:
            raise ValueError(f"threshold is a success rate in [0, 1], got {threshold}")
        self.threshold = threshold

    def _should_stop(self, success_rate: float) -> bool:
        stop = self.n_evals >= self.min_evals and success_rate >= self.threshold
        if stop and self.verbose >= 1:
            print(f"Stopping training: success rate {success_rate:.2f} >= {self.threshold} after {self.n_evals} evaluations")
        return stop


class StopTrainingOnNoSuccessImprovement(_SuccessRateStop):
    """
    Stop training when the evaluation success rate has not improved for ``max_no_improvement_evals`` evaluations.

    Use it as ``callback_after_eval`` of SB3's ``EvalCallback`` or of :class:`MultiAgentEvalCallback`.

    :param max_no_improvement_evals: Patience, in evaluations without a new best success rate.
    :param min_evals: Evaluations before the patience count starts.
    :param verbose: Verbosity level: 0 no output, 1 a message when stopping.
    """

    def __init__(self, max_no_improvement_evals: int, min_evals: int = 0, verbose: int = 0):
        super().__init__(min_evals=min_evals, verbose=verbose)
        if max_no_improvement_evals < 1:
            raise ValueError(f"max_no_improvement_evals must be >= 1, got {max_no_improvement_evals}")
        self.max_no_improvement_evals = max_no_improvement_evals
        self.best_success_rate = -np.inf
        self.no_improvement_evals = 0

    def _should_stop(self, success_rate: float) -> bool:
        if success_rate > self.best_success_rate:
            self.best_success_rate = success_rate
            self.no_improvement_evals = 0
        elif self.n_evals > self.min_evals:
            self.no_improvement_evals += 1
        stop = self.no_improvement_evals >= self.max_no_improvement_evals
        if stop and self.verbose >= 1:
            print(f"Stopping training: no success rate improvement in {self.no_improvement_evals} evaluations")
        return stop


def _counters(callback: BaseCallback) -> dict[str, Any]:
    """A callback's own counters (numbers and booleans set in its ``__init__`` or later), for a checkpoint."""
    return {k: v for k, v in vars(callback).items() if isinstance(v, (bool, int, float, np.number)) and not k.startswith("_")}


def make_eval_vec_env(
    env_id: str, n_eval_episodes: int, seeds: list[int | None], env_kwargs: dict[str, Any] | None = None
) -> VecEnv:
    """
    The evaluation env of one run or of a pack: ``n_eval_episodes`` envs per run (one evaluation = one batch of
    episodes), run ``k``'s ``i``-th env seeded ``seeds[k] + i`` (as SB3's ``make_vec_env(seed=...)`` seeds them).
    The paper's tasks are vectorized (:class:`~sb3_macb.envs.vec_tasks.TaskVecEnv`).

    :param env_id: A registered env id.
    :param n_eval_episodes: Episodes per evaluation and run.
    :param seeds: One seed per run (None: unseeded).
    :param env_kwargs: Keyword arguments for the env.
    """
    import gymnasium as gym

    from sb3_macb.envs.vec_tasks import make_task_vec_env

    if not isinstance(env_id, str) or ":" in env_id or env_id not in gym.registry:
        # (gymnasium imports the module of a "module:Env" id: only ids already registered are taken)
        raise ValueError(f"eval_env {env_id!r} is not a registered gymnasium env id")
    env = make_task_vec_env(env_id, n_eval_episodes * len(seeds), env_kwargs)
    set_next_reset_seeds(env.unwrapped, [None if seed is None else seed + i for seed in seeds for i in range(n_eval_episodes)])
    return env


class MultiAgentEvalCallback(EvalCallback):
    """
    SB3's ``EvalCallback`` for multi-agent runs, as the paper evaluates: every ``eval_freq`` steps (20 = one
    training episode), ``n_eval_episodes`` noise-free episodes, run as one batch on a vectorized eval env.

    Each evaluation records the success rate, the team return, every agent's return, the collisions and, with
    MACB, the number of codes and the count-1 fraction. They are logged through SB3's logger (``eval/...``,
    ``exploration/...``) and saved in SB3's ``evaluations.npz`` format (``timesteps``, ``results``, ``ep_lengths``,
    ``successes``) plus ``final_successes`` (the success condition holds at the episode's last step),
    ``episodes``, ``agent_returns``, ``collisions``, ``num_codes``, ``count1_fraction`` and ``training_collisions``
    (accumulated collisions during training so far). The file is replaced atomically.
    The best model is kept by success rate (ties: mean return). Collisions during training are summed and
    logged as ``rollout/collisions_total``.

    For a pack (``MADDPG(n_runs=K)``) the eval env holds ``n_eval_episodes`` envs per run (run ``k``'s envs one
    after another, see :func:`make_eval_vec_env`); every run gets its own records and its own file
    (``run_log_paths[k]/evaluations.npz``); the logged values are means over the runs.

    :param eval_env: The evaluation env: a VecEnv, a gymnasium env, or a registered env id (a DummyVecEnv of
        ``n_eval_episodes`` copies per run is built, so that an evaluation is one batch of episodes).
    :param n_eval_episodes: Episodes per evaluation (and run).
    :param eval_freq: Evaluate every ``eval_freq`` calls (environment steps per env).
    :param log_path: Folder for ``evaluations.npz`` (None: not saved).
    :param best_model_save_path: Folder for ``best_model.zip`` (None: not saved; not available for packs).
    :param save_freq: Write ``evaluations.npz`` every this many evaluations, or every tenth of the evaluations so
        far where that is more, and at the end of training. A write costs time in proportion to the evaluations held
        (SB3 rewrites the file at every evaluation: quadratic in the run's length); growing the interval with the
        records keeps the total cost of writing in proportion to the run's length.
    :param deterministic: Evaluate the deterministic policy (no action noise).
    :param stop_success_rate: Stop training once the success rate reaches this value (None: never).
    :param stop_patience: Stop training after this many evaluations without a new best success rate (None: never).
    :param min_evals: Evaluations before either stopping rule applies.
    :param callback_after_eval: Another callback to run after every evaluation (not for packs).
    :param callback_on_new_best: A callback to run when a new best model is found.
    :param env_kwargs: Keyword arguments for the env when ``eval_env`` is an env id.
    :param seed: Seed of the eval env when it is built from an env id (for a pack: the model's run seeds).
    :param dump_logs: Dump the logger (print the table of values) after evaluations, as SB3 does after each.
    :param verbose: Verbosity level: 1 prints a one-line summary with each dump, 0 nothing.
    :param warn: Warn (once) when the eval env is not wrapped with a Monitor.
    :param run_log_paths: For a pack: one folder per run for its ``evaluations.npz`` (instead of ``log_path``).
    :param log_freq: Dump the logger and print the summary every this many evaluations (1: after each, as SB3).
        The paper's protocol evaluates 40,000 times: a table each time is unreadable. The logger's files
        (TensorBoard, CSV, JSON) get every evaluation's values at its step, whatever ``log_freq`` and ``dump_logs``.
    :param monitor: Also write each run's training episodes (return, length, wall-clock seconds since the run
        started) to ``monitor.csv`` beside its ``evaluations.npz``, in SB3's Monitor format (``load_results`` and
        rl_zoo3's plots read it). A run that continues from a checkpoint (:meth:`set_state`) first cuts the file back
        to what it held at that checkpoint, so it ends as an uninterrupted run's would (the times aside).
    """

    def __init__(
        self,
        eval_env: gym.Env | VecEnv | str,
        n_eval_episodes: int = 10,
        eval_freq: int = 20,
        log_path: str | None = None,
        best_model_save_path: str | None = None,
        save_freq: int = 100,
        deterministic: bool = True,
        stop_success_rate: float | None = None,
        stop_patience: int | None = None,
        min_evals: int = 1,
        callback_after_eval: BaseCallback | None = None,
        callback_on_new_best: BaseCallback | None = None,
        env_kwargs: dict[str, Any] | None = None,
        seed: int | None = None,
        dump_logs: bool = True,
        verbose: int = 1,
        warn: bool = True,
        run_log_paths: list[str] | None = None,
        log_freq: int = 1,
        monitor: bool = False,
    ):
        if log_freq < 1:
            raise ValueError(f"log_freq must be >= 1, got {log_freq}")
        self.log_freq = log_freq
        self.monitor = monitor
        self._monitor_start: float | None = None  # wall-clock start of the runs (kept across a resume)
        self._monitor_sizes: list[int] | None = None  # each monitor.csv's size at the checkpoint continued from
        self._monitor_ready = False  # files started (or cut back) by the first learn() of this process
        self._env_id = eval_env if isinstance(eval_env, str) else None
        self._env_kwargs = env_kwargs
        if isinstance(eval_env, str):
            eval_env = make_eval_vec_env(eval_env, n_eval_episodes, [seed], env_kwargs)
        after_eval = [c for c in [callback_after_eval] if c is not None]
        if stop_success_rate is not None:
            after_eval.append(StopTrainingOnSuccessRate(stop_success_rate, min_evals=min_evals, verbose=verbose))
        if stop_patience is not None:
            after_eval.append(StopTrainingOnNoSuccessImprovement(stop_patience, min_evals=min_evals, verbose=verbose))
        combined = after_eval[0] if len(after_eval) == 1 else (CallbackList(after_eval) if after_eval else None)
        super().__init__(
            eval_env,
            callback_on_new_best=callback_on_new_best,
            callback_after_eval=combined,
            n_eval_episodes=n_eval_episodes,
            eval_freq=eval_freq,
            log_path=log_path,
            best_model_save_path=best_model_save_path,
            deterministic=deterministic,
            verbose=verbose,
            warn=warn,
        )
        if save_freq < 1:
            raise ValueError(f"save_freq must be >= 1, got {save_freq}")
        self.save_freq = save_freq
        self._monitor_checked = False
        self._saved_evaluations = 0  # evaluations held at the last write of the files
        self.dump_logs = dump_logs
        self.run_log_paths = run_log_paths
        self.best_success_rate = -np.inf
        self.last_success_rate: float | None = None
        self.n_runs = 1
        self.records: list[dict[str, list]] = []
        self.run_episodes: np.ndarray | None = None  # training episodes completed, per run
        self.run_training_collisions: np.ndarray | None = None
        self._new_records(1)

    def _new_records(self, n_runs: int) -> None:
        self.n_runs = n_runs
        self.records = [{name: [] for name in evaluations.FIELDS} for _ in range(n_runs)]
        self._alias_records()

    def _alias_records(self) -> None:
        # SB3's attribute names (and the package's earlier ones) for the first run's records
        first = self.records[0]
        self.evaluations_timesteps = first[evaluations.TIMESTEPS]
        self.evaluations_results = first[evaluations.RESULTS]
        self.evaluations_length = first[evaluations.EP_LENGTHS]
        self.evaluations_successes = first[evaluations.SUCCESSES]
        self.evaluations_final_successes = first[evaluations.FINAL_SUCCESSES]
        self.evaluations_episodes = first[evaluations.EPISODES]
        self.evaluations_agent_returns = first[evaluations.AGENT_RETURNS]
        self.evaluations_collisions = first[evaluations.COLLISIONS]
        self.evaluations_num_codes = first[evaluations.NUM_CODES]
        self.evaluations_count1 = first[evaluations.COUNT1_FRACTION]
        self.evaluations_training_collisions = first[evaluations.TRAINING_COLLISIONS]

    def _per_run(self, count: int) -> int:
        """One run's share of a count over all the model's envs (the model's own count when it is no pack)."""
        pack = getattr(self.model, "pack", None)
        return count if pack is None else pack.run_steps(count)

    @property
    def run_timesteps(self) -> int:
        """Steps of each run so far (the model's ``num_timesteps`` divided between the runs of a pack)."""
        return self._per_run(self.num_timesteps)

    @property
    def training_collisions(self) -> int:
        """Collisions during training so far (summed over the runs of a pack)."""
        return 0 if self.run_training_collisions is None else int(self.run_training_collisions.sum())

    def _init_callback(self) -> None:
        n_runs = int(getattr(self.model, "n_runs", 1))
        if n_runs != self.n_runs:
            if self.evaluations_timesteps:
                raise ValueError("This callback already holds evaluations of a model with another number of runs")
            self._new_records(n_runs)
            if self._env_id is not None:
                seeds = getattr(self.model, "run_seeds", None) or [None] * n_runs
                self.eval_env = make_eval_vec_env(self._env_id, self.n_eval_episodes, seeds, self._env_kwargs)
        if n_runs > 1:
            if self.callback is not None or self.best_model_save_path is not None:
                raise ValueError("Early stopping and best-model saving work on one run, not on a pack of runs")
            if self.eval_env.num_envs % n_runs:
                raise ValueError(
                    f"A pack of {n_runs} runs needs an eval env with n envs per run, got {self.eval_env.num_envs}"
                )
            if self.run_log_paths is not None and len(self.run_log_paths) != n_runs:
                raise ValueError(f"run_log_paths needs one folder per run ({n_runs}), got {len(self.run_log_paths)}")
        if self.run_episodes is None:
            episodes = int(getattr(self.model, "_episode_num", 0))  # (counted over all envs, as SB3 counts)
            self.run_episodes = np.full(n_runs, self._per_run(episodes), dtype=np.int64)
            self.run_training_collisions = np.zeros(n_runs, dtype=np.int64)
        super()._init_callback()
        for path in self.run_log_paths or []:
            os.makedirs(path, exist_ok=True)
        if self.monitor and not self._monitor_ready:
            if self._monitor_start is None:
                self._monitor_start = time.time()
            for run in range(self.n_runs):  # a new run starts its file afresh; a resumed one cuts it back
                monitor_file = self._monitor_file(run)
                if monitor_file is not None and os.path.exists(monitor_file):
                    with open(monitor_file, "r+b") as file:
                        file.truncate(0 if self._monitor_sizes is None else self._monitor_sizes[run])
            self._monitor_ready = True

    def _monitor_file(self, run: int) -> str | None:
        path = self._run_file(run)
        return None if path is None else os.path.join(os.path.dirname(path), "monitor.csv")

    def _write_monitor(self, run: int, episode: dict[str, Any]) -> None:
        """One training episode of run ``run`` appended to its monitor.csv (SB3's Monitor format)."""
        path = self._monitor_file(run)
        if path is None:
            return
        assert self._monitor_start is not None
        size = os.path.getsize(path) if os.path.exists(path) else 0
        text = ""
        if size == 0:
            header = {"t_start": self._monitor_start, **({"env_id": self._env_id} if self._env_id else {})}
            text = "#" + json.dumps(header) + "\nr,l,t\n"
        seconds = round(time.time() - self._monitor_start, 6)
        text += f"{round(float(episode['r']), 6)},{int(episode['l'])},{seconds}\n"
        try:
            with open(path, "a") as file:
                file.write(text)
        except OSError as exc:  # e.g. a full disk: the file is cut back to its last complete line
            with suppress(OSError):
                os.truncate(path, size)
            raise AtomicWriteError(path, exc) from None

    # --- checkpoints: what the callback has recorded so far -------------------------------------------------------

    def get_state(self) -> dict[str, Any]:
        """The records and counters, for a checkpoint (see :meth:`set_state`)."""
        return {
            "records": self.records,
            "n_calls": self.n_calls,
            "num_timesteps": self.num_timesteps,
            "run_episodes": self.run_episodes,
            "run_training_collisions": self.run_training_collisions,
            "best": (self.best_success_rate, self.best_mean_reward),
            "last": (self.last_success_rate, self.last_mean_reward),
            "after_eval": [_counters(c) for c in self._after_eval_callbacks()],
            "monitor": (self._monitor_start, [self._monitor_size(run) for run in range(self.n_runs)]),
        }

    def _monitor_size(self, run: int) -> int:
        path = self._monitor_file(run) if self.monitor else None
        return os.path.getsize(path) if path is not None and os.path.exists(path) else 0

    def _after_eval_callbacks(self) -> list[BaseCallback]:
        if self.callback is None:
            return []
        return list(self.callback.callbacks) if isinstance(self.callback, CallbackList) else [self.callback]

    def set_state(self, state: dict[str, Any]) -> None:
        """Continue from what :meth:`get_state` returned."""
        self.records = state["records"]
        self.n_runs = len(self.records)
        self._alias_records()
        self._saved_evaluations = len(self.evaluations_timesteps)
        self.n_calls = state["n_calls"]
        self.num_timesteps = state["num_timesteps"]
        self.run_episodes = state["run_episodes"]
        self.run_training_collisions = state["run_training_collisions"]
        self.best_success_rate, self.best_mean_reward = state["best"]
        self.last_success_rate, self.last_mean_reward = state["last"]
        self._monitor_start, self._monitor_sizes = state.get("monitor", (None, [0] * self.n_runs))
        self._monitor_ready = False  # the next learn() cuts the files back to this checkpoint
        saved, mine = state.get("after_eval", []), self._after_eval_callbacks()
        if len(saved) != len(mine):
            raise ValueError(f"the checkpoint has {len(saved)} callback(s) after evaluation, this run {len(mine)}")
        for callback, counters in zip(mine, saved):
            callback.__dict__.update(counters)

    # --- one evaluation -------------------------------------------------------------------------------------------

    def _run_episodes(self) -> list[list[dict[str, Any]]]:
        """
        The episodes of one evaluation, per eval env, run as SB3's ``evaluate_policy`` runs them: every env steps
        until each has completed its share ``(n + i) // n_envs`` of the ``n`` episodes (for a pack ``n`` is
        ``n_eval_episodes`` per run), with the policy's actions for all envs at once, and an episode's return is
        the Monitor's where the env has one.
        """
        env = self.eval_env
        n_envs = env.num_envs
        total = self.n_eval_episodes * self.n_runs
        targets = np.array([(total + i) // n_envs for i in range(n_envs)])
        counts = np.zeros(n_envs, dtype=np.int64)
        episodes: list[list[dict[str, Any]]] = [[] for _ in range(n_envs)]
        team, length = np.zeros(n_envs), np.zeros(n_envs, dtype=np.int64)
        collisions = np.zeros(n_envs, dtype=np.int64)
        returns: np.ndarray | None = None  # (n_envs, n_agents) each agent's return so far
        actor_actions = getattr(self.model, "_actor_actions", None)  # MADDPG: predict() without its per-call checks
        if self.warn and not self._monitor_checked:
            self._monitor_checked = True
            if not (is_vecenv_wrapped(env, VecMonitor) or env.env_is_wrapped(Monitor)[0]):
                warnings.warn(
                    "The evaluation env is not wrapped with a Monitor: returns and lengths are counted by the callback "
                    "and may differ from the env's own if other wrappers change rewards or episode lengths",
                    UserWarning,
                    stacklevel=2,
                )
        observations = env.reset()
        while (counts < targets).any():
            if actor_actions is not None and not isinstance(observations, dict):
                actions = actor_actions(observations)
            else:
                actions, _ = self.model.predict(observations, deterministic=self.deterministic)  # type: ignore[arg-type]
            observations, rewards, dones, infos = env.step(actions)
            for i in np.flatnonzero(counts < targets):
                info = infos[i]
                agent_rewards = info.get("agent_rewards")
                if returns is None:
                    returns = np.zeros((n_envs, 0 if agent_rewards is None else len(agent_rewards)))
                if agent_rewards is not None:
                    returns[i] += agent_rewards
                collisions[i] += _collisions(info)
                team[i] += rewards[i]
                length[i] += 1
                if dones[i]:
                    episode = info.get("episode")
                    episodes[i].append(
                        {
                            "return": float(episode["r"]) if episode else float(team[i]),
                            "length": int(episode["l"]) if episode else int(length[i]),
                            "success": info.get("is_success"),
                            "final_success": _final_success(info),
                            "agent_returns": returns[i].copy(),
                            "collisions": int(collisions[i]),
                        }
                    )
                    returns[i], collisions[i], team[i], length[i] = 0.0, 0, 0.0, 0
                    counts[i] += 1
        return episodes

    # --- per training step -------------------------------------------------------------------------------------------

    def _on_step(self) -> bool:
        assert self.run_episodes is not None and self.run_training_collisions is not None
        infos, dones = self.locals.get("infos", ()), self.locals.get("dones")
        if infos:
            per_run = len(infos) // self.n_runs
            for e, info in enumerate(infos):
                self.run_training_collisions[e // per_run] += _collisions(info)
            if dones is not None:
                self.run_episodes += np.asarray(dones, dtype=np.int64).reshape(self.n_runs, per_run).sum(axis=1)
                if self.monitor:
                    for done in np.flatnonzero(dones):
                        if "episode" in infos[done]:  # (VecMonitor's record of the episode)
                            self._write_monitor(int(done) // per_run, infos[done]["episode"])
        if self.eval_freq <= 0 or self.n_calls % self.eval_freq != 0:
            return True
        return self._evaluate()

    def _evaluate(self) -> bool:
        if self.model.get_vec_normalize_env() is not None:
            sync_envs_normalization(self.training_env, self.eval_env)
        n_envs = self.eval_env.num_envs
        env_episodes = self._run_episodes()
        explorations = getattr(self.model, "explorations", [None] * self.n_runs)
        per_run = n_envs // self.n_runs
        run_rates, run_returns = [], []
        for run, record in enumerate(self.records):
            episodes = [ep for env in range(run * per_run, (run + 1) * per_run) for ep in env_episodes[env]]
            successes = [ep["success"] for ep in episodes if ep["success"] is not None]
            exploration = explorations[run]
            record[evaluations.TIMESTEPS].append(self.run_timesteps)
            record[evaluations.RESULTS].append([ep["return"] for ep in episodes])
            record[evaluations.EP_LENGTHS].append([ep["length"] for ep in episodes])
            record[evaluations.SUCCESSES].append(successes)
            record[evaluations.FINAL_SUCCESSES].append(
                [ep["final_success"] for ep in episodes if ep["final_success"] is not None]
            )
            record[evaluations.EPISODES].append(int(self.run_episodes[run]))  # type: ignore[index]
            record[evaluations.AGENT_RETURNS].append(np.array([ep["agent_returns"] for ep in episodes]))
            record[evaluations.COLLISIONS].append([ep["collisions"] for ep in episodes])
            record[evaluations.NUM_CODES].append(exploration.num_codes if exploration is not None else 0)
            record[evaluations.COUNT1_FRACTION].append(exploration.count1_fraction if exploration is not None else 0.0)
            record[evaluations.TRAINING_COLLISIONS].append(int(self.run_training_collisions[run]))  # type: ignore[index]
            run_rates.append(float(np.mean(successes)) if successes else None)
            run_returns.append(float(np.mean(record[evaluations.RESULTS][-1])))
        n_evaluations = len(self.evaluations_timesteps)
        if n_evaluations - self._saved_evaluations >= max(self.save_freq, n_evaluations // 10):
            self.save_evaluations()

        # what SB3's EvalCallback and the stopping rules read (for a pack: means over the runs)
        self._is_success_buffer = list(self.records[0]["successes"][-1]) if self.n_runs == 1 else []
        mean_reward = float(np.mean(run_returns))
        success_rate = None if any(r is None for r in run_rates) else float(np.mean(run_rates))  # type: ignore[arg-type]
        self.last_mean_reward = mean_reward
        self.last_success_rate = success_rate
        last = [record for record in self.records]
        scalars: dict[str, float | int] = {"eval/mean_reward": mean_reward}
        scalars["eval/mean_ep_length"] = float(np.mean([np.mean(r[evaluations.EP_LENGTHS][-1]) for r in last]))
        if success_rate is not None:
            scalars["eval/success_rate"] = success_rate
            finals = [np.mean(r[evaluations.FINAL_SUCCESSES][-1]) for r in last if r[evaluations.FINAL_SUCCESSES][-1]]
            if finals:
                scalars["eval/final_success_rate"] = float(np.mean(finals))
        agent_returns = [r[evaluations.AGENT_RETURNS][-1] for r in last if len(r[evaluations.AGENT_RETURNS][-1])]
        if agent_returns:
            returns = np.mean(np.concatenate(agent_returns), axis=0)
            layout = getattr(self.model, "agent_layout", None)
            names = layout.agents if layout is not None else [str(i) for i in range(len(returns))]
            for name, value in zip(names, returns):
                scalars[f"eval/return_{name}"] = float(value)
        scalars["eval/collisions"] = float(np.mean([np.mean(r[evaluations.COLLISIONS][-1]) for r in last]))
        scalars["rollout/collisions_total"] = self.training_collisions
        with_macb = [e for e in explorations if e is not None]
        if with_macb:
            scalars["exploration/num_codes"] = float(np.mean([e.num_codes for e in with_macb]))
            scalars["exploration/count1_percent"] = 100.0 * float(np.mean([e.count1_fraction for e in with_macb]))
        report = len(self.evaluations_timesteps) % self.log_freq == 0
        dump = self.dump_logs and report
        if not dump:  # the files (TensorBoard, CSV, JSON) get every evaluation at its step; a later dump only the console
            for output in self.logger.output_formats:
                if not isinstance(output, HumanOutputFormat):
                    output.write(scalars, {key: () for key in scalars}, self.num_timesteps)
        for key, value in scalars.items():
            self.logger.record(key, value, exclude=None if dump else ("tensorboard", "json", "csv"))
        if self.verbose >= 1 and report:
            rate = "n/a" if success_rate is None else f"{success_rate:.2f}"
            runs = "" if self.n_runs == 1 else f" (mean of {self.n_runs} runs)"
            window = "" if self.log_freq == 1 else f", mean of the last {self.log_freq} evaluations {self._recent_rate():.2f}"
            print(f"Eval num_timesteps={self.run_timesteps}, success rate {rate}{window}, return {mean_reward:.2f}{runs}")
        if dump:
            self.logger.record("time/total_timesteps", self.num_timesteps, exclude="tensorboard")
            self.logger.dump(self.num_timesteps)

        continue_training = True
        if self.n_runs == 1:
            score = -np.inf if success_rate is None else success_rate
            if (score, mean_reward) > (self.best_success_rate, self.best_mean_reward):
                self.best_success_rate, self.best_mean_reward = score, mean_reward
                if self.best_model_save_path is not None:
                    self.model.save(os.path.join(self.best_model_save_path, "best_model"))
                if self.callback_on_new_best is not None:
                    continue_training = self.callback_on_new_best.on_step()
            if self.callback is not None:
                continue_training = continue_training and self._on_event()
        return continue_training

    def _recent_rate(self) -> float:
        """Success rate over the last ``log_freq`` evaluations, mean over the runs."""
        rates = [
            np.mean([np.mean(s) for s in r[evaluations.SUCCESSES][-self.log_freq :] if len(s)] or [0.0]) for r in self.records
        ]
        return float(np.mean(rates))

    def _run_file(self, run: int) -> str | None:
        if self.run_log_paths is not None:
            return os.path.join(self.run_log_paths[run], "evaluations.npz")
        if self.log_path is None:
            return None
        if self.n_runs == 1:
            return self.log_path + ".npz"
        return os.path.join(os.path.dirname(self.log_path), f"run_{run}", "evaluations.npz")

    def save_evaluations(self) -> None:
        """Write each run's ``evaluations.npz`` (SB3's fields plus the multi-agent ones), compressed and atomically."""
        for run, record in enumerate(self.records):
            path = self._run_file(run)
            if path is not None and record[evaluations.TIMESTEPS]:
                evaluations.save(path, record)
        self._saved_evaluations = len(self.evaluations_timesteps)

    def _on_training_end(self) -> None:
        self.save_evaluations()
        super()._on_training_end()


def _final_success(info: dict[str, Any]) -> bool | None:
    """Whether the success condition holds at this (last) step, from the first agent's info (None if not reported)."""
    agent_infos = info.get("agent_infos")
    if not agent_infos:
        return None
    first = next(iter(agent_infos.values()))
    if not isinstance(first, dict) or "success" not in first:
        return None
    return bool(first["success"])


def _collisions(info: dict[str, Any]) -> int:
    """Collisions reported by the first agent's info (the paper's tasks report them for all agents alike)."""
    agent_infos = info.get("agent_infos")
    if not agent_infos:
        return 0
    first = next(iter(agent_infos.values()))
    return int(first.get("collisions", 0)) if isinstance(first, dict) else 0

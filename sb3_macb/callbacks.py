"""Evaluation as the paper does it (success rate after every training episode), and early stopping on success."""

import os
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, EvalCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import VecEnv, sync_envs_normalization


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


class MultiAgentEvalCallback(EvalCallback):
    """
    SB3's ``EvalCallback`` for multi-agent runs, as the paper evaluates: every ``eval_freq`` steps (20 = one
    training episode), ``n_eval_episodes`` noise-free episodes, run as one batch on a vectorized eval env.

    Each evaluation records the success rate, the team return, every agent's return, the collisions and, with
    MACB, the number of codes and the count-1 fraction. They are logged through SB3's logger (``eval/...``,
    ``exploration/...``) and saved in SB3's ``evaluations.npz`` format (``timesteps``, ``results``, ``ep_lengths``,
    ``successes``) plus ``episodes``, ``agent_returns``, ``collisions``, ``num_codes``, ``count1_fraction`` and
    ``training_collisions`` (accumulated collisions during training so far).
    The best model is kept by success rate (ties: mean return). Collisions during training are summed and
    logged as ``rollout/collisions_total``.

    :param eval_env: The evaluation env: a VecEnv, a gymnasium env, or an env id (a DummyVecEnv of
        ``n_eval_episodes`` copies is built, so that an evaluation is one batch of episodes).
    :param n_eval_episodes: Episodes per evaluation.
    :param eval_freq: Evaluate every ``eval_freq`` calls (environment steps per env).
    :param log_path: Folder for ``evaluations.npz`` (None: not saved).
    :param best_model_save_path: Folder for ``best_model.zip`` (None: not saved).
    :param save_freq: Write ``evaluations.npz`` every this many evaluations (and at the end of training): SB3
        rewrites it at every evaluation, which at the paper's protocol (40,000 evaluations) is quadratic I/O.
    :param deterministic: Evaluate the deterministic policy (no action noise).
    :param stop_success_rate: Stop training once the success rate reaches this value (None: never).
    :param stop_patience: Stop training after this many evaluations without a new best success rate (None: never).
    :param min_evals: Evaluations before either stopping rule applies.
    :param callback_after_eval: Another callback to run after every evaluation.
    :param callback_on_new_best: A callback to run when a new best model is found.
    :param env_kwargs: Keyword arguments for the env when ``eval_env`` is an env id.
    :param seed: Seed of the eval env when it is built from an env id.
    :param dump_logs: Dump the logger after each evaluation (as SB3 does).
    :param verbose: Verbosity level.
    :param warn: Warn when the eval env is not wrapped with a Monitor.
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
    ):
        if isinstance(eval_env, str):
            eval_env = make_vec_env(eval_env, n_envs=n_eval_episodes, seed=seed, env_kwargs=env_kwargs)
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
        self.dump_logs = dump_logs
        self.best_success_rate = -np.inf
        self.last_success_rate: float | None = None
        self.training_collisions = 0
        self.evaluations_episodes: list[int] = []
        self.evaluations_agent_returns: list[np.ndarray] = []
        self.evaluations_collisions: list[list[int]] = []
        self.evaluations_num_codes: list[int] = []
        self.evaluations_count1: list[float] = []
        self.evaluations_training_collisions: list[int] = []
        self._episode_agent_returns: list[np.ndarray] = []
        self._episode_collisions: list[int] = []
        self._running_returns: np.ndarray | None = None
        self._running_collisions: np.ndarray | None = None

    # --- per step of an evaluation (evaluate_policy's callback) ----------------------------------------------------

    def _log_success_callback(self, locals_: dict[str, Any], globals_: dict[str, Any]) -> None:
        super()._log_success_callback(locals_, globals_)
        i, info = locals_["i"], locals_["info"]
        agent_rewards = info.get("agent_rewards")
        if self._running_returns is None:
            n_agents = 0 if agent_rewards is None else len(agent_rewards)
            self._running_returns = np.zeros((self.eval_env.num_envs, n_agents))
            self._running_collisions = np.zeros(self.eval_env.num_envs, dtype=np.int64)
        if agent_rewards is not None:
            self._running_returns[i] += agent_rewards
        assert self._running_collisions is not None
        self._running_collisions[i] += _collisions(info)
        if locals_["done"]:
            self._episode_agent_returns.append(self._running_returns[i].copy())
            self._episode_collisions.append(int(self._running_collisions[i]))
            self._running_returns[i] = 0.0
            self._running_collisions[i] = 0

    # --- per training step -------------------------------------------------------------------------------------------

    def _on_step(self) -> bool:
        for info in self.locals.get("infos", ()):
            self.training_collisions += _collisions(info)
        if self.eval_freq <= 0 or self.n_calls % self.eval_freq != 0:
            return True
        return self._evaluate()

    def _evaluate(self) -> bool:
        if self.model.get_vec_normalize_env() is not None:
            sync_envs_normalization(self.training_env, self.eval_env)
        self._is_success_buffer = []
        self._episode_agent_returns, self._episode_collisions = [], []
        self._running_returns = None
        episode_rewards, episode_lengths = evaluate_policy(
            self.model,
            self.eval_env,
            n_eval_episodes=self.n_eval_episodes,
            deterministic=self.deterministic,
            return_episode_rewards=True,
            warn=self.warn,
            callback=self._log_success_callback,
        )
        assert isinstance(episode_rewards, list) and isinstance(episode_lengths, list)
        mean_reward = float(np.mean(episode_rewards))
        success_rate = float(np.mean(self._is_success_buffer)) if self._is_success_buffer else None
        self.last_mean_reward = mean_reward
        self.last_success_rate = success_rate
        exploration = getattr(self.model, "exploration", None)

        self.evaluations_timesteps.append(self.num_timesteps)
        # training episodes completed (SB3 counts the episodes that end at this step only after the callbacks)
        ended_now = int(np.sum(self.locals.get("dones", 0)))
        self.evaluations_episodes.append(int(getattr(self.model, "_episode_num", 0)) + ended_now)
        self.evaluations_results.append(episode_rewards)
        self.evaluations_length.append(episode_lengths)
        self.evaluations_successes.append(list(self._is_success_buffer))
        self.evaluations_agent_returns.append(np.array(self._episode_agent_returns))
        self.evaluations_collisions.append(self._episode_collisions)
        self.evaluations_num_codes.append(exploration.num_codes if exploration is not None else 0)
        self.evaluations_count1.append(exploration.count1_fraction if exploration is not None else 0.0)
        self.evaluations_training_collisions.append(self.training_collisions)
        if len(self.evaluations_timesteps) % self.save_freq == 0:
            self.save_evaluations()

        self.logger.record("eval/mean_reward", mean_reward)
        self.logger.record("eval/mean_ep_length", float(np.mean(episode_lengths)))
        if success_rate is not None:
            self.logger.record("eval/success_rate", success_rate)
        if self._episode_agent_returns:
            returns = np.mean(self._episode_agent_returns, axis=0)
            layout = getattr(self.model, "agent_layout", None)
            names = layout.agents if layout is not None else [str(i) for i in range(len(returns))]
            for name, value in zip(names, returns):
                self.logger.record(f"eval/return_{name}", float(value))
        self.logger.record("eval/collisions", float(np.mean(self._episode_collisions)))
        self.logger.record("rollout/collisions_total", self.training_collisions)
        if exploration is not None:
            self.logger.record("exploration/num_codes", exploration.num_codes)
            self.logger.record("exploration/count1_percent", 100.0 * exploration.count1_fraction)
        if self.verbose >= 1:
            rate = "n/a" if success_rate is None else f"{success_rate:.2f}"
            print(f"Eval num_timesteps={self.num_timesteps}, success rate {rate}, return {mean_reward:.2f}")
        if self.dump_logs:
            self.logger.record("time/total_timesteps", self.num_timesteps, exclude="tensorboard")
            self.logger.dump(self.num_timesteps)

        continue_training = True
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

    def save_evaluations(self) -> None:
        """Write ``evaluations.npz`` (SB3's fields plus the multi-agent ones), compressed."""
        if self.log_path is None or not self.evaluations_timesteps:
            return
        successes = self.evaluations_successes if all(self.evaluations_successes) else []
        # compressed: read back by np.load like SB3's file, a fraction of the size for long runs
        np.savez_compressed(
            self.log_path,
            timesteps=self.evaluations_timesteps,
            results=self.evaluations_results,
            ep_lengths=self.evaluations_length,
            **({"successes": successes} if successes else {}),
            episodes=self.evaluations_episodes,
            agent_returns=np.array(self.evaluations_agent_returns),
            collisions=self.evaluations_collisions,
            num_codes=self.evaluations_num_codes,
            count1_fraction=self.evaluations_count1,
            training_collisions=self.evaluations_training_collisions,
        )

    def _on_training_end(self) -> None:
        self.save_evaluations()
        super()._on_training_end()


def _collisions(info: dict[str, Any]) -> int:
    """Collisions reported by the first agent's info (the paper's tasks report them for all agents alike)."""
    agent_infos = info.get("agent_infos")
    if not agent_infos:
        return 0
    first = next(iter(agent_infos.values()))
    return int(first.get("collisions", 0)) if isinstance(first, dict) else 0

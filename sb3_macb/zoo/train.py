"""
``sb3-macb train``: one run of MADDPG with the zoo's YAML, as one explicit function (:func:`train`) on top of
:mod:`sb3_macb.zoo.experiment` (the same code ``sb3-macb sweep`` and the paper study's ``reproduce.py`` run), evaluated as the
paper does (:class:`~sb3_macb.callbacks.MultiAgentEvalCallback`), with checkpoints and resume on request.

It takes rl_zoo3's train options that apply to these runs (same names and spellings: ``-c``/``--conf``/``-conf``/
``--conf-file``, ``-params``, ``--env-kwargs``, ``-n``, ``-f``, ``-tb``, ``--eval-freq``, ...) and adds:

- ``--variant NAME[,NAME...]``: named overrides from the ``variants`` section of the YAML file;
- dotted hyperparameter overrides (``-params exploration.beta:0.4``) into nested dicts;
- a clear error for unknown YAML keys; hyperparameter strings parsed without running code (``--unsafe-eval`` to
  evaluate them as Python);
- early-stopping callbacks from the YAML ``callback:`` list run after each evaluation;
- ``--checkpoint-freq N`` and ``--resume RUN_FOLDER``.

``--optimize`` hands the search to rl_zoo3's ExperimentManager (built directly, with the hyperparameters resolved here).
"""

import argparse
import difflib
import os
import shlex
import sys
from copy import deepcopy
from pprint import pprint
from typing import Any

import yaml

import sb3_macb.envs  # noqa: F401  (registers the task ids)
from sb3_macb.common.atomic import atomic_write
from sb3_macb.maddpg import MADDPG
from sb3_macb.zoo.experiment import (
    DEFAULT_CONFIG,
    EVALUATED_KEYS,
    SAFE_CALLBACKS,
    UNSAFE_HINT,
    Experiment,
    ExperimentConfig,
    ExperimentError,
    callback_entries,
    check_hyperparams,
    check_values,
    evaluate_string,
    make_callbacks,
    make_run,
    unsupported_keys,
    valid_device,
)


def register_with_rl_zoo3() -> None:
    """Register MADDPG in rl_zoo3's algorithm table and its Optuna sampler (idempotent)."""
    from rl_zoo3 import hyperparams_opt, utils

    utils.ALGOS["maddpg"] = MADDPG
    hyperparams_opt.HYPERPARAMS_SAMPLER["maddpg"] = sample_maddpg_params
    hyperparams_opt.HYPERPARAMS_CONVERTER["maddpg"] = convert_maddpg_params  # type: ignore[assignment]


def sample_maddpg_params(trial: Any, n_actions: int, n_envs: int, additional_args: dict) -> dict[str, Any]:
    """Optuna sampler for ``--optimize``: rl_zoo3's off-policy parameters plus MACB's beta and k."""
    from rl_zoo3.hyperparams_opt import sample_td3_params

    params = sample_td3_params(trial, n_actions, n_envs, additional_args)
    params["exploration"] = {
        "beta": trial.suggest_float("macb_beta", 0.0, 1.0),
        "k": trial.suggest_categorical("macb_k", [32, 64, 128, 256, 512]),
    }
    return params


def convert_maddpg_params(sampled: dict[str, Any]) -> dict[str, Any]:
    """Turn a trial's raw parameters into hyperparameters (used by rl_zoo3 to reload a trial)."""
    from rl_zoo3.hyperparams_opt import convert_offpolicy_params

    sampled = dict(sampled)
    beta, k = sampled.pop("macb_beta", None), sampled.pop("macb_k", None)
    for name in ("noise_type", "noise_std"):
        sampled.pop(name, None)
    params = convert_offpolicy_params(sampled)
    if beta is not None and k is not None:
        params["exploration"] = {"beta": beta, "k": k}
    return params


def make_parser() -> argparse.ArgumentParser:
    """The ``sb3-macb train`` command line (rl_zoo3's option names where they exist)."""
    parser = argparse.ArgumentParser(
        prog="sb3-macb train",
        description="Train MADDPG (with MACB) on a registered env with the zoo's YAML settings, evaluated as the paper "
        "does (every --eval-freq steps, --eval-episodes noise-free episodes). Run files: evaluations.npz, model.zip, "
        "best_model.zip, config.yml (the effective hyperparameters), run.json.",
    )
    add = parser.add_argument
    add("--env", required=True, help="gymnasium env id (e.g. sb3_macb/CommunicativeNavigation-v0)")
    add("--algo", default="maddpg", choices=["maddpg"], help="algorithm (rl_zoo3's option; only maddpg)")
    add("--seed", type=int, default=-1, help="random seed (default: a random one, printed and recorded)")
    add("-n", "--n-timesteps", type=int, default=None, help="environment steps (default: the YAML's n_timesteps)")
    add("-f", "--log-folder", default="logs", help="runs go to LOG_FOLDER/maddpg/ENV_N")
    add("-conf", "--conf-file", "-c", "--conf", dest="conf_file", default=None,
        help="YAML hyperparameter file (default: zoo/hyperparams/maddpg.yml, shipped with the package)")  # fmt: skip
    add("--variant", default="", help="named overrides from the YAML's variants section, e.g. maddpg,fast")
    add("-params", "--hyperparams", nargs="+", default=[], metavar="KEY:VALUE",
        help="hyperparameter overrides (dotted keys for nested dicts: exploration.beta:0.4)")  # fmt: skip
    add("--env-kwargs", nargs="+", default=[], metavar="KEY:VALUE", help="keyword arguments for the env")
    add(
        "--eval-freq",
        type=int,
        default=20,
        help="evaluate every this many steps (0 or negative: never, as rl_zoo3); the paper: 20",
    )
    add("--eval-episodes", type=int, default=10, help="episodes per evaluation; the paper: 10")
    add("--num-threads", type=int, default=1, help="torch threads")
    add("--device", default="auto", help="torch device (auto, cpu, cuda)")
    add("-tb", "--tensorboard-log", default=None,
        help="TensorBoard folder (default: LOG_FOLDER/tensorboard when tensorboard is installed; '' for none); "
             "a run logs into its subfolder named like the run's folder, e.g. ENV_1, every evaluation included")  # fmt: skip
    add("--log-interval", type=int, default=100, help="SB3's training table every this many training episodes")
    add("--verbose", type=int, default=1, help="0: quiet; 1: a summary every 100 evaluations; 2: a table after each")
    add("-P", "--progress", action="store_true", help="progress bar (the default)")
    add("--no-progress", action="store_true", help="no progress bar")
    add("--unsafe-eval", action="store_true",
        help="evaluate hyperparameter strings (YAML, -params, --env-kwargs) as Python and allow callbacks from any "
        "module, as rl_zoo3 does (only for files you trust); by default they are parsed without running code")  # fmt: skip
    add("--checkpoint-freq", type=int, default=None, help="checkpoint every N steps into the run folder")
    add("--resume", metavar="RUN_FOLDER", default=None, help="continue a checkpointed run (same command)")
    add("--keep-models", action="store_true", help="keep every checkpoint's model as RUN_FOLDER/models/step_N.zip")
    add("--save-freq", type=int, default=-1, help="rl_zoo3's option: keep the model every N steps (here a checkpoint "
        "every N steps with --keep-models: RUN_FOLDER/models/step_N.zip; the last is model.zip); -1: none")  # fmt: skip
    add("--save-replay-buffer", action="store_true", help="also save the final replay buffer as RUN_FOLDER/replay_buffer.pkl")
    add("-i", "--trained-agent", default=None, help="rl_zoo3's option to continue a saved model: not supported "
        "(continue a checkpointed run with --resume RUN_FOLDER)")  # fmt: skip
    search = parser.add_argument_group("hyperparameter search (rl_zoo3's Optuna optimizer)")
    search.add_argument("-optimize", "--optimize-hyperparameters", "--optimize", dest="optimize", action="store_true")
    search.add_argument("--n-trials", type=int, default=500)
    search.add_argument("--n-jobs", type=int, default=1)
    search.add_argument("--sampler", default="tpe", choices=["random", "tpe", "skopt"])
    search.add_argument("--pruner", default="median", choices=["halving", "median", "none"])
    search.add_argument("--n-startup-trials", type=int, default=10)
    search.add_argument("--n-evaluations", type=int, default=None)
    search.add_argument("--storage", default=None,
                        help="Optuna storage: an RDB URL (sqlite:///..., postgresql://...) or a file PATH.log, "
                        "which rl_zoo3 opens as Optuna's journal storage (several workers, no server)")  # fmt: skip
    search.add_argument("--study-name", default=None)
    return parser


def _pairs(items: list[str], what: str, unsafe_eval: bool) -> dict[str, Any]:
    """
    ``KEY:VALUE`` items (rl_zoo3's StoreDict format) parsed into a dict; values as :func:`evaluate_string`. Strings the
    YAML would also hold as strings (``policy_kwargs: "dict(...)"``) are checked here and kept as strings, so that the
    run's ``experiment.json`` stays plain JSON and its ``config.yml`` reads like the YAML.
    """

    result = {}
    for item in items:
        key, sep, value = item.partition(":")
        if not sep or not key:
            raise ExperimentError(f"{what} takes KEY:VALUE pairs, got {item!r}")
        parsed = evaluate_string(value, f"{what} {key}", unsafe_eval)
        result[key] = value if key in EVALUATED_KEYS and not isinstance(parsed, str) else parsed
    return result


def _check_arguments(args: argparse.Namespace) -> None:
    """Refuse command-line values that cannot make a run, in one line naming the option (before anything is made)."""

    if args.n_timesteps is not None and args.n_timesteps < 1:
        raise ExperimentError(f"-n/--n-timesteps must be >= 1 step, got {args.n_timesteps}")
    if args.num_threads < 1:
        raise ExperimentError(f"--num-threads must be >= 1, got {args.num_threads}")
    if args.trained_agent is not None:
        raise ExperimentError(
            f"-i/--trained-agent {args.trained_agent}: not supported (a model zip lacks the replay buffer, count tables and "
            "random states a run continues from); checkpoint with --checkpoint-freq N and continue with --resume RUN_FOLDER"
        )
    if args.eval_episodes < 1:
        raise ExperimentError(f"--eval-episodes must be >= 1, got {args.eval_episodes}")
    args.eval_freq = max(args.eval_freq, 0)  # rl_zoo3: a negative frequency turns evaluation off
    if args.save_freq == 0 or args.save_freq < -1:
        raise ExperimentError(f"--save-freq must be >= 1 step (or -1: none), got {args.save_freq}")
    if args.save_freq > 0:
        if args.checkpoint_freq is not None and args.checkpoint_freq != args.save_freq:
            raise ExperimentError(f"--save-freq {args.save_freq} and --checkpoint-freq {args.checkpoint_freq}: models are "
                                  "kept at the checkpoints, so give one of the two (or both equal)")  # fmt: skip
        args.checkpoint_freq, args.keep_models = args.save_freq, True
    if args.checkpoint_freq is not None and args.checkpoint_freq < 1:
        raise ExperimentError(f"--checkpoint-freq must be >= 1 step, got {args.checkpoint_freq}")
    if not valid_device(args.device):
        raise ExperimentError(f"--device must be auto, cpu, cuda or cuda:N, got {args.device!r}")
    if args.resume and not os.path.isdir(args.resume):
        raise ExperimentError(f"--resume {args.resume}: no such folder")


def _check_writable(folder: str, option: str) -> None:
    """``folder`` is a folder this user can write in, or can be made in one (checked without writing anything)."""

    import tempfile

    existing = os.path.abspath(folder)
    while not os.path.exists(existing) and os.path.dirname(existing) != existing:
        existing = os.path.dirname(existing)  # the nearest folder that exists: the run's folders are made below it
    try:
        if not os.path.isdir(existing):
            raise NotADirectoryError(20, "not a directory")
        with tempfile.TemporaryFile(dir=existing):  # (a file that leaves nothing behind)
            pass
    except OSError as exc:
        raise ExperimentError(
            f"{option} {folder} is not a folder this user can write to ({existing}: {exc.strerror})"
        ) from None


def _check_env_id(env_id: str) -> None:
    import gymnasium as gym

    if env_id not in gym.registry:
        close = difflib.get_close_matches(env_id, list(gym.registry), n=1)
        raise ExperimentError(f"{env_id} not found in gym registry" + (f", did you mean {close[0]}?" if close else ""))


def _new_run_folder(log_folder: str, algo: str, env_id: str) -> str:
    """rl_zoo3's layout: ``LOG_FOLDER/ALGO/ENV_N`` with the next free N."""
    from rl_zoo3.utils import EnvironmentName, get_latest_run_id

    base = os.path.join(log_folder, algo)
    name = str(EnvironmentName(env_id))
    return os.path.join(base, f"{name}_{get_latest_run_id(base, name) + 1}")


def _saved_seed(folder: str) -> int | None:
    import json

    try:
        with open(os.path.join(folder, "experiment.json")) as file:
            return int(json.load(file)["config"]["runs"][0]["seed"])
    except (OSError, ValueError, KeyError, IndexError, TypeError):
        return None


def train(argv: list[str] | None = None, overrides: dict[str, Any] | None = None) -> str | None:
    """
    Run ``sb3-macb train`` with these arguments (see ``sb3-macb train --help``).

    :param argv: Command-line arguments (default: ``sys.argv[1:]``).
    :param overrides: Hyperparameters (dotted names allowed) applied after the variants, before ``-params``.
    :return: The run's folder (``LOG_FOLDER/maddpg/ENV_N``; None for ``--optimize``).
    """
    import numpy as np
    import torch as th

    argv = list(sys.argv[1:] if argv is None else argv)
    args = make_parser().parse_args(argv)
    _check_arguments(args)
    _check_env_id(args.env)
    if args.conf_file is not None and not str(args.conf_file).endswith((".yml", ".yaml")):
        raise ExperimentError(f"--conf-file {args.conf_file!r} is not a .yml/.yaml file")
    variants = [v for v in args.variant.split(",") if v]
    params = _pairs(args.hyperparams, "-params", args.unsafe_eval)
    check_hyperparams({key.split(".")[0]: None for key in params}, "-params")  # a typo there is named there
    run, n_timesteps = make_run(
        args.env, 0, "", variants, {**(overrides or {}), **params}, args.conf_file, args.n_timesteps
    )  # (seed and folder are settled below)
    hyperparams = run.hyperparams
    env_kwargs = _pairs(args.env_kwargs, "--env-kwargs", args.unsafe_eval)
    if args.resume and args.seed < 0:  # a random seed is the one the run recorded
        saved = _saved_seed(args.resume)
        args.seed = args.seed if saved is None else saved
    if args.seed < 0:
        args.seed = int(np.random.randint(2**31 - 1))
    tensorboard_log = args.tensorboard_log
    if tensorboard_log is None and args.optimize:
        tensorboard_log = ""  # (rl_zoo3 logs no trial to TensorBoard)
    elif tensorboard_log is None:
        try:
            import tensorboard  # noqa: F401

            tensorboard_log = os.path.join(args.log_folder, "tensorboard")
        except ImportError:
            tensorboard_log = ""
    th.set_num_threads(args.num_threads)
    if args.device != "auto":
        hyperparams.setdefault("device", args.device)
    if args.optimize:
        _optimize(args, hyperparams, env_kwargs, n_timesteps, tensorboard_log)
        return None

    folder = args.resume or _new_run_folder(args.log_folder, args.algo, args.env)
    run.seed, run.folder = args.seed, folder
    config = ExperimentConfig(
        args.env,
        [run],
        n_timesteps=n_timesteps,
        eval_freq=args.eval_freq,
        eval_episodes=args.eval_episodes,
        env_kwargs=env_kwargs,
        command="sb3-macb train " + " ".join(shlex.quote(a) for a in argv),
        unsafe_eval=args.unsafe_eval,
    )
    if not args.resume:
        _check_writable(args.log_folder, "-f/--log-folder")
    if args.verbose > 0:
        used = ", ".join(variants) or "none"
        print(f"{'Resuming' if args.resume else 'Training'} {args.env} (seed {args.seed}, {n_timesteps} steps) in {folder}")
        print(f"Hyperparameters from {args.conf_file or DEFAULT_CONFIG} (variants: {used}; overrides and -params applied):")
        pprint({**{k: config.runs[0].hyperparams[k] for k in sorted(config.runs[0].hyperparams)}, "n_timesteps": n_timesteps})
    experiment = Experiment(
        config,
        folder,
        monitor=True,  # RUN_FOLDER/monitor.csv, as rl_zoo3 writes one
        checkpoint_freq=args.checkpoint_freq,
        verbose=min(args.verbose, 1),
        progress_bar=not args.no_progress,
        tensorboard_log=tensorboard_log or None,
        log_interval=args.log_interval if args.verbose > 0 else None,
        eval_log_freq=None if args.verbose == 0 else 1 if args.verbose >= 2 else 100,
        save_best=True,
        keep_models=args.keep_models,
    )
    experiment.run(resume=bool(args.resume))
    with atomic_write(os.path.join(folder, "args.yml")) as file:  # the command's options, as rl_zoo3 keeps them
        file.write(yaml.safe_dump({k: v for k, v in sorted(vars(args).items())}).encode())
    if args.save_replay_buffer and experiment.model is not None:
        experiment.model.save_replay_buffer(os.path.join(folder, "replay_buffer.pkl"))
    return folder


def _optimize(args: argparse.Namespace, hyperparams: dict[str, Any], env_kwargs: dict[str, Any], n_timesteps: int,
              tensorboard_log: str) -> None:  # fmt: skip
    """``--optimize``: rl_zoo3's Optuna search over MADDPG's and MACB's hyperparameters, from the resolved entry."""
    from rl_zoo3.exp_manager import ExperimentManager

    check_values({**hyperparams, "n_timesteps": n_timesteps}, "--optimize")
    if args.n_jobs > 1 and (args.storage or "").startswith("sqlite"):
        print(f"Warning: {args.n_jobs} jobs share the SQLite storage {args.storage}, which Optuna advises against for "
              f"parallel workers (locked-database errors); --storage PATH.log keeps the study in a journal file that "
              f"they can share", file=sys.stderr)  # fmt: skip
    resolved = dict(hyperparams)
    if not args.unsafe_eval:
        # rl_zoo3 evals normalize/monitor_kwargs strings and imports and calls env wrappers: refused, as in plain runs
        used = unsupported_keys(resolved)
        if used:
            raise ExperimentError(
                f"{used}: rl_zoo3 would evaluate or import these for --optimize; remove them ({UNSAFE_HINT})"
            )
        writers = [name for name, _ in callback_entries(resolved.get("callback")) if SAFE_CALLBACKS.get(name)]
        if writers:
            raise ExperimentError(f"'callback' {writers}: callbacks that write files are not passed to rl_zoo3's search "
                                  f"(its trials have no run folder to confine them to); {UNSAFE_HINT}")  # fmt: skip
    for key in EVALUATED_KEYS:  # rl_zoo3 would eval these strings: hand it values
        if isinstance(resolved.get(key), str):
            resolved[key] = evaluate_string(resolved[key], f"hyperparameter '{key}'", args.unsafe_eval)
    make_callbacks(resolved, args.unsafe_eval)  # refuses classes outside the allow-list before rl_zoo3 imports them
    register_with_rl_zoo3()

    class _Manager(ExperimentManager):
        def read_hyperparameters(self) -> tuple[dict[str, Any], dict[str, Any]]:
            return deepcopy(resolved), dict(resolved)

    manager = _Manager(
        args, "maddpg", args.env, args.log_folder, tensorboard_log, n_timesteps, args.eval_freq, args.eval_episodes,
        env_kwargs=env_kwargs, optimize_hyperparameters=True, storage=args.storage, study_name=args.study_name,
        n_trials=args.n_trials, n_jobs=args.n_jobs, sampler=args.sampler, pruner=args.pruner,
        n_startup_trials=args.n_startup_trials, n_evaluations=args.n_evaluations or 1, seed=args.seed,
        verbose=args.verbose, device=args.device, config=args.conf_file or DEFAULT_CONFIG,
    )  # fmt: skip
    manager.setup_experiment()
    # the trials' score is the success rate, as a run's best model and the sweep's objective (rl_zoo3 builds its
    # trial callback by this module-level name; restored afterwards)
    import rl_zoo3.exp_manager

    original = rl_zoo3.exp_manager.TrialEvalCallback
    rl_zoo3.exp_manager.TrialEvalCallback = _success_trial_callback(original)  # type: ignore[misc,assignment]
    try:
        manager.hyperparameters_optimization()
    finally:
        rl_zoo3.exp_manager.TrialEvalCallback = original  # type: ignore[misc]
    return None


def _success_trial_callback(base: type) -> type:
    """
    rl_zoo3's ``TrialEvalCallback`` whose score (what each evaluation reports to the trial, and the trial's value) is
    the evaluation's success rate where the episodes report ``is_success``, else the mean reward as in rl_zoo3.
    """

    class SuccessTrialEvalCallback(base):
        @property
        def last_mean_reward(self) -> float:
            successes = getattr(self, "_is_success_buffer", None)  # (the latest evaluation's episodes)
            return float(sum(successes) / len(successes)) if successes else self._last_reward

        @last_mean_reward.setter
        def last_mean_reward(self, value: float) -> None:  # what EvalCallback sets after each evaluation
            self._last_reward = value

    return SuccessTrialEvalCallback

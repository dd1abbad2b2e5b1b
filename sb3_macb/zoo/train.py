"""
``sb3-macb train``: rl_zoo3's train command with MADDPG registered, the package's env ids known, and the paper's
evaluation protocol (:class:`~sb3_macb.callbacks.MultiAgentEvalCallback`) in place of rl_zoo3's EvalCallback.

rl_zoo3 does the work (argument parsing, YAML, schedules, noise, folders, saving, Optuna); this module only adds:

- ``--variant NAME[,NAME...]``: named overrides from the ``variants`` section of the YAML file;
- dotted hyperparameter overrides (``-params exploration.beta:0.4``) into nested dicts;
- a clear error for unknown YAML keys;
- early-stopping callbacks from the YAML ``callback:`` list attached after each evaluation.
"""

import argparse
import difflib
import inspect
import os
import sys
from copy import deepcopy
from pathlib import Path
from typing import Any

import yaml
from stable_baselines3.common.callbacks import CallbackList

import sb3_macb.envs  # noqa: F401  (registers the task ids)
from sb3_macb.callbacks import MultiAgentEvalCallback, _SuccessRateStop
from sb3_macb.maddpg import MADDPG

DEFAULT_CONFIG = str(Path(__file__).parent / "hyperparams" / "maddpg.yml")

# keys rl_zoo3 consumes itself before building the model
ZOO_KEYS = {
    "n_timesteps", "policy", "n_envs", "normalize", "env_wrapper", "vec_env_wrapper", "frame_stack", "callback",
    "noise_type", "noise_std", "env_kwargs", "monitor_kwargs", "normalize_kwargs",
}  # fmt: skip
MODEL_KEYS = set(inspect.signature(MADDPG.__init__).parameters) - {"self", "env", "_init_setup_model", "policy"}


def check_hyperparams(hyperparams: dict[str, Any], where: str) -> None:
    """Raise a clear error for keys neither rl_zoo3 nor MADDPG know."""
    known = ZOO_KEYS | MODEL_KEYS
    unknown = sorted(set(hyperparams) - known)
    if unknown:
        hints = []
        for key in unknown:
            close = difflib.get_close_matches(key, known, n=1)
            hints.append(f"'{key}'" + (f" (did you mean '{close[0]}'?)" if close else ""))
        raise ValueError(f"Unknown hyperparameter(s) in {where}: {', '.join(hints)}. Known keys: {sorted(known)}")


def apply_overrides(hyperparams: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """
    Apply ``overrides`` on top of ``hyperparams``; a dotted key (``exploration.beta``) sets a key of a nested
    dict (created when absent, e.g. when the base has ``exploration: null``).
    """
    result = deepcopy(hyperparams)
    for key, value in overrides.items():
        *parents, leaf = key.split(".")
        target = result
        for parent in parents:
            if not isinstance(target.get(parent), dict):
                target[parent] = {}
            target = target[parent]
        target[leaf] = value
    return result


def register_with_rl_zoo3() -> None:
    """Register MADDPG in rl_zoo3's algorithm table and its Optuna sampler (idempotent)."""
    from rl_zoo3 import hyperparams_opt, utils

    utils.ALGOS["maddpg"] = MADDPG
    hyperparams_opt.HYPERPARAMS_SAMPLER["maddpg"] = sample_maddpg_params
    hyperparams_opt.HYPERPARAMS_CONVERTER["maddpg"] = convert_maddpg_params


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


def _experiment_manager_class() -> type:
    from rl_zoo3.exp_manager import ExperimentManager

    class MultiAgentExperimentManager(ExperimentManager):
        """rl_zoo3's ExperimentManager with variants, dotted overrides, key checks and the paper's evaluation."""

        variants: list[str] = []
        overrides: dict[str, Any] = {}
        last_save_path: str | None = None

        def read_hyperparameters(self) -> tuple[dict[str, Any], dict[str, Any]]:
            custom, self.custom_hyperparams = self.custom_hyperparams, None
            hyperparams, _ = super().read_hyperparameters()
            with open(self.config) as file:
                variants = (yaml.safe_load(file) or {}).get("variants", {}) if self.config.endswith((".yml", ".yaml")) else {}
            for name in self.variants:
                if name not in variants:
                    raise ValueError(f"Unknown variant '{name}' in {self.config}; known variants: {sorted(variants)}")
                hyperparams = apply_overrides(hyperparams, variants[name])
            hyperparams = apply_overrides(hyperparams, self.overrides)
            hyperparams = apply_overrides(hyperparams, custom or {})
            check_hyperparams(hyperparams, f"{self.config} (env {self.env_name.gym_id})")
            self.custom_hyperparams = custom
            saved = {key: hyperparams[key] for key in sorted(hyperparams)}
            return hyperparams, saved

        def create_callbacks(self) -> None:
            eval_freq, self.eval_freq = self.eval_freq, 0
            super().create_callbacks()  # progress bar, checkpoints
            self.eval_freq = eval_freq
            MultiAgentExperimentManager.last_save_path = self.save_path
            stoppers = [c for c in self.callbacks if isinstance(c, _SuccessRateStop)]
            self.callbacks = [c for c in self.callbacks if c not in stoppers]
            if self.eval_freq > 0 and not self.optimize_hyperparameters:
                self.eval_freq = max(self.eval_freq // self.n_envs, 1)
                after_eval = None
                if stoppers:
                    after_eval = stoppers[0] if len(stoppers) == 1 else CallbackList(stoppers)
                self.callbacks.append(
                    MultiAgentEvalCallback(
                        self.create_envs(self.n_eval_episodes, eval_env=True),
                        n_eval_episodes=self.n_eval_episodes,
                        eval_freq=self.eval_freq,
                        log_path=self.save_path,
                        best_model_save_path=self.save_path,
                        deterministic=self.deterministic_eval,
                        callback_after_eval=after_eval,
                        verbose=0,
                    )
                )
            elif stoppers:
                raise ValueError("Early-stopping callbacks need evaluations: pass --eval-freq > 0")

    return MultiAgentExperimentManager


def _with_defaults(argv: list[str], defaults: dict[str, list[str]]) -> list[str]:
    present = {arg.split("=")[0] for arg in argv if arg.startswith("-")}
    extra: list[str] = []
    for flags, value in defaults.items():
        if not any(flag in present for flag in flags.split("|")):
            extra += [flags.split("|")[0], *value]
    return argv + extra


def _checkpointed_train(argv: list[str]) -> str:
    """
    ``sb3-macb train`` with ``--checkpoint-freq N`` or ``--resume RUN_FOLDER``: one run through
    :mod:`sb3_macb.zoo.experiment` (checkpoints every N steps in the run folder; resume continues the same command
    from its latest checkpoint, with evaluations identical to an uninterrupted run's).
    """
    import shlex

    import torch as th

    from sb3_macb.zoo.experiment import Experiment, ExperimentConfig, RunConfig, load_hyperparams, safe_eval

    parser = argparse.ArgumentParser(prog="sb3-macb train", description="Checkpointed training (one run).")
    parser.add_argument("--env", required=True)
    parser.add_argument("--algo", default="maddpg", choices=["maddpg"])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("-n", "--n-timesteps", type=int, default=-1)
    parser.add_argument("-f", "--log-folder", default="logs")
    parser.add_argument("-conf", "--conf-file", "-c", "--conf", dest="conf_file", default=None)
    parser.add_argument("--variant", default="")
    parser.add_argument("-params", "--hyperparams", nargs="+", default=[], metavar="KEY:VALUE")
    parser.add_argument("--env-kwargs", nargs="+", default=[], metavar="KEY:VALUE")
    parser.add_argument("--eval-freq", type=int, default=20)
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--num-threads", type=int, default=1)
    parser.add_argument("--checkpoint-freq", type=int, default=None)
    parser.add_argument("--resume", metavar="RUN_FOLDER", default=None)
    parser.add_argument("--verbose", type=int, default=1)
    parser.add_argument("-P", "--progress", action="store_true")
    parser.add_argument("--no-progress", action="store_true")
    args, unknown = parser.parse_known_args(argv)
    if unknown:
        parser.error(f"options not supported with --checkpoint-freq/--resume: {unknown}")

    def pairs(items: list[str], what: str) -> dict[str, Any]:
        result = {}
        for item in items:
            key, sep, value = item.partition(":")
            if not sep:
                parser.error(f"{what} takes KEY:VALUE pairs, got {item!r}")
            result[key] = safe_eval(value, f"{what} {key}")
        return result

    variants = [v for v in args.variant.split(",") if v]
    hyperparams = load_hyperparams(args.env, args.conf_file, variants, pairs(args.hyperparams, "-params"))
    n_timesteps = args.n_timesteps if args.n_timesteps > 0 else int(hyperparams.get("n_timesteps", 800_000))
    if args.resume:
        folder = args.resume
    else:
        base = os.path.join(args.log_folder, args.algo)
        name = args.env.split("/")[-1]
        index = 1
        while os.path.exists(os.path.join(base, f"{name}_{index}")):
            index += 1
        folder = os.path.join(base, f"{name}_{index}")
    config = ExperimentConfig(
        args.env,
        [RunConfig(seed=args.seed, folder=folder, variants=variants, hyperparams=hyperparams)],
        n_timesteps=n_timesteps,
        eval_freq=args.eval_freq,
        eval_episodes=args.eval_episodes,
        env_kwargs=pairs(args.env_kwargs, "--env-kwargs"),
        command="sb3-macb train " + " ".join(shlex.quote(a) for a in argv if a != "--resume" and a != args.resume),
    )
    th.set_num_threads(args.num_threads)
    if args.verbose:
        print(f"{'Resuming' if args.resume else 'Training'} {args.env} (seed {args.seed}, {n_timesteps} steps) in {folder}")
    Experiment(config, folder, checkpoint_freq=args.checkpoint_freq, verbose=args.verbose).run(resume=bool(args.resume))
    return folder


def train(argv: list[str] | None = None, overrides: dict[str, Any] | None = None) -> str | None:
    """
    Run ``sb3-macb train`` with these arguments (rl_zoo3's train arguments plus ``--variant``).

    :param argv: Command-line arguments (default: ``sys.argv[1:]``).
    :param overrides: Hyperparameters (dotted names allowed) applied after the variants, before ``-params``.
    :return: The run's folder (rl_zoo3's layout: ``LOGDIR/maddpg/ENV_ID_N``).
    """
    import rl_zoo3.train as zoo_train

    argv = list(sys.argv[1:] if argv is None else argv)
    if any(a.split("=")[0] in ("--checkpoint-freq", "--resume") for a in argv):
        if overrides:
            argv = [*argv, "-params", *(f"{k}:{v!r}" for k, v in overrides.items())]
        return _checkpointed_train([a for part in argv for a in (part.split("=", 1) if part.startswith("--") and "=" in part else [part])])
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--variant", default="")
    parser.add_argument("--no-progress", action="store_true")
    own, rest = parser.parse_known_args(argv)
    defaults = {
        "--algo": ["maddpg"],
        "-conf|--conf-file": [DEFAULT_CONFIG],
        "--eval-freq": ["20"],  # the paper: evaluate after every training episode
        "--eval-episodes": ["10"],
        "--gym-packages": ["sb3_macb.envs"],
        "--num-threads": ["1"],
    }
    if not own.no_progress:
        defaults["-P|--progress"] = []
    try:
        import tensorboard  # noqa: F401

        defaults["-tb|--tensorboard-log"] = [os.path.join(_log_folder(rest), "tensorboard")]
    except ImportError:
        pass
    rest = _with_defaults(rest, defaults)

    register_with_rl_zoo3()
    manager_class = _experiment_manager_class()
    manager_class.variants = [v for v in own.variant.split(",") if v]
    manager_class.overrides = dict(overrides or {})
    original, zoo_train.ExperimentManager = zoo_train.ExperimentManager, manager_class
    saved_argv = sys.argv
    try:
        sys.argv = ["sb3-macb train", *rest]
        zoo_train.train()
    finally:
        zoo_train.ExperimentManager = original
        sys.argv = saved_argv
    return manager_class.last_save_path


def _log_folder(argv: list[str]) -> str:
    for i, arg in enumerate(argv):
        if arg in ("-f", "--log-folder") and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith("--log-folder="):
            return arg.split("=", 1)[1]
    return "logs"

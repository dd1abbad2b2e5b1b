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
import contextlib
import difflib
import inspect
import io
import os
import sys
from copy import deepcopy
from pathlib import Path
from pprint import pprint
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
        from sb3_macb.zoo.experiment import ExperimentError

        raise ExperimentError(f"Unknown hyperparameter(s) in {where}: {', '.join(hints)}. Known keys: {sorted(known)}")


# Hyperparameter strings rl_zoo3 evaluates as Python, and keys whose values name classes it imports and calls
EVALUATED_KEYS = ("policy_kwargs", "replay_buffer_class", "replay_buffer_kwargs", "monitor_kwargs", "normalize")
CLASS_NAME_KEYS = ("callback", "env_wrapper", "vec_env_wrapper")
# Modules whose classes a YAML file may name without --unsafe-eval
SAFE_MODULES = ("sb3_macb.", "stable_baselines3.", "sb3_contrib.", "rl_zoo3.", "gymnasium.wrappers.", "supersuit.")

UNSAFE_HINT = "pass --unsafe-eval to evaluate hyperparameter strings as Python (only for files you trust)"


def _class_names(value: Any) -> list[str]:
    """The dotted class names in an rl_zoo3 callback/wrapper entry (a name, a {name: kwargs} dict, or a list of them)."""
    if value is None:
        return []
    if isinstance(value, str):
        return [value]
    if isinstance(value, dict):
        return [str(k) for k in value]
    if isinstance(value, list):
        return [name for item in value for name in _class_names(item)]
    return []


def make_safe(hyperparams: dict[str, Any], where: str) -> dict[str, Any]:
    """
    Parse the strings rl_zoo3 would ``eval`` with the restricted evaluator, and refuse class names outside the
    trusted libraries, so that a YAML file, a sweep config or ``-params`` cannot run code. Errors name the key.

    :param hyperparams: Hyperparameters (after variants and overrides).
    :param where: The source, for error messages.
    """
    from sb3_macb.zoo.experiment import ExperimentError, safe_eval

    result = dict(hyperparams)
    for key in EVALUATED_KEYS:
        if isinstance(result.get(key), str):
            if key == "replay_buffer_class":
                raise ExperimentError(f"{where}: '{key}' names a class as a string, which rl_zoo3 evaluates; {UNSAFE_HINT}")
            try:
                result[key] = safe_eval(result[key], f"{where}: '{key}'")
            except ExperimentError as exc:
                raise ExperimentError(f"{exc} ({UNSAFE_HINT})") from None
    for key in CLASS_NAME_KEYS:
        bad = [name for name in _class_names(result.get(key)) if not name.startswith(SAFE_MODULES)]
        if bad:
            raise ExperimentError(
                f"{where}: '{key}' names {bad}, outside the trusted libraries {list(SAFE_MODULES)}; rl_zoo3 would import "
                f"and call it. {UNSAFE_HINT}"
            )
    return result


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
        unsafe_eval = False
        last_save_path: str | None = None

        def read_hyperparameters(self) -> tuple[dict[str, Any], dict[str, Any]]:
            custom, self.custom_hyperparams = self.custom_hyperparams, None
            with contextlib.redirect_stdout(io.StringIO()):  # rl_zoo3 prints the file's entry before variants apply
                hyperparams, _ = super().read_hyperparameters()
            with open(self.config) as file:
                variants = (yaml.safe_load(file) or {}).get("variants", {}) if self.config.endswith((".yml", ".yaml")) else {}
            for name in self.variants:
                if name not in variants:
                    from sb3_macb.zoo.experiment import ExperimentError

                    raise ExperimentError(f"Unknown variant '{name}' in {self.config}; known variants: {sorted(variants)}")
                hyperparams = apply_overrides(hyperparams, variants[name])
            hyperparams = apply_overrides(hyperparams, self.overrides)
            check_hyperparams({key.split(".")[0]: None for key in custom or {}}, "-params")  # a typo there is named there
            hyperparams = apply_overrides(hyperparams, custom or {})
            check_hyperparams(hyperparams, f"{self.config} (env {self.env_name.gym_id})")
            if not self.unsafe_eval:
                hyperparams = make_safe(hyperparams, f"{self.config} (env {self.env_name.gym_id}) or -params")
            self.custom_hyperparams = custom
            saved = {key: hyperparams[key] for key in sorted(hyperparams)}
            if self.n_timesteps > 0:
                saved["n_timesteps"] = self.n_timesteps  # config.yml records the steps that run, not the file's
            if self.verbose > 0:
                used = ", ".join(self.variants) or "none"
                print(f"Hyperparameters for {self.env_name.gym_id} from {self.config} (variants: {used}; overrides and -params applied):")
                pprint(saved)
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
                        log_freq=1 if self.verbose >= 2 else 100,  # a summary every 100 evaluations; -v 2: every one
                        verbose=1 if self.verbose >= 1 else 0,
                    )
                )
            elif stoppers:
                raise ValueError("Early-stopping callbacks need evaluations: pass --eval-freq > 0")

    return MultiAgentExperimentManager


def _with_defaults(argv: list[str], defaults: dict[str, list[str]]) -> list[str]:
    """
    Append each default option that ``argv`` does not give, recognising every spelling argparse accepts for
    rl_zoo3's options (``-c``, ``--conf``, ``-conf``, ``--conf-file``, ``--conf-file=X``, ...).

    :param defaults: ``"-short|--long"`` option spellings (as rl_zoo3 defines them) to the default's values.
    """
    parser = argparse.ArgumentParser(add_help=False)
    dests = {}
    for i, flags in enumerate(defaults):
        dest = f"option_{i}"
        dests[flags] = dest
        parser.add_argument(*flags.split("|"), dest=dest, nargs="?", const=True, default=None)
    given, _ = parser.parse_known_args(argv)
    extra: list[str] = []
    for flags, value in defaults.items():
        if getattr(given, dests[flags]) is None:
            extra += [flags.split("|")[-1], *value]
    return argv + extra


def _safe_store_dict(unsafe: bool) -> type:
    """rl_zoo3's ``StoreDict`` (KEY:VALUE options), parsing the values with the restricted evaluator."""
    from rl_zoo3.utils import StoreDict

    from sb3_macb.zoo.experiment import ExperimentError, safe_eval

    class SafeStoreDict(StoreDict):
        def __call__(self, parser: Any, namespace: Any, values: Any, option_string: Any = None) -> None:
            if unsafe:
                return super().__call__(parser, namespace, values, option_string)
            result = {}
            for item in values:
                key, _, text = item.partition(":")
                try:
                    result[key] = safe_eval(text, f"{option_string} {key}")
                except ExperimentError as exc:
                    raise ExperimentError(f"{exc} ({UNSAFE_HINT})") from None
            setattr(namespace, self.dest, result)

    return SafeStoreDict


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
        command="sb3-macb train " + " ".join(shlex.quote(a) for a in argv),
    )
    th.set_num_threads(args.num_threads)
    if args.verbose:
        print(f"{'Resuming' if args.resume else 'Training'} {args.env} (seed {args.seed}, {n_timesteps} steps) in {folder}")
    Experiment(config, folder, checkpoint_freq=args.checkpoint_freq, verbose=args.verbose).run(resume=bool(args.resume))
    return folder


TRAIN_HELP = """sb3-macb train: rl_zoo3's train with MADDPG registered; its options follow. sb3_macb adds:
  --variant NAME[,NAME...]   named overrides from the YAML file's 'variants' section (e.g. maddpg,fast)
  --no-progress              no progress bar
  --unsafe-eval              evaluate hyperparameter strings (YAML, -params, --env-kwargs) as Python, as rl_zoo3
                             does; by default they are parsed without running code (literals, dict(...), nn.ReLU...)
  --checkpoint-freq N        checkpoint every N steps into the run folder (a checkpointed run: see README)
  --resume RUN_FOLDER        continue a checkpointed run from its latest checkpoint (same command)
"""


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
        return _checkpointed_train(argv)
    if any(a in ("-h", "--help") for a in argv):
        print(TRAIN_HELP)
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--variant", default="")
    parser.add_argument("--no-progress", action="store_true")
    parser.add_argument("--unsafe-eval", action="store_true")
    own, rest = parser.parse_known_args(argv)
    given_conf = argparse.ArgumentParser(add_help=False)
    given_conf.add_argument("-conf", "--conf-file", dest="conf_file", default=None)
    conf_file = given_conf.parse_known_args(rest)[0].conf_file
    if conf_file is not None and not own.unsafe_eval and not str(conf_file).endswith((".yml", ".yaml")):
        from sb3_macb.zoo.experiment import ExperimentError

        raise ExperimentError(f"--conf-file {conf_file!r} is not a .yml/.yaml file; rl_zoo3 would import it as Python. {UNSAFE_HINT}")
    defaults = {
        "--algo": ["maddpg"],
        "-conf|--conf-file": [DEFAULT_CONFIG],
        "--eval-freq": ["20"],  # the paper: evaluate after every training episode
        "--eval-episodes": ["10"],
        "--gym-packages": ["sb3_macb.envs"],
        "--num-threads": ["1"],
        "--log-interval": ["100"],  # SB3's table every 100 training episodes (its default, 4, prints 10,000 tables)
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
    manager_class.unsafe_eval = own.unsafe_eval
    original, zoo_train.ExperimentManager = zoo_train.ExperimentManager, manager_class
    original_store, zoo_train.StoreDict = zoo_train.StoreDict, _safe_store_dict(own.unsafe_eval)
    saved_argv = sys.argv
    try:
        sys.argv = ["sb3-macb train", *rest]
        zoo_train.train()
    finally:
        zoo_train.ExperimentManager = original
        zoo_train.StoreDict = original_store
        sys.argv = saved_argv
    return manager_class.last_save_path


def _log_folder(argv: list[str]) -> str:
    for i, arg in enumerate(argv):
        if arg in ("-f", "--log-folder") and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith("--log-folder="):
            return arg.split("=", 1)[1]
    return "logs"

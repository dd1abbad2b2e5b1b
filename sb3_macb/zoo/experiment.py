"""
Experiments that survive interruption and pack many runs into one process.

An experiment is one env id and one or more runs (a seed, variants of the zoo YAML, a folder for the run's
files). Runs whose hyperparameters differ only in :data:`PACKABLE` keys (MACB's settings, the noise scale) are
trained together as one ``MADDPG(n_runs=K)`` pack; each run is the same experiment it would be alone (same
random streams, bit for bit on CPU). The experiment folder holds ``experiment.json`` (what is run) and
``checkpoint/`` (the latest complete checkpoint: model with optimizer and MACB states, replay buffer, the envs'
states, the evaluation history and every random generator), from which :func:`resume` continues so that the
evaluations are identical, array for array, to an uninterrupted run's.

    python -m sb3_macb.zoo.experiment --resume FOLDER      # continue any experiment folder

``sb3-macb train ... --checkpoint-freq N`` / ``--resume RUN_FOLDER`` and the paper study's
``experiments/macb_paper/scripts/reproduce.py`` use it.
"""

import argparse
import ast
import difflib
import inspect
import json
import os
import pickle
import random
import shutil
import sys
import time
from collections.abc import Callable
from copy import deepcopy
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch as th
import yaml
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.logger import configure
from stable_baselines3.common.noise import ActionNoise, NormalActionNoise, OrnsteinUhlenbeckActionNoise
from torch import nn

import sb3_macb
import sb3_macb.envs  # noqa: F401  (registers the task ids)
from sb3_macb.callbacks import MultiAgentEvalCallback, _SuccessRateStop, make_eval_vec_env
from sb3_macb.common.atomic import AtomicWriteError, atomic_write, remove_leftovers
from sb3_macb.common.snapshot import restore, snapshot
from sb3_macb.envs.vec_tasks import make_task_vec_env
from sb3_macb.maddpg import MADDPG, Pack


def zoo_folder(name: str) -> str:
    """
    A folder of the YAML files shipped with sb3_macb (``"hyperparams"`` or ``"sweeps"``): inside the installed package
    (``sb3_macb/zoo/<name>``, where a wheel puts them), else the top-level ``zoo/<name>`` of the checkout that this
    package is imported from (an editable install, or a run from the repository root).

    :param name: ``"hyperparams"`` or ``"sweeps"``.
    """
    here = os.path.dirname(os.path.abspath(__file__))
    installed = os.path.join(here, name)
    if os.path.isdir(installed):
        return installed
    return os.path.join(os.path.dirname(os.path.dirname(here)), "zoo", name)


DEFAULT_CONFIG = os.path.join(zoo_folder("hyperparams"), "maddpg.yml")
DEFAULT_TIMESTEPS = 800_000  # steps per run where neither the command nor the YAML entry says: the paper's 4e4 episodes of 20
EXPERIMENT_FILE = "experiment.json"
CHECKPOINT_DIR = "checkpoint"
MODELS_DIR = "models"  # every checkpoint's model, with keep_models

# Hyperparameters that may differ between the runs of one pack; everything else must be equal
PACKABLE = ("exploration", "noise_std")
# rl_zoo3 keys the experiment runner does not support (they wrap the env in ways a checkpoint cannot restore exactly)
UNSUPPORTED = ("normalize", "env_wrapper", "vec_env_wrapper", "frame_stack", "normalize_kwargs", "monitor_kwargs")
# Hyperparameter strings rl_zoo3 evaluates as Python (parsed here by :func:`safe_eval`, or by ``eval`` when asked)
EVALUATED_KEYS = ("policy_kwargs", "replay_buffer_class", "replay_buffer_kwargs")
# The callback classes a YAML ``callback:`` entry may name without ``unsafe_eval`` (exact names), each with the
# keyword arguments that name a folder to write to: those must be relative and stay inside the run's folder
SAFE_CALLBACKS: dict[str, tuple[str, ...]] = {
    "sb3_macb.callbacks.StopTrainingOnSuccessRate": (),
    "sb3_macb.callbacks.StopTrainingOnNoSuccessImprovement": (),
    "stable_baselines3.common.callbacks.StopTrainingOnMaxEpisodes": (),
    "stable_baselines3.common.callbacks.ProgressBarCallback": (),
    "stable_baselines3.common.callbacks.CheckpointCallback": ("save_path",),
    "rl_zoo3.callbacks.RawStatisticsCallback": (),
}
UNSAFE_HINT = "pass --unsafe-eval to evaluate hyperparameter strings as Python (only for files you trust)"


class ExperimentError(ValueError):
    """A user's mistake in an experiment's settings or folder (reported in one line by the command line)."""


# --- hyperparameter strings, without running code ----------------------------------------------------------------

_SAFE_NAMES: dict[str, Any] = {
    **{f"{prefix}{name}": getattr(nn, name) for prefix in ("nn.", "th.nn.", "torch.nn.") for name in
       ("ReLU", "Tanh", "ELU", "LeakyReLU", "SiLU", "GELU", "Sigmoid", "Softplus", "Identity")},
    **{f"{prefix}{name}": getattr(th.optim, name) for prefix in ("th.optim.", "torch.optim.") for name in
       ("Adam", "AdamW", "SGD", "RMSprop")},
}  # fmt: skip


def safe_eval(text: str, where: str) -> Any:
    """
    Evaluate a hyperparameter string such as ``"dict(net_arch=[400, 300], activation_fn=nn.Tanh)"`` without running
    code: literals, lists, tuples, dicts, ``dict(...)`` calls and a fixed list of names (activation functions and
    optimizers from ``torch``) are accepted; anything else is refused with an error naming ``where``.

    :param text: The string from a YAML file or the command line.
    :param where: What the string is (e.g. ``"policy_kwargs in maddpg.yml"``), for the error message.
    """

    def convert(node: ast.AST) -> Any:
        if isinstance(node, ast.Constant):
            return node.value
        if isinstance(node, (ast.List, ast.Tuple)):
            values = [convert(e) for e in node.elts]
            return values if isinstance(node, ast.List) else tuple(values)
        if isinstance(node, ast.Dict):
            return {convert(k): convert(v) for k, v in zip(node.keys, node.values)}  # type: ignore[arg-type]
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub) and isinstance(node.operand, ast.Constant):
            value = node.operand.value
            if isinstance(value, (int, float)) and not isinstance(value, bool):  # a negative number, nothing else
                return -value
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "dict" and not node.args:
            return {kw.arg: convert(kw.value) for kw in node.keywords if kw.arg is not None}
        if isinstance(node, (ast.Attribute, ast.Name)):
            name = ast.unparse(node)
            if name in _SAFE_NAMES:
                return _SAFE_NAMES[name]
        raise ExperimentError(
            f"{where}: '{ast.unparse(node)}' is not allowed in a hyperparameter string (literals, lists, dicts, dict(...) "
            f"and {sorted(_SAFE_NAMES)} are). Use rl_zoo3's own train command if you need arbitrary Python."
        )

    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise ExperimentError(f"{where}: cannot parse {text!r}: {exc.msg}") from None
    return convert(tree.body)


# --- hyperparameters from the zoo YAML -----------------------------------------------------------------------------


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
        raise ExperimentError(f"Unknown hyperparameter(s) in {where}: {', '.join(hints)}. Known keys: {sorted(known)}")


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


def load_hyperparams(
    env_id: str,
    conf_file: str | None = None,
    variants: tuple[str, ...] | list[str] = (),
    overrides: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """
    The env's entry of a zoo YAML file with variants and overrides applied (dotted keys set nested values), checked
    for unknown keys.

    :param env_id: The env id (a top-level key of the file).
    :param conf_file: The YAML file (default: the package's ``maddpg.yml``).
    :param variants: Names from the file's ``variants`` section, applied in order.
    :param overrides: Hyperparameters applied last.
    """
    conf_file = conf_file or DEFAULT_CONFIG
    try:
        with open(conf_file, "rb") as file:
            config = yaml.safe_load(file.read().decode("utf-8")) or {}
    except OSError as exc:
        raise ExperimentError(f"cannot read the hyperparameter file {conf_file}: {exc.strerror}") from None
    except (UnicodeDecodeError, yaml.YAMLError) as exc:
        where = getattr(exc, "problem_mark", None)
        line = f" (line {where.line + 1})" if where is not None else ""
        raise ExperimentError(f"the hyperparameter file {conf_file} is not valid YAML{line}: {type(exc).__name__}") from None
    if not isinstance(config, dict):
        raise ExperimentError(f"the hyperparameter file {conf_file} is not a YAML mapping of env ids to hyperparameters")
    if env_id not in config:
        envs = sorted(k for k in config if k != "variants")
        raise ExperimentError(f"{conf_file} has no entry for env '{env_id}'; it has {envs}")
    hyperparams = deepcopy(config[env_id])
    known = config.get("variants") or {}
    if (
        not isinstance(hyperparams, dict)
        or not isinstance(known, dict)
        or not all(isinstance(v, dict) for v in known.values())
    ):
        raise ExperimentError(f"{conf_file}: the entry of '{env_id}' and each variant must be a mapping of hyperparameters")
    for name in variants:
        if name not in known:
            raise ExperimentError(f"Unknown variant '{name}' in {conf_file}; known variants: {sorted(known)}")
        hyperparams = apply_overrides(hyperparams, known[name])
    hyperparams = apply_overrides(hyperparams, overrides or {})
    try:
        check_hyperparams(hyperparams, f"{conf_file} (env {env_id})")
    except ValueError as exc:
        raise ExperimentError(str(exc)) from None
    return hyperparams


def _action_noise(hyperparams: dict[str, Any], action_dim: int) -> ActionNoise | None:
    kind, std = hyperparams.get("noise_type"), hyperparams.get("noise_std", 0.0)
    if kind is None:
        return None
    mean, sigma = np.zeros(action_dim), float(std) * np.ones(action_dim)
    if kind == "normal":
        return NormalActionNoise(mean, sigma)
    if kind == "ornstein-uhlenbeck":
        return OrnsteinUhlenbeckActionNoise(mean, sigma)
    raise ExperimentError(f"noise_type must be 'normal' or 'ornstein-uhlenbeck', got {kind!r}")


def evaluate_string(text: str, where: str, unsafe_eval: bool = False) -> Any:
    """
    A hyperparameter string's value: :func:`safe_eval`, or Python's ``eval`` (as rl_zoo3 does) with ``unsafe_eval``.

    :param text: The string.
    :param where: What it is, for error messages.
    :param unsafe_eval: Evaluate it as Python (only for files the user trusts and asked for explicitly).
    """
    if not unsafe_eval:
        try:
            return safe_eval(text, where)
        except ExperimentError as exc:
            raise ExperimentError(f"{exc} ({UNSAFE_HINT})") from None
    import stable_baselines3 as sb3

    namespace = {"nn": nn, "th": th, "torch": th, "np": np, "sb3": sb3}
    try:
        return eval(text, namespace)  # noqa: S307 (the user asked for it with --unsafe-eval)
    except Exception as exc:  # noqa: BLE001
        raise ExperimentError(f"{where}: evaluating {text!r} failed: {type(exc).__name__}: {exc}") from None


def callback_entries(value: Any) -> list[tuple[str, dict[str, Any]]]:
    """The (dotted class name, kwargs) pairs of a YAML ``callback:`` entry (a name, a {name: kwargs} dict, or a list)."""
    if value is None:
        return []
    if isinstance(value, str):
        return [(value, {})]
    if isinstance(value, dict):
        return [(str(name), dict(kwargs or {})) for name, kwargs in value.items()]
    if isinstance(value, list):
        return [entry for item in value for entry in callback_entries(item)]
    raise ExperimentError(f"'callback' must be a class name, a {{name: kwargs}} dict or a list of them, got {value!r}")


def make_callbacks(hyperparams: dict[str, Any], unsafe_eval: bool = False, folder: str | None = None) -> list[BaseCallback]:
    """
    The callbacks a run's ``callback:`` hyperparameter names (rl_zoo3's format), built. Only the classes of
    :data:`SAFE_CALLBACKS` are allowed unless ``unsafe_eval``, and the folders they write to are relative paths
    inside the run's ``folder``; anything else is refused with an error that names the key and what is allowed.

    :param hyperparams: The run's hyperparameters.
    :param unsafe_eval: Allow any class, with its arguments as given.
    :param folder: The run's folder, which the callbacks' relative paths are joined to (None: only checked).
    """
    import importlib

    callbacks = []
    for name, kwargs in callback_entries(hyperparams.get("callback")):
        if not unsafe_eval:
            if name not in SAFE_CALLBACKS:
                raise ExperimentError(
                    f"'callback' names {name!r}, which is not one of the allowed callbacks {sorted(SAFE_CALLBACKS)}: "
                    f"building it would import and call it. {UNSAFE_HINT}"
                )
            for key in SAFE_CALLBACKS[name]:
                if key in kwargs:
                    kwargs[key] = _inside_run_folder(kwargs[key], f"'callback' {name} {key}", folder)
        module_name, _, class_name = name.rpartition(".")
        try:
            cls = getattr(importlib.import_module(module_name), class_name)
        except (ImportError, AttributeError, ValueError):
            raise ExperimentError(f"'callback' names {name!r}, which cannot be imported") from None
        if not (isinstance(cls, type) and issubclass(cls, BaseCallback)):
            raise ExperimentError(f"'callback' names {name!r}, which is not an SB3 callback class")
        try:
            callbacks.append(cls(**kwargs))
        except (TypeError, ValueError) as exc:
            raise ExperimentError(f"'callback' {name}: {exc}") from None
    return callbacks


def _inside_run_folder(value: Any, where: str, folder: str | None) -> str:
    """``value`` (a relative path that stays inside the run's folder) joined to ``folder``."""
    if (
        not isinstance(value, str)
        or not value
        or os.path.isabs(value)
        or os.path.normpath(value).split(os.sep)[0] == os.pardir
    ):
        raise ExperimentError(f"{where} must be a relative path inside the run's folder, got {value!r}")
    return os.path.join(folder or ".", value)


def check_values(hyperparams: dict[str, Any], where: str) -> None:
    """
    Refuse hyperparameter values that cannot make a sensible run (``gamma: 2``, ``batch_size: 0``, ...) with one
    line naming the key and what is allowed. Values given as strings to be evaluated are checked when built.

    :param hyperparams: A run's hyperparameters.
    :param where: Where they come from, for the message.
    """

    def number(key: str, low: float, high: float | None = None, integer: bool = False, low_open: bool = False,
               allowed: str = "") -> None:  # fmt: skip
        if key not in hyperparams or hyperparams[key] is None:
            return
        value = hyperparams[key]
        kind = (int, np.integer) if integer else (int, float, np.integer, np.floating)
        ok = isinstance(value, kind) and not isinstance(value, bool) and np.isfinite(value)
        ok = ok and (value > low if low_open else value >= low) and (high is None or value <= high)
        if not ok:
            raise ExperimentError(f"{where}: '{key}' must be {allowed}, got {value!r}")

    number("gamma", 0.0, 1.0, low_open=True, allowed="a number in (0, 1]")
    number("tau", 0.0, 1.0, allowed="a number in [0, 1]")
    number("batch_size", 1, integer=True, allowed="an integer >= 1")
    number("buffer_size", 1, integer=True, allowed="an integer >= 1")
    number("learning_starts", 0, integer=True, allowed="an integer >= 0")
    number("n_envs", 1, integer=True, allowed="an integer >= 1")
    number("policy_delay", 1, integer=True, allowed="an integer >= 1")
    number("gradient_steps", -1, integer=True, allowed="an integer >= -1 (-1: as many as steps)")
    number("noise_std", 0.0, allowed="a number >= 0")
    number("target_policy_noise", 0.0, allowed="a number >= 0")
    number("target_noise_clip", 0.0, allowed="a number >= 0")
    number("n_timesteps", 1, allowed="a number >= 1")
    if isinstance(hyperparams.get("learning_rate"), str):
        linear_schedule_of(hyperparams["learning_rate"], f"{where}: 'learning_rate'", low_open=True)
    else:
        number("learning_rate", 0.0, low_open=True, allowed="a number > 0 or 'lin_<number>'")
    train_freq = hyperparams.get("train_freq", 1)
    steps = train_freq[0] if isinstance(train_freq, (list, tuple)) and len(train_freq) == 2 else train_freq
    unit = train_freq[1] if isinstance(train_freq, (list, tuple)) and len(train_freq) == 2 else "step"
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1 or unit not in ("step", "episode"):
        raise ExperimentError(f"{where}: 'train_freq' must be an integer >= 1 or [N, 'step' | 'episode'], got {train_freq!r}")
    if hyperparams.get("policy", "MlpPolicy") != "MlpPolicy":
        raise ExperimentError(f"{where}: 'policy' must be 'MlpPolicy' (MADDPG's only policy), got {hyperparams['policy']!r}")
    if hyperparams.get("noise_type") not in (None, "normal", "ornstein-uhlenbeck"):
        raise ExperimentError(
            f"{where}: 'noise_type' must be 'normal', 'ornstein-uhlenbeck' or null, got {hyperparams['noise_type']!r}"
        )
    if not valid_device(hyperparams.get("device", "auto")):
        raise ExperimentError(
            f"{where}: 'device' must be 'auto' or a torch device such as 'cpu' or 'cuda', got {hyperparams['device']!r}"
        )
    exploration = hyperparams.get("exploration")
    if exploration is not None:
        from sb3_macb.exploration.estimators import make_exploration

        exploration = exploration_with_schedules(exploration, where)
        try:
            make_exploration(exploration)
        except (TypeError, ValueError) as exc:
            raise ExperimentError(f"{where}: 'exploration': {exc}") from None


def linear_schedule_of(value: str, where: str, low_open: bool = False) -> Callable[[float], float]:
    """
    rl_zoo3's string form of a linear schedule, ``lin_<number>`` (from the number down to 0 over training), parsed
    without evaluating anything.

    :param value: The string.
    :param where: What the value is, for the error message.
    :param low_open: Whether the number must be > 0 (else >= 0).
    """
    from rl_zoo3.utils import linear_schedule

    try:
        start = float(value[4:]) if value.startswith("lin_") else None
    except ValueError:
        start = None
    if start is None or not np.isfinite(start) or (start <= 0 if low_open else start < 0):
        raise ExperimentError(f"{where} must be a number {'> 0' if low_open else '>= 0'} or 'lin_<number>', got {value!r}")
    return linear_schedule(start)


def exploration_with_schedules(exploration: Any, where: str) -> Any:
    """The exploration setting with a ``lin_<number>`` beta turned into its schedule (other values as given)."""
    if isinstance(exploration, dict) and isinstance(exploration.get("beta"), str):
        return {**exploration, "beta": linear_schedule_of(exploration["beta"], f"{where}: 'exploration.beta'")}
    return exploration


def valid_device(device: Any) -> bool:
    """Whether ``device`` is ``"auto"`` or a name torch takes as a device (``cpu``, ``cuda``, ``cuda:1``, ...)."""
    try:
        return device == "auto" or th.device(device) is not None
    except (RuntimeError, TypeError):
        return False


def unsupported_keys(hyperparams: dict[str, Any]) -> list[str]:
    """The :data:`UNSUPPORTED` keys that ``hyperparams`` uses (``normalize: false``, ``frame_stack: 1`` and empty
    wrappers change nothing and are not counted)."""

    def used(key: str) -> bool:
        value = hyperparams.get(key)
        return not (
            value is None
            or value is False
            or value == {}
            or value == []
            or (key == "frame_stack" and type(value) is int and value == 1)
        )

    return [key for key in UNSUPPORTED if used(key)]


def model_kwargs(hyperparams: dict[str, Any], unsafe_eval: bool = False) -> dict[str, Any]:
    """
    MADDPG's keyword arguments from a run's hyperparameters (strings parsed safely, zoo keys removed).

    :param hyperparams: The run's hyperparameters.
    :param unsafe_eval: Evaluate strings as Python, as rl_zoo3 does.
    """
    bad = unsupported_keys(hyperparams)
    if bad:
        raise ExperimentError(
            f"{bad}: rl_zoo3 options that sb3_macb's runs do not support (they wrap the env in ways a checkpoint cannot "
            f"restore); remove them (from the YAML entry or -params)"
        )
    dropped = ("n_timesteps", "policy", "noise_type", "noise_std", "callback", "n_envs", *UNSUPPORTED)
    kwargs = {k: v for k, v in hyperparams.items() if k not in dropped}
    for key, value in list(kwargs.items()):
        if isinstance(value, str) and key not in ("device",):
            if key == "learning_rate":
                kwargs[key] = linear_schedule_of(value, "hyperparameter 'learning_rate'", low_open=True)
            elif key == "replay_buffer_class" and not unsafe_eval:
                raise ExperimentError(
                    f"hyperparameter '{key}' names a class as a string, which would be evaluated; {UNSAFE_HINT}"
                )
            else:
                kwargs[key] = evaluate_string(value, f"hyperparameter '{key}'", unsafe_eval)
    if "exploration" in kwargs:
        kwargs["exploration"] = exploration_with_schedules(kwargs["exploration"], "hyperparameter")
    if isinstance(kwargs.get("train_freq"), list):
        kwargs["train_freq"] = tuple(kwargs["train_freq"])
    policy_kwargs = kwargs.get("policy_kwargs")
    if policy_kwargs is not None and not isinstance(policy_kwargs, dict):
        raise ExperimentError(f"hyperparameter 'policy_kwargs' must be a dict, got {policy_kwargs!r}")
    if policy_kwargs and "net_arch" in policy_kwargs:
        _check_net_arch(policy_kwargs["net_arch"])
    return kwargs


def _check_net_arch(net_arch: Any) -> None:
    def layers(value: Any) -> bool:
        return isinstance(value, (list, tuple)) and all(
            isinstance(n, int) and not isinstance(n, bool) and n >= 1 for n in value
        )

    if not (
        layers(net_arch)
        or (isinstance(net_arch, dict) and set(net_arch) <= {"pi", "qf"} and all(map(layers, net_arch.values())))
    ):
        raise ExperimentError(
            "policy_kwargs 'net_arch' must be a list of layer sizes (integers >= 1) or dict(pi=[...], qf=[...]), "
            f"got {net_arch!r}"
        )


# --- the experiment --------------------------------------------------------------------------------------------------


@dataclass
class RunConfig:
    """
    One run of an experiment.

    :param seed: The run's seed.
    :param folder: Where its ``evaluations.npz``, ``config.yml``, ``run.json`` and final ``model.zip`` go.
    :param variants: Variants of the zoo YAML it was built from (recorded).
    :param hyperparams: Its hyperparameters (variants and overrides applied).
    """

    seed: int
    folder: str
    variants: list[str] = field(default_factory=list)
    hyperparams: dict[str, Any] = field(default_factory=dict)


def make_run(
    env_id: str,
    seed: int,
    folder: str,
    variants: list[str] | tuple[str, ...] = (),
    overrides: dict[str, Any] | None = None,
    conf_file: str | None = None,
    n_timesteps: int | None = None,
) -> tuple[RunConfig, int]:
    """
    One run of ``env_id`` from the zoo YAML (the one function that turns settings into a run, for ``sb3-macb
    train``, the sweep and scripts): its hyperparameters (the env's entry with ``variants`` and ``overrides``
    applied, see :func:`load_hyperparams`) and its steps.

    :param env_id: The env id (a top-level key of the YAML file).
    :param seed: The run's seed.
    :param folder: The run's folder.
    :param variants: Names from the file's ``variants`` section, applied in order.
    :param overrides: Hyperparameters applied last.
    :param conf_file: The YAML file (default: the package's ``maddpg.yml``).
    :param n_timesteps: Steps per run; None: the entry's ``n_timesteps``, else :data:`DEFAULT_TIMESTEPS`.
    :return: The run and its steps.
    """
    hyperparams = load_hyperparams(env_id, conf_file, list(variants), overrides)
    steps = int(n_timesteps if n_timesteps is not None else hyperparams.get("n_timesteps", DEFAULT_TIMESTEPS))
    return RunConfig(seed=int(seed), folder=folder, variants=list(variants), hyperparams=hyperparams), steps


@dataclass
class ExperimentConfig:
    """
    What an experiment runs: stored as ``experiment.json`` in its folder and compared on resume.

    :param env_id: A registered env id.
    :param runs: The runs, trained as one pack.
    :param n_timesteps: Environment steps per run.
    :param eval_freq: Evaluate every this many steps (per run).
    :param eval_episodes: Episodes per evaluation (per run).
    :param env_kwargs: Keyword arguments for the env.
    :param command: The command line that started it (recorded in each run's ``run.json``).
    :param unsafe_eval: Evaluate hyperparameter strings as Python and allow callbacks from any module (only for
        files the user trusts and asked for explicitly); by default they are parsed by :func:`safe_eval`.
    """

    env_id: str
    runs: list[RunConfig]
    n_timesteps: int
    eval_freq: int = 20
    eval_episodes: int = 10
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    command: str = ""
    unsafe_eval: bool = False

    def __post_init__(self) -> None:
        self.runs = [r if isinstance(r, RunConfig) else RunConfig(**r) for r in self.runs]
        if not self.runs:
            raise ExperimentError("An experiment needs at least one run")
        # rl_zoo3 lets the YAML entry carry the env's kwargs; the command line's win. A pack's runs share one env, so
        # their YAML env kwargs must agree (merging them would give every run the union, silently)
        yaml_env_kwargs = [run.hyperparams.pop("env_kwargs", None) or {} for run in self.runs]
        for run, kwargs in zip(self.runs[1:], yaml_env_kwargs[1:]):
            if kwargs != yaml_env_kwargs[0]:
                raise ExperimentError(
                    f"Runs of one pack share one env, but their env_kwargs differ: seed {self.runs[0].seed} "
                    f"{self.runs[0].variants} has {yaml_env_kwargs[0]}, seed {run.seed} {run.variants} has {kwargs}; "
                    f"run them in separate packs"
                )
        if yaml_env_kwargs[0]:
            self.env_kwargs = {**yaml_env_kwargs[0], **self.env_kwargs}
        if self.n_timesteps < 1 or self.eval_freq < 0 or self.eval_episodes < 1:
            raise ExperimentError("n_timesteps and eval_episodes must be >= 1 and eval_freq >= 0")
        for run in self.runs:  # bad settings are refused here, before anything is written or run
            check_values({**run.hyperparams, "n_timesteps": self.n_timesteps}, f"seed {run.seed} {run.variants}")
            model_kwargs(run.hyperparams, self.unsafe_eval)
            make_callbacks(run.hyperparams, self.unsafe_eval)
        if len(self.runs) > 1:
            for key in ("callback", "n_envs"):
                if any(r.hyperparams.get(key) not in (None, 1, []) for r in self.runs):
                    raise ExperimentError(f"'{key}' is supported for single runs, not for packs of {len(self.runs)} runs")
        common = [_pack_key(r.hyperparams) for r in self.runs]
        if any(key != common[0] for key in common):
            first = self.runs[0].hyperparams
            for run in self.runs[1:]:
                diff = sorted(
                    k
                    for k in set(first) | set(run.hyperparams)
                    if k not in PACKABLE and first.get(k) != run.hyperparams.get(k)
                )
                if diff:
                    raise ExperimentError(
                        f"Runs of one pack may differ only in {list(PACKABLE)}; "
                        f"seed {run.seed} {run.variants} differs in {diff}"
                    )

    def comparable(self) -> dict[str, Any]:
        """The settings that must not change on resume (everything but the command line and the folders)."""
        return comparable_settings(asdict(self))


def comparable_settings(config: dict[str, Any]) -> dict[str, Any]:
    """
    The settings of an :class:`ExperimentConfig` (as a dict, e.g. read from ``experiment.json``) that must not change
    on resume: everything but the command line and where the folders are (a folder may be moved or copied).
    """
    data = json.loads(json.dumps(config, default=repr))
    data.pop("command", None)
    if not data.get("unsafe_eval"):
        data.pop("unsafe_eval", None)  # as checkpoints written before the option existed have it
    for run in data.get("runs", []):
        if isinstance(run, dict):
            run.pop("folder", None)
    return data


def settings_diff(old: Any, new: Any, where: str = "") -> list[str]:
    """
    The differences between two settings trees as ``key: old -> new`` lines, keys dotted (``runs[0].seed``).

    :param old: The recorded settings.
    :param new: The settings given now.
    :param where: The key of ``old`` and ``new`` (for the recursion).
    """
    if isinstance(old, dict) and isinstance(new, dict):
        return [
            line
            for key in sorted(set(old) | set(new), key=str)
            for line in settings_diff(
                old.get(key, "(absent)"), new.get(key, "(absent)"), f"{where}.{key}" if where else str(key)
            )
        ]
    if isinstance(old, list) and isinstance(new, list) and len(old) == len(new):
        return [line for i, (a, b) in enumerate(zip(old, new)) for line in settings_diff(a, b, f"{where}[{i}]")]
    return [] if old == new else [f"{where}: {old!r} -> {new!r}"]


def _pack_key(hyperparams: dict[str, Any]) -> str:
    return json.dumps({k: v for k, v in hyperparams.items() if k not in PACKABLE}, sort_keys=True, default=repr)


class _Checkpointer(BaseCallback):
    """Saves a checkpoint at the start of a rollout (between two steps, nothing half-done) every ``freq`` steps per run."""

    def __init__(self, experiment: "Experiment", freq: int | None):
        super().__init__()
        self.experiment = experiment
        self.freq = freq

    def _on_rollout_start(self) -> None:
        steps = self.model.run_timesteps  # type: ignore[attr-defined]
        if self.freq and steps // self.freq > self.experiment.last_checkpoint // self.freq:
            self.experiment.save_checkpoint()

    def _on_step(self) -> bool:
        return True


class Experiment:
    """
    Runs an :class:`ExperimentConfig` in ``folder`` as one pack, with checkpoints every ``checkpoint_freq`` steps.

    :param config: What to run.
    :param folder: The experiment's folder (``experiment.json`` and ``checkpoint/``).
    :param checkpoint_freq: Steps per run between checkpoints (None: no checkpoints).
    :param keep_checkpoint: Keep the last checkpoint when the experiment ends (by default it is deleted: the replay
        buffer makes it large).
    :param keep_models: Also keep every checkpoint's model (the pack's ``model.zip``, without the replay buffer) as
        ``models/step_<N>.zip`` in ``folder``, for looking inside a run as it went (the checkpoint folder holds only
        the latest). Each is the size of one model of the pack (26 MB for three 400-300 runs).
    :param verbose: 1 prints a line per checkpoint and at the end.
    :param progress_bar: Show SB3's progress bar.
    :param tensorboard_log: Folder for TensorBoard logs (None: none). The experiment logs into the subfolder named
        like its own folder (``<tensorboard_log>/<basename of folder>``), and a resumed one continues there.
    :param log_interval: Print SB3's training table every this many training episodes (None: never).
    :param eval_log_freq: Print an evaluation summary every this many evaluations (1: SB3's table after each;
        None: nothing).
    :param save_best: Keep ``best_model.zip`` (by success rate) in the run's folder (single runs only).
    :param callbacks: Callbacks run at every step beside the YAML's (e.g. a sweep worker's check of its storage);
        not part of the experiment's settings.
    :param monitor: Write each run's training episodes to ``monitor.csv`` in its folder (SB3's Monitor format; see
        :class:`~sb3_macb.callbacks.MultiAgentEvalCallback`).
    """

    def __init__(self, config: ExperimentConfig, folder: str, checkpoint_freq: int | None = None,
                 keep_checkpoint: bool = False, verbose: int = 1, progress_bar: bool = False,
                 tensorboard_log: str | None = None, log_interval: int | None = None, eval_log_freq: int | None = None,
                 save_best: bool = False, keep_models: bool = False, callbacks: list[BaseCallback] | None = None,
                 monitor: bool = False):  # fmt: skip
        if checkpoint_freq is not None and checkpoint_freq < 1:
            raise ExperimentError(f"checkpoint_freq must be >= 1 step, got {checkpoint_freq}")
        # absolute folders: what a run writes does not depend on the working directory of a later resume
        self.folder = os.path.abspath(folder)
        for run in config.runs:
            run.folder = os.path.abspath(run.folder)
        self.config = config
        self.checkpoint_freq = checkpoint_freq
        self.keep_checkpoint = keep_checkpoint
        self.keep_models = keep_models
        self.verbose = verbose
        self.progress_bar = progress_bar
        self.tensorboard_log = tensorboard_log
        self.log_interval = log_interval
        self.eval_log_freq = eval_log_freq
        self.save_best = bool(save_best) and len(config.runs) == 1
        # (a run that wrote a monitor.csv goes on writing it, however it is resumed)
        self.monitor = monitor or any(os.path.exists(os.path.join(r.folder, "monitor.csv")) for r in config.runs)
        self.user_callbacks: list[BaseCallback] = []
        self.callbacks = list(callbacks or [])
        self.stopped_early = False
        self.model: MADDPG | None = None
        self.eval_callback: MultiAgentEvalCallback | None = None
        self.last_checkpoint = 0
        self._elapsed_before = 0.0
        self._started = time.time()

    @property
    def n_runs(self) -> int:
        return len(self.config.runs)

    @property
    def checkpoint_root(self) -> str:
        return os.path.join(self.folder, CHECKPOINT_DIR)

    def status(self) -> str:
        """``"new"``, ``"started"`` (no checkpoint yet), ``"checkpointed"`` or ``"done"``."""
        path = os.path.join(self.folder, EXPERIMENT_FILE)
        if not os.path.isfile(path):
            return "new"
        saved = _read_json(path)
        if isinstance(saved, dict) and saved.get("done"):
            return "done"
        return "checkpointed" if self._latest_checkpoint() is not None else "started"

    def _latest_checkpoint(self) -> str | None:
        """
        The name of the checkpoint to resume from: the one ``checkpoint/LATEST`` names, or, when LATEST is missing
        (a kill between writing a checkpoint and pointing to it), the newest complete ``step_N`` folder. None: none.
        A LATEST that cannot be read or names no complete checkpoint is an error naming it.
        """
        root = self.checkpoint_root
        latest = os.path.join(root, "LATEST")
        if os.path.exists(latest):
            try:
                with open(latest, "rb") as file:
                    name = file.read().decode("utf-8").strip()
            except (OSError, UnicodeDecodeError) as exc:
                raise ExperimentError(
                    f"{latest} is damaged ({type(exc).__name__}): it should hold a name like step_20000"
                ) from None
            if not (name.startswith("step_") and name[5:].isdigit()):
                raise ExperimentError(f"{latest} is damaged: it holds {name[:40]!r}, not a name like step_20000")
            if not self._complete(os.path.join(root, name)):
                raise ExperimentError(f"{latest} names {name}, but {os.path.join(root, name)} is missing or incomplete")
            return name
        try:
            names = [
                e
                for e in os.listdir(root)
                if e.startswith("step_") and e[5:].isdigit() and self._complete(os.path.join(root, e))
            ]
        except (FileNotFoundError, NotADirectoryError):
            return None
        return max(names, key=lambda e: int(e[5:])) if names else None

    @staticmethod
    def _complete(checkpoint: str) -> bool:
        return all(os.path.isfile(os.path.join(checkpoint, f)) for f in ("model.zip", "buffer.npz", "state.pkl"))

    def _remove_leftovers(self) -> None:
        """Temporary files a killed process left in the experiment's folders (see :func:`remove_leftovers`)."""
        for folder in {
            self.folder,
            self.checkpoint_root,
            os.path.join(self.folder, MODELS_DIR),
            *(r.folder for r in self.config.runs),
        }:
            remove_leftovers(folder)

    # --- building --------------------------------------------------------------------------------------------------

    @property
    def n_envs(self) -> int:
        """Envs per run: the ``n_envs`` hyperparameter of a single run (rl_zoo3's), one per run in a pack."""
        return int(self.config.runs[0].hyperparams.get("n_envs") or 1) if self.n_runs == 1 else 1

    def _build(self) -> tuple[MADDPG, MultiAgentEvalCallback]:
        cfg = self.config
        runs = cfg.runs
        kwargs = model_kwargs(runs[0].hyperparams, cfg.unsafe_eval)
        explorations = [exploration_with_schedules(r.hyperparams.get("exploration"), r.folder) for r in runs]
        kwargs.pop("exploration", None)
        env = make_task_vec_env(cfg.env_id, self.n_runs * self.n_envs, cfg.env_kwargs)
        assert env.action_space.shape is not None
        action_dim = int(np.prod(env.action_space.shape))
        noises = [_action_noise(r.hyperparams, action_dim) for r in runs]
        kwargs["learning_starts"] = Pack(self.n_runs).pack_steps(int(kwargs.get("learning_starts", 100)))  # over all envs
        model = MADDPG(
            runs[0].hyperparams.get("policy", "MlpPolicy"),
            env,
            n_runs=self.n_runs,
            run_seeds=[r.seed for r in runs],
            exploration=explorations,
            action_noise=None if noises[0] is None else noises,  # type: ignore[arg-type]
            tensorboard_log=self.tensorboard_log,
            verbose=0 if self.log_interval is None else 1,
            **kwargs,
        )
        return model, self._eval_callback(
            make_eval_vec_env(cfg.env_id, cfg.eval_episodes, [r.seed for r in runs], cfg.env_kwargs)
        )

    def _build_checked(self) -> tuple[MADDPG, MultiAgentEvalCallback]:
        """:meth:`_build`, with a setting that MADDPG, the env or the callback refuses reported in one line."""
        try:
            return self._build()
        except ExperimentError:
            raise
        except (ValueError, TypeError, KeyError, RuntimeError, AssertionError) as exc:
            message = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise ExperimentError(f"the settings cannot build this run ({type(exc).__name__}): {message}") from None

    def _eval_callback(self, eval_env: Any) -> MultiAgentEvalCallback:
        # early-stopping rules from the YAML's callback: list run after each evaluation; other callbacks every step
        self.user_callbacks = make_callbacks(
            self.config.runs[0].hyperparams, self.config.unsafe_eval, self.config.runs[0].folder
        )
        stoppers: list[BaseCallback] = [c for c in self.user_callbacks if isinstance(c, _SuccessRateStop)]
        self.user_callbacks = [c for c in self.user_callbacks if c not in stoppers]
        after_eval = None if not stoppers else stoppers[0] if len(stoppers) == 1 else CallbackList(stoppers)
        if stoppers and self.config.eval_freq == 0:
            raise ExperimentError("Early-stopping callbacks need evaluations: eval_freq must be > 0")
        return MultiAgentEvalCallback(
            eval_env,
            n_eval_episodes=self.config.eval_episodes,
            eval_freq=max(self.config.eval_freq // self.n_envs, 1) if self.config.eval_freq else 0,
            run_log_paths=[r.folder for r in self.config.runs],
            best_model_save_path=self.config.runs[0].folder if self.save_best else None,
            callback_after_eval=after_eval,
            save_freq=100,
            dump_logs=self.eval_log_freq is not None,
            log_freq=self.eval_log_freq or 1,
            verbose=0 if self.eval_log_freq is None else 1,
            warn=False,
            monitor=self.monitor,
        )

    # --- running -----------------------------------------------------------------------------------------------------

    def run(self, resume: bool = False) -> list[str]:
        """
        Train (or, with ``resume``, continue from the latest checkpoint) to the end; return the runs' folders.

        Without ``resume`` the folder must not hold an experiment yet; with it, it must hold this same experiment
        with a checkpoint (anything else is an error naming the file, never a silent fresh start).
        """
        status = self.status()
        if resume:
            self._check_same_experiment()
            if status == "done":
                if self.verbose:
                    print(f"{self.folder}: already finished")
                return [r.folder for r in self.config.runs]
            if status == "started":
                raise ExperimentError(
                    f"{self.checkpoint_root} holds no complete checkpoint: the experiment in {self.folder} stopped before "
                    f"its first checkpoint. Start it again without --resume (in a new folder, or after deleting this one)."
                )
            self._remove_leftovers()
            model, callback = self._load_checkpoint()
        else:
            if status != "new":
                raise ExperimentError(
                    f"{os.path.join(self.folder, EXPERIMENT_FILE)} exists: {self.folder} already holds an experiment "
                    f"({status}). Resume it with --resume, or choose another folder."
                )
            model, callback = self._build_checked()  # a setting that cannot build a run leaves no folder behind
            self._remove_leftovers()
            self._write_experiment_file(done=False)
        self.model, self.eval_callback = model, callback
        if self.tensorboard_log:  # (SB3 would number its own folders, and continue a resumed run in the latest one)
            formats = ["tensorboard"] if self.log_interval is None else ["stdout", "tensorboard"]
            name = os.path.basename(os.path.normpath(self.folder))
            model.set_logger(configure(os.path.join(self.tensorboard_log, name), formats))
        self._started = time.time()
        total = model.pack.pack_steps(self.config.n_timesteps)
        model.learn(
            total - model.num_timesteps,
            callback=[callback, _Checkpointer(self, self.checkpoint_freq), *self.user_callbacks, *self.callbacks],
            reset_num_timesteps=not resume,
            progress_bar=self.progress_bar,
            log_interval=self.log_interval or 4,
        )
        if model.num_timesteps < total:
            if not self.user_callbacks and callback.callback is None:
                raise RuntimeError(f"Training stopped at {model.run_timesteps} of {self.config.n_timesteps} steps")
            self.stopped_early = True  # a callback ended training (e.g. the success rate reached its threshold)
            if self.verbose:
                print(f"{self.folder}: stopped by a callback at {model.run_timesteps} steps")
        self._finish()
        return [r.folder for r in self.config.runs]

    def _finish(self) -> None:
        assert self.model is not None and self.eval_callback is not None
        self.eval_callback.save_evaluations()
        wall = self._elapsed_before + time.time() - self._started
        buffer_size_per_run = int(self.model.replay_buffer.buffer_size_per_run)
        for k, run in enumerate(self.config.runs):
            solo = self.model if self.n_runs == 1 else self.model.get_run(k)
            solo.save(os.path.join(run.folder, "model.zip"))
            with atomic_write(os.path.join(run.folder, "config.yml")) as file:
                file.write(yaml.safe_dump({"env_id": self.config.env_id, "seed": run.seed, "variants": run.variants,
                                           **run.hyperparams, "env_kwargs": dict(self.config.env_kwargs),
                                           "n_timesteps": self.config.n_timesteps,
                                           "buffer_size_per_run": buffer_size_per_run}).encode())  # fmt: skip
            info = {
                "command": self.config.command,
                "wall_time_s": round(wall, 1),
                "n_timesteps": self.config.n_timesteps,
                "variants": run.variants,
                "seed": run.seed,
                "pack_size": self.n_runs,
                "buffer_size_per_run": buffer_size_per_run,
                "complete": True,
                "stopped_early": self.stopped_early,
                "timesteps_run": self.model.run_timesteps,
                "sb3_macb": sb3_macb.__version__,
            }
            with atomic_write(os.path.join(run.folder, "run.json")) as file:
                file.write(json.dumps(info, indent=1).encode())
        self._write_experiment_file(done=True)
        if not self.keep_checkpoint:
            shutil.rmtree(self.checkpoint_root, ignore_errors=True)
        if self.verbose:
            print(f"{self.folder}: finished {self.n_runs} run(s) of {self.config.n_timesteps} steps in {wall:.0f} s")

    def _write_experiment_file(self, done: bool) -> None:
        # run folders relative to the experiment's, so that a moved or copied folder resumes into itself
        config = asdict(self.config)
        for run in config["runs"]:
            run["folder"] = os.path.relpath(run["folder"], self.folder)
        data = {"sb3_macb": sb3_macb.__version__, "done": done, "folder": self.folder, "config": config}
        with atomic_write(os.path.join(self.folder, EXPERIMENT_FILE)) as file:
            file.write(json.dumps(data, indent=1, default=repr).encode())

    def _check_same_experiment(self) -> None:
        path = os.path.join(self.folder, EXPERIMENT_FILE)
        if not os.path.isfile(path):
            raise ExperimentError(f"{path} does not exist: {self.folder} holds no experiment to resume")
        saved = read_experiment_file(path)
        _refuse_unsafe_from_file(path, saved, self.config.unsafe_eval)
        mine, theirs = self.config.comparable(), comparable_settings(saved["config"])
        if mine != theirs:
            diff = settings_diff(theirs, mine)
            raise ExperimentError(f"The settings differ from those in {path}: {'; '.join(diff)}. Resume with the same command")

    # --- checkpoints -------------------------------------------------------------------------------------------------

    def save_checkpoint(self) -> str:
        """
        Write a complete checkpoint into a new folder, then point ``checkpoint/LATEST`` at it (an atomic rename), then
        delete the older one: a process killed at any moment leaves the previous checkpoint usable.
        """
        assert self.model is not None and self.eval_callback is not None
        model = self.model
        steps = model.run_timesteps
        name = f"step_{steps}"
        root = self.checkpoint_root
        tmp = os.path.join(root, f".{name}.tmp")
        try:
            return self._write_checkpoint(name, tmp, steps)
        except OSError as exc:  # e.g. a full disk: the previous checkpoint stays what LATEST names
            shutil.rmtree(tmp, ignore_errors=True)
            reason = str(exc) if isinstance(exc, AtomicWriteError) else f"{exc.filename or tmp}: {exc.strerror or exc}"
            raise ExperimentError(f"writing the checkpoint at step {steps} failed ({reason}); the previous checkpoint "
                                  f"is kept") from None  # fmt: skip

    def _write_checkpoint(self, name: str, tmp: str, steps: int) -> str:
        assert self.model is not None and self.eval_callback is not None
        model, callback = self.model, self.eval_callback
        root = self.checkpoint_root
        shutil.rmtree(tmp, ignore_errors=True)
        os.makedirs(tmp)
        model.save(os.path.join(tmp, "model.zip"))
        with atomic_write(os.path.join(tmp, "buffer.npz")) as file:
            np.savez(file, **model.replay_buffer.state_arrays())  # type: ignore[arg-type]
        state = {
            "sb3_macb": sb3_macb.__version__,
            "config": self.config.comparable(),
            "steps": steps,
            "elapsed": self._elapsed_before + time.time() - self._started,
            "train_env": snapshot(model.env),
            "eval_env": snapshot(callback.eval_env),
            "callback": callback.get_state(),
            "rng": global_rng_states(),
        }
        with atomic_write(os.path.join(tmp, "state.pkl")) as file:
            pickle.dump(state, file, protocol=5)
        final = os.path.join(root, name)
        shutil.rmtree(final, ignore_errors=True)
        os.replace(tmp, final)
        if self.keep_models:
            models = os.path.join(self.folder, MODELS_DIR)
            os.makedirs(models, exist_ok=True)
            with (
                open(os.path.join(final, "model.zip"), "rb") as source,
                atomic_write(os.path.join(models, f"{name}.zip")) as file,
            ):
                shutil.copyfileobj(source, file)
        with atomic_write(os.path.join(root, "LATEST")) as file:
            file.write(name.encode())
        for entry in os.listdir(root):
            if entry.startswith("step_") and entry != name:
                shutil.rmtree(os.path.join(root, entry), ignore_errors=True)
        callback.save_evaluations()  # the files beside the checkpoint show the evaluations reached so far
        self.last_checkpoint = steps
        if self.verbose:
            print(f"{self.folder}: checkpoint at {steps} of {self.config.n_timesteps} steps per run", flush=True)
        return final

    def _load_checkpoint(self) -> tuple[MADDPG, MultiAgentEvalCallback]:
        root = self.checkpoint_root
        name = self._latest_checkpoint()
        if name is None:
            raise ExperimentError(f"{root} holds no complete checkpoint to resume from")
        # on the device a fresh start would use: a run started on a GPU continues on it
        device = self.config.runs[0].hyperparams.get("device", "auto")
        model, state = load_checkpoint(os.path.join(root, name), config=self.config.comparable(),
                                       experiment_file=os.path.join(self.folder, EXPERIMENT_FILE), device=device,
                                       needed_keys=("sb3_macb", "config", "steps", "elapsed", "train_env", "eval_env",
                                                    "callback", "rng"))  # fmt: skip
        callback = self._eval_callback(restore(state["eval_env"]))
        callback.set_state(state["callback"])
        restore_global_rngs(state)
        self.last_checkpoint = state["steps"]
        self._elapsed_before = state["elapsed"]
        if self.verbose:
            print(f"{self.folder}: resuming at {state['steps']} of {self.config.n_timesteps} steps per run", flush=True)
        return model, callback


def load_checkpoint(
    folder: str,
    config: dict[str, Any] | None = None,
    experiment_file: str = EXPERIMENT_FILE,
    allow_other_version: bool = False,
    device: th.device | str = "auto",
    needed_keys: tuple[str, ...] = ("train_env",),
) -> tuple[MADDPG, dict[str, Any]]:
    """
    The model of checkpoint ``folder`` with its training env and replay buffer restored, and the checkpoint's state
    (steps, elapsed time, evaluation callback state, env snapshots, random states). The global random states are not
    touched: call :func:`restore_global_rngs` when everything that precedes the resumed steps has been built.

    Checkpoints hold pickles (state.pkl, and model.zip as SB3's zips do): loading one runs code that it names, so
    load only those your own runs wrote.

    :param folder: A checkpoint folder (``checkpoint/step_N`` of an experiment).
    :param config: The experiment's comparable settings, which the checkpoint must match (None: not checked).
    :param experiment_file: The file ``config`` comes from, named in the error.
    :param allow_other_version: Accept a checkpoint written by another sb3_macb version (for diagnosis: a version
        whose arithmetic differs does not continue the run exactly).
    :param device: The torch device to load the model on ("auto": CUDA where there is one, as a fresh run's default).
    :param needed_keys: What ``state.pkl`` must hold (a resume needs all of it; a look inside, the train env).
    """
    state_file = os.path.join(folder, "state.pkl")
    try:
        with open(state_file, "rb") as file:
            state = pickle.load(file)
    except Exception as exc:  # noqa: BLE001 (any unpickling failure means a damaged file)
        raise ExperimentError(f"{state_file} is missing or damaged ({type(exc).__name__}: {exc})") from None
    if not isinstance(state, dict) or any(key not in state for key in needed_keys):
        raise ExperimentError(f"{state_file} is damaged: it is not a checkpoint state (a dict with {list(needed_keys)})")
    if state.get("sb3_macb") != sb3_macb.__version__ and not allow_other_version:
        raise ExperimentError(f"{state_file} was written by sb3_macb {state.get('sb3_macb')}, this is {sb3_macb.__version__}")
    if config is not None and state.get("config") != config:
        raise ExperimentError(f"{state_file} belongs to other settings than {experiment_file}")
    model_file = os.path.join(folder, "model.zip")
    try:
        model = MADDPG.load(model_file, env=None, device=device)
    except Exception as exc:  # noqa: BLE001
        raise ExperimentError(f"{model_file} is missing or damaged ({type(exc).__name__}: {exc})") from None
    model.set_env(restore(state["train_env"]), force_reset=False)
    buffer_file = os.path.join(folder, "buffer.npz")
    try:
        with np.load(buffer_file) as arrays:
            model.replay_buffer.load_state_arrays(arrays)
    except Exception as exc:  # noqa: BLE001
        raise ExperimentError(f"{buffer_file} is missing or damaged ({type(exc).__name__}: {exc})") from None
    return model, state


def global_rng_states() -> dict[str, Any]:
    """
    numpy's, Python's and torch's global random states, with CUDA's where CUDA has been used (the package's own
    draws use per-run generators; user code and callbacks may draw from these).
    """
    states = {"numpy": np.random.get_state(), "python": random.getstate(), "torch": th.get_rng_state()}
    if th.cuda.is_available() and th.cuda.is_initialized():
        states["torch_cuda"] = th.cuda.get_rng_state_all()
    return states


def restore_global_rngs(state: dict[str, Any]) -> None:
    """Set the global random states to those a checkpoint's ``state`` recorded (see :func:`global_rng_states`)."""
    np.random.set_state(state["rng"]["numpy"])
    random.setstate(state["rng"]["python"])
    th.set_rng_state(state["rng"]["torch"])
    cuda = state["rng"].get("torch_cuda")
    if cuda is not None and th.cuda.is_available():
        for index, cuda_state in enumerate(cuda[: th.cuda.device_count()]):
            th.cuda.set_rng_state(cuda_state, index)


def run_experiment(
    env_id: str,
    hyperparams: dict[str, Any],
    seed: int,
    n_timesteps: int,
    log_folder: str,
    variants: list[str] | tuple[str, ...] = (),
    eval_freq: int = 20,
    eval_episodes: int = 10,
    env_kwargs: dict[str, Any] | None = None,
    checkpoint_freq: int | None = None,
    verbose: int = 0,
    callbacks: list[BaseCallback] | None = None,
    resume: bool = False,
) -> str:
    """
    Train one run, evaluated as the paper does, into ``log_folder`` (``evaluations.npz``, ``model.zip``,
    ``config.yml``, ``run.json``); the explicit form of ``sb3-macb train`` that the sweep calls.

    :param env_id: A registered env id.
    :param hyperparams: The run's hyperparameters (e.g. from :func:`load_hyperparams`).
    :param seed: The run's seed.
    :param n_timesteps: Environment steps.
    :param log_folder: The run's folder (must not hold an experiment yet, unless ``resume``).
    :param variants: The zoo variants the hyperparameters came from (recorded).
    :param eval_freq: Evaluate every this many steps.
    :param eval_episodes: Episodes per evaluation.
    :param env_kwargs: Keyword arguments for the env.
    :param checkpoint_freq: Steps between checkpoints (None: none).
    :param verbose: 1 prints a line per checkpoint and at the end.
    :param callbacks: Callbacks run at every step (see :class:`Experiment`).
    :param resume: Continue the run from its latest checkpoint when ``log_folder`` holds one, with the same
        settings (see :func:`run_or_resume`).
    :return: ``log_folder``.
    """
    config = ExperimentConfig(
        env_id,
        [RunConfig(seed=int(seed), folder=log_folder, variants=list(variants), hyperparams=dict(hyperparams))],
        n_timesteps=int(n_timesteps),
        eval_freq=eval_freq,
        eval_episodes=eval_episodes,
        env_kwargs=dict(env_kwargs or {}),
    )
    experiment = Experiment(config, log_folder, checkpoint_freq=checkpoint_freq, verbose=verbose, callbacks=callbacks)
    if resume:
        run_or_resume(experiment)
    else:
        experiment.run()
    return log_folder


def run_or_resume(experiment: Experiment) -> list[str]:
    """
    Run ``experiment``, or continue it from its latest checkpoint when its folder holds one (a finished one returns
    at once). A folder whose experiment stopped before its first checkpoint is deleted and the experiment started
    again: nothing in it can be resumed. Settings that differ from those the folder holds are an
    :class:`ExperimentError`, as with :meth:`Experiment.run`.

    :param experiment: The experiment, built with the settings it was started with.
    :return: The runs' folders.
    """
    status = experiment.status()
    if status == "started":
        if experiment.verbose:
            print(f"{experiment.folder}: stopped before its first checkpoint; starting it again", flush=True)
        shutil.rmtree(experiment.folder)
        status = "new"
    return experiment.run(resume=status != "new")


def _read_json(path: str) -> Any:
    """An experiment file's JSON; a missing, unreadable or damaged file is an :class:`ExperimentError` naming it."""
    try:
        with open(path, "rb") as file:
            return json.loads(file.read().decode("utf-8"))
    except FileNotFoundError:
        raise ExperimentError(f"{path} does not exist: {os.path.dirname(path) or '.'} holds no experiment to resume") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ExperimentError(f"{path} is not a readable experiment file ({type(exc).__name__}: {exc})") from None


def _refuse_unsafe_from_file(path: str, saved: dict[str, Any], unsafe_eval: bool) -> None:
    """``unsafe_eval`` comes from the command line only: a file started with it needs it given again."""
    if saved["config"].get("unsafe_eval") and not unsafe_eval:
        raise ExperimentError(
            f"{path} was started with --unsafe-eval: resuming it evaluates its hyperparameter strings as Python. "
            f"Pass --unsafe-eval again if you trust this folder"
        )


def read_experiment_file(path: str) -> dict[str, Any]:
    """
    ``experiment.json`` read and checked: a JSON object written by this sb3_macb version, with a ``config`` mapping.
    Anything else is an :class:`ExperimentError` naming the file.

    :param path: The file.
    """
    saved = _read_json(path)
    if (
        not isinstance(saved, dict)
        or not isinstance(saved.get("config"), dict)
        or not isinstance(saved["config"].get("runs"), list)
    ):
        raise ExperimentError(f"{path} is not an experiment file (no 'config' with 'runs')")
    if saved.get("sb3_macb") != sb3_macb.__version__:
        raise ExperimentError(
            f"{path} was written by sb3_macb {saved.get('sb3_macb')}; this is {sb3_macb.__version__}. A checkpoint "
            f"continues only with the version that wrote it (random streams and formats may differ)."
        )
    return saved


def load_experiment(folder: str, checkpoint_freq: int | None = None, verbose: int = 1, keep_models: bool = False,
                    unsafe_eval: bool = False) -> Experiment:  # fmt: skip
    """
    The experiment stored in ``folder`` (its ``experiment.json``), to resume (the other arguments as
    :class:`Experiment`'s). Its runs' folders are found relative to ``folder`` wherever it now is; a folder that was
    moved or copied resumes only runs that lie inside it (so that it never writes into the original's runs).

    :param folder: The experiment's folder.
    :param unsafe_eval: Evaluate the hyperparameter strings as Python; never taken from the file: an experiment
        started with ``--unsafe-eval`` needs it again.
    """
    path = os.path.join(folder, EXPERIMENT_FILE)
    saved = read_experiment_file(path)
    _refuse_unsafe_from_file(path, saved, unsafe_eval)
    config = {**saved["config"], "unsafe_eval": bool(unsafe_eval)}
    here = os.path.abspath(folder)
    moved = "folder" in saved and os.path.realpath(str(saved["folder"])) != os.path.realpath(here)
    runs = []
    for run in config["runs"]:
        if not isinstance(run, dict) or not isinstance(run.get("folder"), str):
            raise ExperimentError(f"{path}: every run needs a 'folder' (a string)")
        relative = run["folder"]
        if os.path.isabs(relative) or "folder" not in saved:
            raise ExperimentError(f"{path} records run folders in an older layout; resume it with the version that wrote it")
        target = os.path.normpath(os.path.join(here, relative))
        if moved and (relative == os.pardir or relative.startswith(os.pardir + os.sep)):
            raise ExperimentError(
                f"{folder} was moved or copied from {saved['folder']}, and its run {relative} lies outside it: resuming "
                f"here would write into {target}. Resume it where it was, or start it again"
            )
        runs.append({**run, "folder": target})
    config["runs"] = runs
    try:
        experiment_config = ExperimentConfig(**config)
    except TypeError as exc:
        raise ExperimentError(f"{path} is not a readable experiment file ({exc})") from None
    return Experiment(experiment_config, folder, checkpoint_freq=checkpoint_freq, verbose=verbose, keep_models=keep_models)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Resume an experiment folder (sb3_macb.zoo.experiment).")
    parser.add_argument("--resume", required=True, metavar="FOLDER", help="the experiment's folder")
    parser.add_argument("--checkpoint-freq", type=int, default=None, help="steps per run between checkpoints")
    parser.add_argument("--keep-models", action="store_true", help="keep every checkpoint's model in FOLDER/models/")
    parser.add_argument("--num-threads", type=int, default=1)
    parser.add_argument("--unsafe-eval", action="store_true",
                        help="evaluate the experiment's hyperparameter strings as Python (needed again for an experiment "
                        "started with it; only for folders you trust)")  # fmt: skip
    args = parser.parse_args(argv)
    try:
        if args.num_threads < 1:
            raise ExperimentError(f"--num-threads must be >= 1, got {args.num_threads}")
        th.set_num_threads(args.num_threads)
        load_experiment(args.resume, checkpoint_freq=args.checkpoint_freq, keep_models=args.keep_models,
                        unsafe_eval=args.unsafe_eval).run(resume=True)  # fmt: skip
    except ExperimentError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())

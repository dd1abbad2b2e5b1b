"""
``sb3-macb enjoy RUN_FOLDER``: play a trained run (rl_zoo3's ``enjoy`` in spirit) and print each episode's success
and every agent's return, then their means.

    sb3-macb enjoy logs/maddpg/sb3_macb-CommunicativeNavigation-v0_1 -n 10
    sb3-macb enjoy RUN_FOLDER --model final --seed 3
    sb3-macb enjoy RUN_FOLDER -n 3 --record videos/      # and one mp4 per episode in videos/

The run folder's ``best_model.zip`` (or ``model.zip``: ``--model final``) is played with the deterministic actors on
the env id and env kwargs of the folder's ``config.yml`` (read as plain YAML data). Model zips are pickles: loading
one runs code that it names, so play only run folders you trust. With ``--record``, the episodes are played on the
task's mpe2-based env (step for step the same as the vectorized one) and gymnasium's ``RecordVideo`` writes each as
an mp4 from its ``rgb_array`` frames (moviepy, in the ``zoo`` extra).
"""

import argparse
import os
from typing import Any

import numpy as np
import yaml

from sb3_macb.zoo.experiment import ExperimentError


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sb3-macb enjoy", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "run_folder", help="a run folder written by sb3-macb train or experiments/macb_paper/scripts/reproduce.py"
    )
    parser.add_argument("-n", "--n-episodes", type=int, default=10, help="episodes to play")
    parser.add_argument("--model", choices=["best", "final"], default="best",
                        help="best_model.zip (by success rate; model.zip where there is none) or model.zip")  # fmt: skip
    parser.add_argument("--seed", type=int, default=0, help="seed of the episodes' starts")
    parser.add_argument("--record", metavar="VIDEO_FOLDER", default=None,
                        help="also write each episode as an mp4 into VIDEO_FOLDER (created if missing)")  # fmt: skip
    return parser


def _run_settings(folder: str, which: str) -> tuple[str, str, dict[str, Any]]:
    """The model file, env id and env kwargs of a run folder, each checked (one line naming what is wrong)."""
    import gymnasium as gym

    import sb3_macb.envs  # noqa: F401  (registers the task ids)

    if not os.path.isdir(folder):
        raise ExperimentError(f"{folder}: no such run folder")
    config_path = os.path.join(folder, "config.yml")
    try:
        with open(config_path) as file:
            config = yaml.safe_load(file) or {}
    except OSError:
        raise ExperimentError(
            f"{folder} has no config.yml (written when a run completes): not a finished run folder"
        ) from None
    except yaml.YAMLError:
        raise ExperimentError(f"{config_path} is not valid YAML") from None
    if not isinstance(config, dict):
        raise ExperimentError(f"{config_path} is not a mapping of run settings")
    env_id, env_kwargs = config.get("env_id"), config.get("env_kwargs") or {}
    if not isinstance(env_id, str) or env_id not in gym.registry:
        raise ExperimentError(f"{config_path}: 'env_id' must name a registered env, got {env_id!r}")
    if not isinstance(env_kwargs, dict):
        raise ExperimentError(f"{config_path}: 'env_kwargs' must be a mapping, got {env_kwargs!r}")
    names = ["best_model.zip", "model.zip"] if which == "best" else ["model.zip"]
    models = [os.path.join(folder, name) for name in names if os.path.isfile(os.path.join(folder, name))]
    if not models:
        raise ExperimentError(f"{folder} has no {' or '.join(names)}")
    return models[0], env_id, env_kwargs


def enjoy(argv: list[str]) -> list[dict[str, Any]]:
    """
    Play a run folder's model and print the episodes; returns one record per episode (``success``, ``returns``:
    each agent's return).
    """
    from sb3_macb.envs.vec_tasks import make_task_vec_env
    from sb3_macb.maddpg import MADDPG

    args = make_parser().parse_args(argv)
    if args.n_episodes < 1:
        raise ExperimentError(f"-n/--n-episodes must be >= 1, got {args.n_episodes}")
    path, env_id, env_kwargs = _run_settings(args.run_folder, args.model)
    if args.record is not None:
        try:
            import moviepy  # noqa: F401  (what RecordVideo writes with)
        except ImportError:
            raise ExperimentError("--record needs moviepy: pip install 'sb3_macb[zoo]' (or moviepy)") from None
        ancestor = os.path.abspath(args.record)  # the folder, or what of its path exists
        while not os.path.exists(ancestor):
            ancestor = os.path.dirname(ancestor)
        if not os.path.isdir(ancestor) or not os.access(ancestor, os.W_OK):
            raise ExperimentError(f"--record {args.record}: cannot write videos there ({ancestor} is not a writable folder)")
        if os.path.isdir(args.record) and any(n.startswith("episode-") for n in os.listdir(args.record)):
            raise ExperimentError(f"--record {args.record} already holds episode videos: give another folder")
    model = MADDPG.load(path, device="cpu")  # (a pickle: see the module's docstring)
    agents = list(model.agent_layout.agents)  # type: ignore[union-attr]
    print(f"{path} on {env_id} {env_kwargs or ''}".rstrip())
    records: list[dict[str, Any]] = []

    def finished(returns: np.ndarray, info: dict[str, Any]) -> None:
        records.append({"success": bool(info.get("is_success", False)), "returns": returns.copy()})
        per_agent = ", ".join(f"{name} {value:.2f}" for name, value in zip(agents, returns))
        print(f"episode {len(records)}: success {int(records[-1]['success'])}, return {per_agent}")

    returns = np.zeros(len(agents))
    if args.record is None:
        env = make_task_vec_env(env_id, 1, env_kwargs)
        env.seed(args.seed)
        obs = env.reset()
        while len(records) < args.n_episodes:
            action, _ = model.predict(obs, deterministic=True)  # type: ignore[arg-type]
            obs, _, dones, infos = env.step(action)
            returns += infos[0]["agent_rewards"]
            if dones[0]:
                finished(returns, infos[0])
                returns = np.zeros(len(agents))
    else:
        import gymnasium as gym
        from gymnasium.wrappers import RecordVideo

        video_env = RecordVideo(gym.make(env_id, render_mode="rgb_array", **env_kwargs), args.record,
                                episode_trigger=lambda _: True, name_prefix="episode", disable_logger=True)  # fmt: skip
        try:
            single, _ = video_env.reset(seed=args.seed)
            while len(records) < args.n_episodes:
                action, _ = model.predict(single, deterministic=True)
                single, _, terminated, truncated, info = video_env.step(action)
                returns += info["agent_rewards"]
                if terminated or truncated:
                    finished(returns, info)
                    returns = np.zeros(len(agents))
                    if len(records) < args.n_episodes:  # (a reset would start recording one more episode)
                        single, _ = video_env.reset()
        finally:
            video_env.close()
        print(f"videos in {args.record}")
    mean = np.mean([r["returns"] for r in records], axis=0)
    print(f"success rate {np.mean([r['success'] for r in records]):.2f} over {len(records)} episodes; mean return "
          + ", ".join(f"{name} {value:.2f}" for name, value in zip(agents, mean)))  # fmt: skip
    return records


def main(argv: list[str]) -> int:
    enjoy(argv)
    return 0

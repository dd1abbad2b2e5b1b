"""
Success rates of the scripted reference policy (:func:`sb3_macb.envs.scripted.scripted_actions`) and of uniformly
random actions on the exploration study's candidate tasks, as the study's evaluation counts them (an episode
succeeds when its success condition holds at some step).

    python experiments/exploration/scripts/task_levels.py --episodes 1000 --json levels.json

Prints one line per task and policy; ``--json`` also writes them.
"""

import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from sb3_macb.envs.scripted import scripted_actions  # noqa: E402
from sb3_macb.envs.vec_tasks import make_task_vec_env  # noqa: E402
from study_tasks import CANDIDATES  # noqa: E402


def success_rate(task: str, policy: str, episodes: int, seed: int) -> float:
    """
    The fraction of ``episodes`` episodes of a candidate task (all run side by side) in which ``policy`` succeeds.

    :param task: A key of ``CANDIDATES``.
    :param policy: ``"scripted"`` or ``"random"``.
    :param episodes: Number of episodes.
    :param seed: Seed of the envs and of the random actions.
    """
    env_id, env_kwargs = CANDIDATES[task]
    venv = make_task_vec_env(env_id, episodes, env_kwargs)
    venv.seed(seed)
    venv.reset()
    rng = np.random.default_rng(seed)
    low, high = venv.action_space.low, venv.action_space.high
    finished = np.zeros(episodes, dtype=bool)
    succeeded = np.zeros(episodes, dtype=bool)
    while not finished.all():
        if policy == "scripted":
            actions = scripted_actions(venv)
        else:
            actions = rng.uniform(low, high, (episodes, low.shape[0])).astype(np.float32)
        _, _, dones, infos = venv.step(actions)
        for i in np.flatnonzero(dones & ~finished):
            finished[i] = True
            succeeded[i] = infos[i]["is_success"]
    return float(succeeded.mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--tasks", nargs="+", default=list(CANDIDATES), choices=list(CANDIDATES))
    parser.add_argument("--json", help="also write the levels to this file")
    args = parser.parse_args()
    levels: dict[str, dict[str, float]] = {}
    for task in args.tasks:
        levels[task] = {p: success_rate(task, p, args.episodes, args.seed) for p in ("scripted", "random")}
        print(
            f"{task}: scripted {levels[task]['scripted']:.3f} random {levels[task]['random']:.3f} "
            f"({args.episodes} episodes, seed {args.seed})",
            flush=True,
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"episodes": args.episodes, "seed": args.seed, "levels": levels}, f, indent=1)


if __name__ == "__main__":
    main()

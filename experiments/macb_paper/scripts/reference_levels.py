"""
Success levels of scripted listeners on sparse Communicative Navigation, for the plots and the pre-registered
analysis (the study's README.md): two that ignore the speaker (a random landmark per episode; a tour of the landmarks)
and an oracle that reads the goal. Each is evaluated as the learned runs are (20-step episodes; any-step success:
within 0.15 of the goal at some step; final-step success: at the last step), over --episodes episodes.

    python scripts/reference_levels.py                       # 10,000 episodes each, writes the JSON below
    python scripts/reference_levels.py --episodes 2000 -o -  # print only

Output: results/CommunicativeNavigation-sparse-reference.json ({policy: {any_step, final_step, mean_return,
episodes}}), read by `sb3-macb plot curves --reference` and scripts/summarize_results.py.
"""

import argparse
import json
import os
import sys

import numpy as np

from reference_policies import GoalListener, LandmarkTourListener, RandomLandmarkListener  # beside this script
from sb3_macb.common.atomic import atomic_write
from sb3_macb.envs.vec_tasks import make_task_vec_env

POLICIES = {"random_landmark": RandomLandmarkListener, "landmark_tour": LandmarkTourListener, "oracle": GoalListener}


def measure(policy, episodes: int, seed: int, reward: str = "sparse", batch: int = 2000) -> dict[str, float]:
    any_step, final_step, returns = [], [], []
    for start in range(0, episodes, batch):
        n = min(batch, episodes - start)
        env = make_task_vec_env("sb3_macb/CommunicativeNavigation-v0", n, {"reward": reward})
        env.seed(seed + start)
        obs, starting = env.reset(), np.ones(n, dtype=bool)
        reached, total, done = np.zeros(n, dtype=bool), np.zeros(n), np.zeros(n, dtype=bool)
        final = np.zeros(n, dtype=bool)  # success at the last step of the batch's (equal-length) episodes
        while not done.all():
            actions, _ = policy.predict(obs, episode_start=starting)
            obs, rewards, starting, infos = env.step(actions)
            success = np.array([info["agent_infos"]["listener_0"]["success"] for info in infos])
            reached |= success & ~done
            total += np.where(done, 0.0, rewards)
            if not done.any():
                final = success
            done |= starting
        any_step.append(reached)
        final_step.append(final)
        returns.append(total)
    cat = np.concatenate
    return {"any_step": float(cat(any_step).mean()), "final_step": float(cat(final_step).mean()),
            "mean_return": float(cat(returns).mean()), "episodes": episodes}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=12345)
    study = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    parser.add_argument("-o", "--out", default=os.path.join(study, "results", "CommunicativeNavigation-sparse-reference.json"))
    args = parser.parse_args()
    levels = {name: measure(cls(seed=args.seed), args.episodes, args.seed) for name, cls in POLICIES.items()}
    print("| listener | any-step success | final-step success | mean return | episodes |")
    print("|---|---|---|---|---|")
    for name, level in levels.items():
        figures = f"{level['any_step']:.3f} | {level['final_step']:.3f} | {level['mean_return']:.2f}"
        print(f"| {name} | {figures} | {level['episodes']} |")
    if args.out != "-":
        with atomic_write(args.out) as file:
            file.write(json.dumps(levels, indent=1).encode())
        print(f"written: {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()

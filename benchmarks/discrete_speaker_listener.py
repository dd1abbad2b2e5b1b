"""
Discrete against continuous actions on speaker-listener (mpe2, 25-step episodes): MADDPG's evaluation return after
a fixed budget, next to a uniformly random policy's, for a few seeds. Discrete agents use the straight-through
Gumbel-softmax (see ``MultiAgentActor``); continuous ones Gaussian action noise 0.1.

    python benchmarks/discrete_speaker_listener.py                 # 10,000 steps, seeds 0 1 2, 64-64
    python benchmarks/discrete_speaker_listener.py --steps 30000 --seeds 0 1 2 3 4
"""

import argparse
import statistics

import numpy as np
import torch as th
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor

from benchmarks_common import train_and_evaluate
from sb3_macb import MADDPG, make_joint_env


def make_env(continuous: bool) -> Monitor:
    from mpe2 import simple_speaker_listener_v4

    return Monitor(make_joint_env(simple_speaker_listener_v4.parallel_env(max_cycles=25, continuous_actions=continuous)))


class RandomPolicy:
    """Uniform random actions (one-hot for discrete agents), with SB3's ``predict`` signature."""

    def __init__(self, model: MADDPG, seed: int):
        self.model, self.rng = model, np.random.default_rng(seed)

    def predict(self, obs, state=None, episode_start=None, deterministic=True):  # type: ignore[no-untyped-def]
        space = self.model.action_space
        actions = self.rng.uniform(space.low, space.high, size=(len(obs), *space.shape)).astype(np.float32)
        return (self.model._one_hot(actions) if self.model.actor.has_discrete else actions), None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=10_000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--eval-episodes", type=int, default=100)
    args = parser.parse_args()
    th.set_num_threads(1)
    rows = []
    for continuous in (False, True):
        learned, random_, times = [], [], []
        for seed in args.seeds:
            model, result, seconds = train_and_evaluate(
                lambda continuous=continuous: make_env(continuous), args.steps, seed, args.eval_episodes, noise=continuous
            )
            learned.append(result)
            times.append(seconds)
            random_env = make_env(continuous)
            random_env.reset(seed=1000 + seed)
            random_.append(evaluate_policy(RandomPolicy(model, seed), random_env, n_eval_episodes=args.eval_episodes)[0])
        rows.append(("continuous" if continuous else "discrete", learned, random_, times))
    print(f"speaker-listener, 25-step episodes, {args.steps} steps, 64-64, batch 256, seeds {args.seeds}, "
          f"{args.eval_episodes} evaluation episodes, torch {th.__version__}, 1 thread")  # fmt: skip
    print("| actions | MADDPG return (mean over seeds) | per seed | random policy | steps/s |")
    print("|---|---|---|---|---|")
    for name, learned, random_, times in rows:
        per_seed = ", ".join(f"{r:.1f}" for r in learned)
        rate = args.steps / statistics.mean(times)
        print(f"| {name} | {statistics.mean(learned):.1f} | {per_seed} | {statistics.mean(random_):.1f} | {rate:.0f} |")


if __name__ == "__main__":
    main()

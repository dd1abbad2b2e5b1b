"""
Parameter sharing on simple_spread (mpe2, continuous actions, 25-step episodes): MADDPG's evaluation return after a
fixed budget with one actor and critic per agent and with shared actors and critics (``share_parameters="all",
share_critics=True``, one-hot agent ids), for N=3 and N=6 agents, next to training steps per second.

    python benchmarks/sharing_spread.py                      # 20,000 steps, seeds 0 1, 64-64
    python benchmarks/sharing_spread.py --steps 50000 --seeds 0 1 2 --agents 3
"""

import argparse
import statistics

import torch as th
from stable_baselines3.common.monitor import Monitor

from benchmarks_common import train_and_evaluate
from sb3_macb import make_joint_env


def make_env(n: int) -> Monitor:
    from mpe2 import simple_spread_v3

    return Monitor(make_joint_env(simple_spread_v3.parallel_env(N=n, continuous_actions=True, max_cycles=25)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--agents", type=int, nargs="+", default=[3, 6])
    parser.add_argument("--eval-episodes", type=int, default=50)
    args = parser.parse_args()
    th.set_num_threads(1)
    print(f"simple_spread, 25-step episodes, {args.steps} steps, 64-64, batch 256, Gaussian noise 0.1, seeds {args.seeds}, "
          f"{args.eval_episodes} evaluation episodes, torch {th.__version__}, 1 thread")  # fmt: skip
    print("| agents | networks | return (mean over seeds) | per seed | actor + critic parameters | steps/s |")
    print("|---|---|---|---|---|---|")
    for n in args.agents:
        for share in (False, True):
            returns, times = [], []
            for seed in args.seeds:
                kwargs = dict(share_parameters="all", share_critics=True) if share else {}
                model, result, seconds = train_and_evaluate(
                    lambda n=n: make_env(n), args.steps, seed, args.eval_episodes, **kwargs
                )
                returns.append(result)
                times.append(seconds)
            size = sum(p.numel() for p in [*model.actor.parameters(), *model.critic.parameters()])
            per_seed = ", ".join(f"{r:.1f}" for r in returns)
            name = "shared actors and critics" if share else "one per agent"
            print(f"| {n} | {name} | {statistics.mean(returns):.1f} | {per_seed} | {size} | "
                  f"{args.steps / statistics.mean(times):.0f} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()

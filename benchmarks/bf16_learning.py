"""
``policy_kwargs=dict(precision="bf16")`` against the default float32: learning curves and speed of MADDPG at 400-300
(the size where bfloat16 products pay) on continuous speaker-listener (mpe2, 25-step episodes), for a few seeds.

    python benchmarks/bf16_learning.py                        # 10,000 steps, seeds 0 1 2, evaluations every 2,500
    python benchmarks/bf16_learning.py --steps 20000 --seeds 0 1 2 3 4

Each run: batch 100, learning after 1,000 steps, Gaussian action noise 0.1, one torch thread; after every
``--eval-every`` steps, the mean return of ``--eval-episodes`` deterministic episodes on an evaluation env seeded
``1000 + seed`` (the same episodes for both precisions). The same seed gives the same initial weights and the same
exploration noise for both precisions, so the two curves of a seed differ only through the rounding of the products.

Reading rule (fixed before the first run): bfloat16 "does not change learning" at this budget if the seed mean of
its final return is within one float32 seed standard deviation of float32's seed mean; otherwise the table says
which way it moved.
"""

import argparse
import statistics
import time

import numpy as np
import torch as th
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.noise import NormalActionNoise

from benchmarks_common import describe_backend
from sb3_macb import MADDPG, make_joint_env


def make_env() -> Monitor:
    from mpe2 import simple_speaker_listener_v4

    return Monitor(make_joint_env(simple_speaker_listener_v4.parallel_env(max_cycles=25, continuous_actions=True)))


def curve(precision: str, seed: int, steps: int, every: int, episodes: int) -> tuple[list[float], float]:
    """Evaluation returns after every ``every`` steps, and the training steps per second."""
    env = make_env()
    dim = env.action_space.shape[0]
    model = MADDPG("MlpPolicy", env, action_noise=NormalActionNoise(np.zeros(dim), 0.1 * np.ones(dim)), batch_size=100,
                   learning_starts=1000, seed=seed, policy_kwargs=dict(net_arch=[400, 300], precision=precision))  # fmt: skip
    returns, seconds = [], 0.0
    for _ in range(steps // every):
        start = time.perf_counter()
        model.learn(every, reset_num_timesteps=False)
        seconds += time.perf_counter() - start
        eval_env = make_env()
        eval_env.reset(seed=1000 + seed)
        returns.append(float(evaluate_policy(model, eval_env, n_eval_episodes=episodes)[0]))
    return returns, model.num_timesteps / seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=10_000)
    parser.add_argument("--eval-every", type=int, default=2_500)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--eval-episodes", type=int, default=50)
    args = parser.parse_args()
    th.set_num_threads(1)
    results = {}
    for seed in args.seeds:  # the two precisions of a seed back to back, so that machine drift hits both alike
        for precision in ("fp32", "bf16"):
            results[precision, seed] = curve(precision, seed, args.steps, args.eval_every, args.eval_episodes)
    checkpoints = list(range(args.eval_every, args.steps + 1, args.eval_every))
    print(f"speaker-listener, 25-step episodes, 400-300, batch 100, seeds {args.seeds}, {args.eval_episodes} evaluation "
          f"episodes per point\nbackend: {describe_backend()}")  # fmt: skip
    print("| precision | " + " | ".join(f"return at {c}" for c in checkpoints) + " | final per seed | steps/s |")
    print("|---|" + "---|" * len(checkpoints) + "---|---|")
    finals = {}
    for precision in ("fp32", "bf16"):
        curves = [results[precision, seed][0] for seed in args.seeds]
        rates = [results[precision, seed][1] for seed in args.seeds]
        finals[precision] = [c[-1] for c in curves]
        points = [f"{statistics.mean(c[i] for c in curves):.1f} +/- {statistics.pstdev(c[i] for c in curves):.1f}"
                  for i in range(len(checkpoints))]  # fmt: skip
        print(f"| {precision} | " + " | ".join(points) + f" | {', '.join(f'{f:.1f}' for f in finals[precision])} | "
              f"{statistics.mean(rates):.0f} |")  # fmt: skip
    gap = statistics.mean(finals["bf16"]) - statistics.mean(finals["fp32"])
    spread = statistics.pstdev(finals["fp32"])
    verdict = "within" if abs(gap) <= spread else ("above" if gap > 0 else "below")
    print(f"\nfinal return, bf16 - fp32: {gap:+.1f} (fp32 seed std {spread:.1f}): bf16 {verdict} one fp32 seed std")


if __name__ == "__main__":
    main()

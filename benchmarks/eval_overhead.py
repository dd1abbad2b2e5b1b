"""
What the paper's evaluation protocol adds to training time: MultiAgentEvalCallback evaluating every 20 steps (one
training episode) with 10 noise-free episodes run as one batch, on sparse Communicative Navigation with the paper's
settings (400-300 networks, batch 100), against the same training without evaluation. Rounds are interleaved.

    python benchmarks/eval_overhead.py
    python benchmarks/eval_overhead.py --net 64 64 --steps 2000
"""

import argparse
import statistics
import tempfile
import time

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.noise import NormalActionNoise

from sb3_macb import MADDPG
from sb3_macb.callbacks import MultiAgentEvalCallback

ENV_ID = "sb3_macb/CommunicativeNavigation-v0"


def run(net: list[int], steps: int, evaluate: bool) -> float:
    env = gym.make(ENV_ID)
    model = MADDPG(
        "MlpPolicy",
        env,
        batch_size=100,
        action_noise=NormalActionNoise(np.zeros(5), 0.1 * np.ones(5)),
        policy_kwargs=dict(net_arch=net),
        seed=0,
        device="cpu",
    )
    model.learn(200)
    with tempfile.TemporaryDirectory() as folder:
        callback = (
            MultiAgentEvalCallback(ENV_ID, n_eval_episodes=10, eval_freq=20, log_path=folder, seed=1, verbose=0)
            if evaluate
            else None
        )
        start = time.perf_counter()
        model.learn(steps, callback=callback, reset_num_timesteps=False)
        return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--net", type=int, nargs="+", default=[400, 300])
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    th.set_num_threads(args.threads)
    plain, with_eval = [], []
    for _ in range(args.rounds):
        plain.append(run(args.net, args.steps, evaluate=False))
        with_eval.append(run(args.net, args.steps, evaluate=True))
    p, e = statistics.median(plain), statistics.median(with_eval)
    print(f"net={args.net} steps={args.steps} threads={args.threads} rounds={args.rounds}")
    print(f"training alone:              {p:.2f} s ({args.steps / p:.0f} steps/s)")
    print(f"with evaluation every 20 st: {e:.2f} s ({args.steps // 20} evaluations of 10 episodes)")
    print(f"evaluation overhead: {100 * (e - p) / p:.1f}% of training time")


if __name__ == "__main__":
    main()

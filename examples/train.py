"""
A short training run: MADDPG (+ MACB) on a cooperative PettingZoo task, evaluated with SB3's EvalCallback.

    python examples/train.py                              # speaker-listener, MACB joint, 20k steps
    python examples/train.py --timesteps 100000 --no-macb --net 400 300
"""

import argparse
import time

import numpy as np
from mpe2 import simple_speaker_listener_v4
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.noise import NormalActionNoise

from sb3_macb import MACB, MADDPG, make_joint_env


def make_env() -> Monitor:
    return Monitor(make_joint_env(simple_speaker_listener_v4.parallel_env(continuous_actions=True, max_cycles=20)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--timesteps", type=int, default=20_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--net", type=int, nargs="+", default=[64, 64], help="hidden sizes (the paper: 400 300)")
    parser.add_argument("--beta", type=float, default=0.8)
    parser.add_argument("--k", type=int, default=512)
    parser.add_argument("--no-macb", action="store_true", help="plain MADDPG")
    parser.add_argument("--save", default="logs/maddpg_speaker_listener.zip")
    args = parser.parse_args()

    env, eval_env = make_env(), make_env()
    dim = env.action_space.shape[0]
    model = MADDPG(
        "MlpPolicy",
        env,
        learning_rate=1e-3,
        batch_size=100,
        learning_starts=100,
        action_noise=NormalActionNoise(np.zeros(dim), 0.1 * np.ones(dim)),
        exploration=None if args.no_macb else MACB(beta=args.beta, k=args.k),
        policy_kwargs=dict(net_arch=args.net),
        seed=args.seed,
        verbose=0,
    )
    random_return, _ = evaluate_policy(model, eval_env, n_eval_episodes=20)
    callback = EvalCallback(eval_env, n_eval_episodes=10, eval_freq=2_000, verbose=1)
    start = time.perf_counter()
    model.learn(args.timesteps, callback=callback, progress_bar=True)
    elapsed = time.perf_counter() - start
    final_return, std = evaluate_policy(model, eval_env, n_eval_episodes=50)
    model.save(args.save)
    print(f"\n{args.timesteps} steps in {elapsed:.0f} s ({args.timesteps / elapsed:.0f} steps/s)")
    print(f"evaluation return: untrained {random_return:.1f} -> trained {final_return:.1f} +/- {std:.1f} (50 episodes)")
    if model.exploration is not None:
        e = model.exploration
        print(f"MACB: {e.num_codes} codes for {e.total_count} transitions, count-1 {100 * e.count1_fraction:.1f}%")
    print(f"saved to {args.save}")


if __name__ == "__main__":
    main()

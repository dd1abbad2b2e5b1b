"""
A short training run of the paper's task with the paper's settings: MADDPG + MACB(beta 0.8, k 512, joint) on
sparse Communicative Navigation, 400-300 networks, batch 100, lr 1e-3, gamma 0.99, tau 0.005, Gaussian noise 0.1,
learning after 100 steps. The paper trains 8e5 steps; this run uses a short budget and reports the evaluation
success rate (10 noise-free episodes) along the way.

    python examples/train.py                                   # 20k steps (1,000 episodes)
    python examples/train.py --env sb3_macb/TwoAgentNavigation-v0 --no-macb --timesteps 50000
"""

import argparse
import time

import gymnasium as gym
import numpy as np
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.noise import NormalActionNoise

from sb3_macb import MACB, MADDPG


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="sb3_macb/CommunicativeNavigation-v0")
    parser.add_argument("--reward", default=None, help="'sparse' or 'distance' (Communicative Navigation)")
    parser.add_argument("--timesteps", type=int, default=20_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--net", type=int, nargs="+", default=[400, 300], help="hidden sizes")
    parser.add_argument("--beta", type=float, default=0.8)
    parser.add_argument("--k", type=int, default=512)
    parser.add_argument("--no-macb", action="store_true", help="plain MADDPG")
    parser.add_argument("--eval-freq", type=int, default=2_000)
    parser.add_argument("--log-dir", default="logs/example")
    args = parser.parse_args()

    env_kwargs = {} if args.reward is None else {"reward": args.reward}
    env, eval_env = (Monitor(gym.make(args.env, **env_kwargs)) for _ in range(2))
    dim = env.action_space.shape[0]
    model = MADDPG(
        "MlpPolicy",
        env,
        learning_rate=1e-3,
        buffer_size=1_000_000,
        learning_starts=100,
        batch_size=100,
        tau=0.005,
        gamma=0.99,
        action_noise=NormalActionNoise(np.zeros(dim), 0.1 * np.ones(dim)),
        exploration=None if args.no_macb else MACB(beta=args.beta, k=args.k),
        policy_kwargs=dict(net_arch=args.net),
        seed=args.seed,
    )
    callback = EvalCallback(eval_env, n_eval_episodes=10, eval_freq=args.eval_freq, log_path=args.log_dir, verbose=0)
    start = time.perf_counter()
    model.learn(args.timesteps, callback=callback, progress_bar=True)
    elapsed = time.perf_counter() - start
    model.save(f"{args.log_dir}/model.zip")

    data = np.load(f"{args.log_dir}/evaluations.npz")
    setting = " ".join(f"{k}={v}" for k, v in env_kwargs.items())
    print(f"\n{args.env} {setting} {'MADDPG' if args.no_macb else 'MADDPG + MACB'}, seed {args.seed}".replace("  ", " "))
    print(f"{args.timesteps} steps in {elapsed:.0f} s ({args.timesteps / elapsed:.0f} steps/s)")
    print("| steps | episodes | success rate (10 eval episodes) | mean return |")
    print("|---|---|---|---|")
    for steps, successes, returns in zip(data["timesteps"], data["successes"], data["results"]):
        print(f"| {steps} | {steps // 20} | {np.mean(successes):.1f} | {np.mean(returns):.2f} |")
    if model.exploration is not None:
        e = model.exploration
        print(f"MACB: {e.num_codes} codes for {e.total_count} transitions, count-1 {100 * e.count1_fraction:.1f}%")
    print(f"model and evaluations.npz saved in {args.log_dir}/")


if __name__ == "__main__":
    main()

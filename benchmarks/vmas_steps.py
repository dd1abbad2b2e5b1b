"""
Environment steps per second with random actions: VMAS scenarios through :func:`sb3_macb.envs.vmas_env.make_vmas_env`
(on the CPU, one thread) at several batch sizes, next to mpe2's ``simple_spread_v3`` through
:func:`sb3_macb.make_joint_env` and the package's vectorized 2-Agent Navigation (``TaskVecEnv``). A step of a batch of
``n`` envs counts ``n`` env-steps. Needs the ``vmas`` extra.

    python benchmarks/vmas_steps.py
    python benchmarks/vmas_steps.py --seconds 5 --batches 1 8 64 512

Last line: ``vmas_steps: <env>@<batch>=<env-steps/s> ...``.
"""

import argparse
import time

import numpy as np
import torch as th


def rate(env, seconds: float) -> float:  # type: ignore[no-untyped-def]
    """Env-steps per second of a VecEnv with uniform random actions, timed for about ``seconds``."""
    rng = np.random.default_rng(0)
    low, high = env.action_space.low, env.action_space.high
    env.reset()
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        env.step(rng.uniform(low, high, (env.num_envs, len(low))).astype(np.float32))
        steps += env.num_envs
    return steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=3.0, help="timed seconds per measurement")
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 8, 64, 512], help="VMAS batch sizes")
    args = parser.parse_args()
    th.set_num_threads(1)
    from mpe2 import simple_spread_v3
    from stable_baselines3.common.vec_env import DummyVecEnv

    from sb3_macb import make_joint_env
    from sb3_macb.envs.vec_tasks import TaskVecEnv
    from sb3_macb.envs.vmas_env import make_vmas_env

    results = {}
    spread = DummyVecEnv([lambda: make_joint_env(simple_spread_v3.parallel_env(N=3, continuous_actions=True))])
    results["mpe2-simple_spread-N3@1"] = rate(spread, args.seconds)
    for batch in (1, 64):
        results[f"task-2agent_navigation@{batch}"] = rate(TaskVecEnv("navigation", batch), args.seconds)
    for scenario in ("navigation", "balance"):
        for batch in args.batches:
            env = make_vmas_env(scenario, n_envs=batch, max_steps=100, seed=0, monitor=False, n_agents=3)
            results[f"vmas-{scenario}-N3@{batch}"] = rate(env, args.seconds)
    for name, value in results.items():
        print(f"{name:35s} {value:10.0f} env-steps/s")
    print("vmas_steps: " + " ".join(f"{name}={value:.0f}" for name, value in results.items()))


if __name__ == "__main__":
    main()

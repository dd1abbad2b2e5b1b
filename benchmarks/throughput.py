"""
Training throughput: environment steps per second with one gradient step per environment step.

MADDPG on speaker-listener (2 agents) is measured next to SB3's DDPG on Pendulum-v1 with the same network sizes
and batch size, in the same run, and the ratio is printed (1.0 = two agents trained for the price of one SB3
agent). Rounds are interleaved so that machine drift hits every configuration alike; the median is reported.

    python benchmarks/throughput.py                  # one thread, 400-300 and 64-64, 4-agent task, MACB
    python benchmarks/throughput.py --threads 2 --steps 2000 --rounds 5
    python benchmarks/throughput.py --quick --bf16   # adds MADDPG with policy_kwargs=dict(precision="bf16")
    python benchmarks/throughput.py --quick --device cuda   # every configuration on the GPU
"""

import argparse
import statistics
import time
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3 import DDPG
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.noise import NormalActionNoise

from benchmarks_common import describe_backend, describe_device, speaker_listener, spread, spread4
from sb3_macb import MACB, MADDPG


def make_model(
    kind: str, net: list[int], batch_size: int, seed: int, precision: str = "fp32", device: str = "cpu", **kwargs: Any
) -> BaseAlgorithm:
    common = dict(batch_size=batch_size, learning_starts=100, seed=seed, device=device, policy_kwargs=dict(net_arch=net))
    if precision != "fp32":
        common["policy_kwargs"]["precision"] = precision
    if kind == "ddpg":
        env = gym.make("Pendulum-v1")
        noise = NormalActionNoise(np.zeros(1), 0.1 * np.ones(1))
        return DDPG("MlpPolicy", env, action_noise=noise, **common)
    if kind == "maddpg-discrete":
        env = speaker_listener(continuous=False)
    elif kind.startswith("spread-"):
        env = spread(int(kind.split("-")[1]))
    else:
        env = spread4() if kind == "maddpg-4" else speaker_listener()
    dim = env.action_space.shape[0]
    noise = None if kind == "maddpg-discrete" else NormalActionNoise(np.zeros(dim), 0.1 * np.ones(dim))
    return MADDPG("MlpPolicy", env, action_noise=noise, **common, **kwargs)


def steps_per_second(build: Callable[[], BaseAlgorithm], steps: int, warmup: int) -> float:
    model = build()
    model.learn(warmup)  # fills learning_starts, warms up allocators and kernels
    start = time.perf_counter()
    model.learn(steps, reset_num_timesteps=False)
    return steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--steps", type=int, default=1500, help="timed environment steps per measurement")
    parser.add_argument("--warmup", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--batch-size", type=int, default=100)
    parser.add_argument("--quick", action="store_true", help="only the 400-300 speaker-listener configurations")
    parser.add_argument("--features", action="store_true",
                        help="discrete actions and parameter sharing instead: discrete vs continuous speaker-listener, "
                        "simple_spread N=3 and N=6 with and without shared actors and critics (64-64)")  # fmt: skip
    parser.add_argument("--bf16", action="store_true",
                        help="add MADDPG with its products in bfloat16 (policy_kwargs=dict(precision='bf16'))")  # fmt: skip
    parser.add_argument("--device", default="cpu", help="torch device of every model (cpu, cuda, cuda:1, ...)")
    args = parser.parse_args()
    th.set_num_threads(args.threads)
    device = args.device

    def new_model(kind: str, net: list[int], precision: str = "fp32", **kwargs: Any) -> BaseAlgorithm:
        return make_model(kind, net, args.batch_size, 0, precision, device=device, **kwargs)

    big, small = [400, 300], [64, 64]
    configs: dict[str, Callable[[], BaseAlgorithm]] = {
        "SB3 DDPG, Pendulum-v1, 400-300": lambda: new_model("ddpg", big),
        "MADDPG, speaker-listener (2 agents), 400-300": lambda: new_model("maddpg", big),
        "MADDPG + MACB(k=512), speaker-listener, 400-300": lambda: new_model("maddpg", big, exploration=MACB(beta=0.8, k=512)),
    }
    if not args.quick:
        configs.update(
            {
                "SB3 DDPG, Pendulum-v1, 64-64": lambda: new_model("ddpg", small),
                "MADDPG, speaker-listener, 64-64": lambda: new_model("maddpg", small),
                "MADDPG, simple_spread N=4 (4 agents), 400-300": lambda: new_model("maddpg-4", big),
                "MADDPG, simple_spread N=4 (4 agents), 64-64": lambda: new_model("maddpg-4", small),
            }
        )
    if args.bf16:
        configs["MADDPG bf16, speaker-listener, 400-300"] = lambda: new_model("maddpg", big, "bf16")
        if not args.quick:
            configs["MADDPG bf16, speaker-listener, 64-64"] = lambda: new_model("maddpg", small, "bf16")
    if args.features:
        configs = {
            "MADDPG, speaker-listener, continuous, 64-64": lambda: new_model("maddpg", small),
            "MADDPG, speaker-listener, discrete (Gumbel-softmax), 64-64": lambda: new_model("maddpg-discrete", small),
        }
        for n in (3, 6):
            for share in (False, True):
                name = (
                    f"MADDPG, simple_spread N={n}, 64-64, {'shared actors and critics' if share else 'one network per agent'}"
                )
                kwargs = dict(share_parameters="all", share_critics=True) if share else {}
                configs[name] = lambda n=n, kwargs=kwargs: new_model(f"spread-{n}", small, **kwargs)
    results: dict[str, list[float]] = {name: [] for name in configs}
    for _ in range(args.rounds):
        for name, build in configs.items():
            results[name].append(steps_per_second(build, args.steps, args.warmup))

    med = {name: statistics.median(values) for name, values in results.items()}
    print(f"\nthreads={args.threads} batch={args.batch_size} steps={args.steps} rounds={args.rounds} torch={th.__version__}")
    print(f"backend: {describe_backend()}")
    print(f"device: {describe_device(device)}")
    print("| configuration | env steps/s (median) | min | max |")
    print("|---|---|---|---|")
    for name, values in results.items():
        print(f"| {name} | {med[name]:.0f} | {min(values):.0f} | {max(values):.0f} |")
    ratios = [
        (
            "MADDPG 2 agents / SB3 DDPG, 400-300",
            "MADDPG, speaker-listener (2 agents), 400-300",
            "SB3 DDPG, Pendulum-v1, 400-300",
        ),
        ("MADDPG 2 agents / SB3 DDPG, 64-64", "MADDPG, speaker-listener, 64-64", "SB3 DDPG, Pendulum-v1, 64-64"),
        (
            "MADDPG+MACB / MADDPG, 400-300",
            "MADDPG + MACB(k=512), speaker-listener, 400-300",
            "MADDPG, speaker-listener (2 agents), 400-300",
        ),
        ("MADDPG bf16 / SB3 DDPG, 400-300", "MADDPG bf16, speaker-listener, 400-300", "SB3 DDPG, Pendulum-v1, 400-300"),
        (
            "MADDPG bf16 / MADDPG fp32, 400-300",
            "MADDPG bf16, speaker-listener, 400-300",
            "MADDPG, speaker-listener (2 agents), 400-300",
        ),
        ("MADDPG bf16 / MADDPG fp32, 64-64", "MADDPG bf16, speaker-listener, 64-64", "MADDPG, speaker-listener, 64-64"),
    ]
    for label, num, den in ratios:
        if num in med and den in med:
            print(f"ratio {label}: {med[num] / med[den]:.3f}")


if __name__ == "__main__":
    main()

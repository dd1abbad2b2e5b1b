"""
Packed runs against solo runs: how many more runs' environment steps per second one process trains when K runs
share one set of stacked tensors (``MADDPG(n_runs=K)``).

Workload: sparse Communicative Navigation as the paper runs it (MACB(s, x) beta 0.8 k 512, batch 100, one gradient
step per step, Gaussian noise 0.1, evaluation with 10 episodes after every 20-step training episode), the paper's
400-300 networks and the 64-64 ones. A configuration is built and warmed up (learning starts, kernels), then a
fixed number of steps per run is timed. Solo and pack rounds are interleaved; the median of the rounds is used.

    python benchmarks/packed.py                      # pack of 8 at 64-64, pack of 3 at 400-300, 3 rounds
    python benchmarks/packed.py --rounds 5 --steps-64 3000
    python benchmarks/packed.py --device cuda --pack-400 12   # the models on a GPU (env and evaluation stay on CPU)

ratio = (run-steps per second of the pack) / (steps per second of one solo run). The last line reads
``packed: ratio_64=<x> ratio_400=<y>``. Everything runs on one thread. The header says what explains the
figures on the machine at hand: PyTorch's build, its GEMM backends and their measured rate.
"""

import argparse
import platform
import statistics
import time

import numpy as np
import torch as th
from stable_baselines3.common.noise import NormalActionNoise

import sb3_macb
from benchmarks_common import describe_device
from sb3_macb import MACB, MADDPG
from sb3_macb.callbacks import MultiAgentEvalCallback, make_eval_vec_env
from sb3_macb.common.grouped_mlp import onednn_available
from sb3_macb.envs.vec_tasks import make_task_vec_env

ENV = "sb3_macb/CommunicativeNavigation-v0"


def build(n_runs: int, net: list[int], seed: int = 0, device: str = "cpu") -> tuple[MADDPG, MultiAgentEvalCallback]:
    seeds = [seed + k for k in range(n_runs)]
    model = MADDPG(
        "MlpPolicy",
        make_task_vec_env(ENV, n_runs, {"reward": "sparse"}),
        n_runs=n_runs,
        run_seeds=seeds,
        exploration=MACB(beta=0.8, k=512),
        action_noise=NormalActionNoise(np.zeros(5), 0.1 * np.ones(5)),
        learning_rate=1e-3,
        batch_size=100,
        learning_starts=100 * n_runs,
        policy_kwargs=dict(net_arch=net),
        device=device,
    )
    callback = MultiAgentEvalCallback(
        make_eval_vec_env(ENV, 10, seeds, {"reward": "sparse"}), n_eval_episodes=10, eval_freq=20, verbose=0, warn=False
    )
    return model, callback


def run_steps_per_second(n_runs: int, net: list[int], steps: int, device: str = "cpu") -> float:
    """Run-steps per second (summed over the pack's runs), after warm-up."""
    model, callback = build(n_runs, net, device=device)
    model.learn(200 * n_runs, callback=callback)  # learning starts at 100; 100 updates of warm-up
    start = time.perf_counter()
    model.learn(steps * n_runs, callback=callback, reset_num_timesteps=False)
    return steps * n_runs / (time.perf_counter() - start)


def gemm_rates() -> dict[str, float]:
    """GFLOP/s of one 100x400 @ 400x300 product (the paper's hidden layer at batch 100) on each backend."""
    x, w, b = th.randn(100, 400), th.randn(300, 400), th.randn(300)
    xs, ws = x.expand(2, 100, 400).contiguous(), w.t().expand(2, 400, 300).contiguous()
    calls = {"mkl addmm": lambda: th.addmm(b, x, w.t()), "bmm": lambda: th.bmm(xs, ws)}
    if onednn_available():
        calls["oneDNN linear"] = lambda: th.ops.mkldnn._linear_pointwise(x, w, b, "none", [], "")
    rates = {}
    for name, call in calls.items():
        for _ in range(20):
            call()
        n = 200
        start = time.perf_counter()
        for _ in range(n):
            call()
        flops = 2 * 100 * 400 * 300 * (2 if name == "bmm" else 1)
        rates[name] = flops * n / (time.perf_counter() - start) / 1e9
    return rates


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--pack-64", type=int, default=8)
    parser.add_argument("--pack-400", type=int, default=3)
    parser.add_argument("--steps-64", type=int, default=2000, help="timed steps per run at 64-64")
    parser.add_argument("--steps-400", type=int, default=400, help="timed steps per run at 400-300")
    parser.add_argument("--device", default="cpu", help="torch device of the models (cpu, cuda, ...)")
    args = parser.parse_args()
    th.set_num_threads(1)
    print(f"sb3_macb {sb3_macb.__version__}, torch {th.__version__}, {platform.processor() or platform.machine()}, 1 thread")
    print(f"models on: {describe_device(args.device)}")
    print("GEMM 100x400 @ 400x300, GFLOP/s: " + ", ".join(f"{k} {v:.0f}" for k, v in gemm_rates().items()))
    print("paths: 400-300 layers per group through oneDNN" if onednn_available() else "paths: no oneDNN (bmm everywhere)",
          "| 64-64 layers batched over groups (baddbmm)")  # fmt: skip
    configs = [("64-64", [64, 64], args.pack_64, args.steps_64), ("400-300", [400, 300], args.pack_400, args.steps_400)]
    results: dict[tuple[str, int], list[float]] = {}
    for round_ in range(args.rounds):
        for name, net, pack, steps in configs:
            for n_runs in (1, pack):
                rate = run_steps_per_second(n_runs, net, steps, args.device)
                results.setdefault((name, n_runs), []).append(rate)
                print(f"round {round_ + 1}: {name}, {n_runs} run(s): {rate:.0f} run-steps/s", flush=True)
    print("\n| networks | runs in the process | run-steps/s (median) | per run | ratio to solo |")
    print("|---|---|---|---|---|")
    ratios = {}
    for name, _, pack, _ in configs:
        solo = statistics.median(results[(name, 1)])
        packed = statistics.median(results[(name, pack)])
        ratios[name] = packed / solo
        print(f"| {name} | 1 | {solo:.0f} | {solo:.0f} | 1.00 |")
        print(f"| {name} | {pack} | {packed:.0f} | {packed / pack:.0f} | {ratios[name]:.2f} |")
    print(f"\npacked: ratio_64={ratios['64-64']:.2f} ratio_400={ratios['400-300']:.2f}")


if __name__ == "__main__":
    main()

"""
Where an update's time goes: torch's profiler over ``MADDPG.train`` updates on speaker-listener (2 agents, the
throughput benchmark's task), after ``learning_starts``. Prints the ms per update, the number of ``aten::copy_``
calls per update and the operators with the most self CPU time.

    python benchmarks/profile_update.py                   # 400-300, one thread, the package's GEMM path
    python benchmarks/profile_update.py --net 64 64 --updates 300
    python benchmarks/profile_update.py --no-onednn       # force the batched (MKL/bmm) path
    python benchmarks/profile_update.py --precision bf16  # products in bfloat16 (policy_kwargs precision)
"""

import argparse
import time

import numpy as np
import torch as th
from stable_baselines3.common.noise import NormalActionNoise
from torch.profiler import ProfilerActivity, profile

from sb3_macb import MADDPG
from sb3_macb.common.grouped_mlp import GroupedMLP


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--net", type=int, nargs="+", default=[400, 300])
    parser.add_argument("--updates", type=int, default=200)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--top", type=int, default=15)
    parser.add_argument("--no-onednn", action="store_true", help="use the batched path for every layer size")
    parser.add_argument("--precision", default="fp32", choices=["fp32", "bf16"])
    args = parser.parse_args()
    th.set_num_threads(args.threads)
    GroupedMLP.use_onednn = not args.no_onednn
    from benchmarks_common import describe_backend, speaker_listener  # beside this file

    env = speaker_listener()
    dim = env.action_space.shape[0]
    model = MADDPG("MlpPolicy", env, action_noise=NormalActionNoise(np.zeros(dim), 0.1 * np.ones(dim)), batch_size=100,
                   learning_starts=100, seed=0, device="cpu",
                   policy_kwargs=dict(net_arch=args.net, precision=args.precision))  # fmt: skip
    model.learn(300)
    model.train(20, 100)  # warm-up
    start = time.perf_counter()
    model.train(args.updates, 100)
    per_update = (time.perf_counter() - start) / args.updates * 1e3
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        model.train(args.updates, 100)
    events = prof.key_averages()
    copies = sum(e.count for e in events if e.key == "aten::copy_") / args.updates
    total = sum(e.self_cpu_time_total for e in events)
    print(
        f"net={args.net} threads={args.threads} onednn={GroupedMLP.use_onednn} precision={args.precision} "
        f"torch={th.__version__}"
    )
    print(f"backend: {describe_backend()}")
    print(f"{per_update:.2f} ms per update (unprofiled); aten::copy_ calls per update: {copies:.0f}")
    print("| operator | self CPU % | calls per update | us per call |")
    print("|---|---|---|---|")
    for e in sorted(events, key=lambda e: -e.self_cpu_time_total)[: args.top]:
        print(f"| {e.key} | {100 * e.self_cpu_time_total / total:.1f} | {e.count / args.updates:.1f} | "
              f"{e.self_cpu_time_total / max(e.count, 1):.1f} |")  # fmt: skip


if __name__ == "__main__":
    main()

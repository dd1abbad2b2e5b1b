"""
The two CPU paths of a large layer's products, side by side on the study's task: GroupedMLP's per-group oneDNN path
(the default for layers of >= ONEDNN_MIN_WEIGHTS weights) against the batched ``baddbmm`` path that small layers
take, alternating in one process on one model (``GroupedMLP.use_onednn`` switches the path at the next call), for a
solo run and for packs. Prints the CPU ms per update of each path, per round, and the median ratio.

    python benchmarks/update_paths.py                      # 400-300, packs of 1 and 3
    python benchmarks/update_paths.py --net 400 300 --packs 1 --rounds 5

The two paths give the same results up to float32 rounding, not bit for bit: a run's numbers depend on its path.
"""

import argparse
import time

import numpy as np
import torch as th

from sb3_macb import MADDPG
from sb3_macb.common.grouped_mlp import GroupedMLP
from sb3_macb.envs.vec_tasks import make_task_vec_env

TASK = "sb3_macb/CommunicativeNavigation-v0"


def per_update_ms(model: MADDPG, updates: int) -> float:
    """CPU time of ``updates`` updates (minibatches of 100), in ms per update."""
    start = time.process_time()
    model.train(updates, batch_size=100)
    return (time.process_time() - start) / updates * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--net", type=int, nargs="+", default=[400, 300])
    parser.add_argument("--packs", type=int, nargs="+", default=[1, 3], help="runs per model")
    parser.add_argument("--updates", type=int, default=60, help="updates per run and path in each round")
    parser.add_argument("--rounds", type=int, default=4)
    args = parser.parse_args()
    th.set_num_threads(1)
    for n_runs in args.packs:
        env = make_task_vec_env(TASK, n_runs, {"reward": "sparse"})
        model = MADDPG("MlpPolicy", env, n_runs=n_runs, seed=0, batch_size=100, buffer_size=20_000,
                       learning_starts=2_000 * n_runs, policy_kwargs=dict(net_arch=args.net))  # fmt: skip
        model.learn(2_100 * n_runs)  # buffers filled, a few updates done
        updates = max(1, args.updates // n_runs)
        ratios = []
        for rnd in range(args.rounds):
            times = {}
            for onednn in (rnd % 2 == 0, rnd % 2 == 1):  # the order swaps from round to round
                GroupedMLP.use_onednn = onednn
                per_update_ms(model, 2)  # (the first calls of a path warm it up)
                times[onednn] = per_update_ms(model, updates)
            ratios.append(times[True] / times[False])
            print(f"{'-'.join(map(str, args.net))} pack of {n_runs}, round {rnd}: oneDNN per group {times[True]:.2f} ms, "
                  f"batched {times[False]:.2f} ms per update "
                  f"({times[True] / n_runs:.2f} / {times[False] / n_runs:.2f} per run)")  # fmt: skip
        GroupedMLP.use_onednn = True
        print(f"update_paths: net={'-'.join(map(str, args.net))} pack={n_runs} onednn_over_batched={np.median(ratios):.2f}")


if __name__ == "__main__":
    main()

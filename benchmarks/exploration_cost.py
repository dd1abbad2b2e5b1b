"""
What each exploration estimator adds to a step of training, as a share of one MADDPG update, on the paper's task
(sparse Communicative Navigation, batch 100, one update per step) or one of the exploration study's, at 64-64 and
400-300 networks.

    python benchmarks/exploration_cost.py                 # tables of 8e5 codes, as at the end of a paper run
    python benchmarks/exploration_cost.py --codes 1e5 --updates 100
    python benchmarks/exploration_cost.py --task spread3 --codes 1e5 --nets 64-64   # the study's spread3

Per step, an estimator hashes and counts the collected transition (``keys`` + ``count``) and gives the bonus of a
sampled minibatch (``bonus``, with its normalisation). Both are timed on an estimator whose table already holds
``--codes`` codes, in the same process as the update they are compared with (a plain MADDPG update, medians of
interleaved blocks). The intrinsic critic (``intrinsic_critic=True``, with the centered MACB at k 32 that the study
gives it) is timed as whole updates, interleaved with plain ones: its line is what it adds to an update, estimator
included. Targets (issue 28): counts at most 10% of an update at 400-300, RND at most 25%. The last line:
``exploration_cost: <setting>@<net>=<percent> ...``.
"""

import argparse
import time
from functools import partial

import numpy as np
import torch as th

from sb3_macb import MACB, MADDPG, RND
from sb3_macb.envs.vec_tasks import make_task_vec_env

COMM = "sb3_macb/CommunicativeNavigation-v0"
TASKS = {  # the paper's task and the exploration study's (experiments/exploration/scripts/study_tasks.py)
    "comm": (COMM, {}),
    "spread3": ("sb3_macb/SparseSpread-v0", {"n_agents": 3}),
    "spread6": ("sb3_macb/SparseSpread-v0", {"n_agents": 6}),
    "comm6-wide": (COMM, {"n_landmarks": 6, "half_width": 2.0, "max_cycles": 40}),
}
SETTINGS = {
    "exact": lambda: MACB(0.8, 512),
    "exact+center": lambda: MACB(0.8, 512, normalize="center"),
    "exact+zscore": lambda: MACB(0.8, 512, normalize="zscore"),
    "sketch": lambda: MACB(0.8, 512, table="sketch"),
    "constant": lambda: MACB(0.8, 512, counts=False),
    "rnd": lambda: RND(0.8),
}


def median_us(fn, calls: int, blocks: int = 7) -> float:
    """Median over ``blocks`` of the mean time of ``calls`` calls, in microseconds."""
    times = []
    for _ in range(blocks):
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        times.append((time.perf_counter() - start) / calls * 1e6)
    return float(np.median(times))


def estimator_us(model: MADDPG, make, codes: int, calls: int) -> float:
    """One step's estimator work (count one transition, bonus of one minibatch) with ``codes`` codes counted."""
    macb = make()
    macb.setup(model.agent_layout, seed=0)
    rng = np.random.default_rng(0)
    if isinstance(macb, MACB) and macb.counts:
        for table in macb.tables:  # fill with random keys as a long run would have them (almost all new at k 512)
            table.add(rng.integers(1, 2**63, size=codes, dtype=np.uint64))
    buffer = model.replay_buffer
    n = buffer.pos
    obs, actions = buffer.observations[:n, 0], buffer.actions[:n, 0]
    stored = macb.keys(obs, actions)
    macb.count(stored)
    step = [0]

    def one_step() -> None:
        i = step[0] % n
        step[0] += 1
        macb.count(macb.keys(obs[i : i + 1], actions[i : i + 1]))
        rows = rng.integers(0, n, size=100)
        if isinstance(macb, RND):  # (its bonus reads the observations, and trains its predictor on them)
            macb.bonus(stored[rows], observations=obs[rows])
        else:
            macb.bonus(stored[rows])

    return median_us(one_step, calls)


def intrinsic_us(plain: MADDPG, intrinsic: MADDPG, calls: int, blocks: int = 7) -> tuple[float, float]:
    """Median times of a plain update and of an update with intrinsic critics, in interleaved blocks (microseconds)."""
    times: dict[int, list[float]] = {0: [], 1: []}
    for _ in range(blocks):
        for i, model in enumerate((plain, intrinsic)):
            start = time.perf_counter()
            for _ in range(calls):
                model.train(1, 100)
            times[i].append((time.perf_counter() - start) / calls * 1e6)
    return float(np.median(times[0])), float(np.median(times[1]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--codes", type=float, default=8e5, help="codes in each table before timing")
    parser.add_argument("--updates", type=int, default=50, help="updates (and estimator steps) per timed block")
    parser.add_argument("--task", choices=sorted(TASKS), default="comm", help="default: the paper's task")
    parser.add_argument("--nets", nargs="+", default=["64-64", "400-300"], help="network sizes, e.g. 64-64")
    args = parser.parse_args()
    try:
        nets = [[int(units) for units in net.split("-")] for net in args.nets]
    except ValueError:
        parser.error(f"--nets takes sizes such as 64-64 or 400-300, got {args.nets}")
    if args.updates < 1 or args.codes < 0 or any(units < 1 for net in nets for units in net):
        parser.error("--updates and every size in --nets must be >= 1, --codes >= 0")
    th.set_num_threads(1)
    env_id, env_kwargs = TASKS[args.task]
    summary = []
    print(f"task {args.task} ({env_id} {env_kwargs}), batch 100, tables of {int(args.codes)} codes")
    for net in nets:
        models = [MADDPG("MlpPolicy", make_task_vec_env(env_id, 1, env_kwargs), batch_size=100, learning_starts=2000,
                         policy_kwargs=dict(net_arch=net), seed=0, **extra)
                  for extra in ({}, {"exploration": MACB(0.8, 32, normalize="center"), "intrinsic_critic": True})]  # fmt: skip
        for trained in models:
            trained.learn(2100)  # a buffer to sample from, and optimizer state
        model = models[0]
        update = median_us(partial(model.train, 1, 100), args.updates)
        name = "-".join(map(str, net))
        print(f"{name}: one MADDPG update {update / 1000:.2f} ms")
        for setting, make in SETTINGS.items():
            cost = estimator_us(model, make, int(args.codes), args.updates)
            print(f"  {setting:13s} {cost:8.1f} us per step = {100 * cost / update:5.1f}% of an update")
            summary.append(f"{setting}@{name}={100 * cost / update:.1f}")
        plain, intrinsic = intrinsic_us(models[0], models[1], args.updates)
        extra = 100 * (intrinsic - plain) / plain
        print(f"  {'intrinsic':13s} {intrinsic - plain:8.1f} us per step = {extra:5.1f}% of an update "
              f"({intrinsic / 1000:.2f} ms against {plain / 1000:.2f} ms, interleaved, with its MACB)")  # fmt: skip
        summary.append(f"intrinsic@{name}={extra:.1f}")
    print("exploration_cost: " + " ".join(summary))


if __name__ == "__main__":
    main()

"""
What writing ``evaluations.npz`` costs over a whole run at the paper's protocol (an evaluation of 10 episodes after
every 20-step training episode: 40,000 evaluations in 8e5 steps), under two schedules: a write every ``save_freq``
(100) evaluations, as ``MultiAgentEvalCallback`` did up to 0.11.0, and a write every ``save_freq`` evaluations or
every tenth of those held where that is more, as it does now.

A write's time is measured at several sizes on records shaped like the callback's (Python lists, one entry per
evaluation, values drawn at random), fitted with a line in the number of evaluations held, and summed over each
schedule's writes.

    python benchmarks/evaluation_writes.py
    python benchmarks/evaluation_writes.py --evaluations 40000 --episodes 10 --agents 2

Last line: ``evaluation_writes: per_run_s_every_100=<x> per_run_s_growing=<y> writes_every_100=<n> writes_growing=<m>``.
"""

import argparse
import os
import tempfile
import time

import numpy as np

from sb3_macb.common import evaluations


def make_record(n: int, episodes: int, agents: int, rng: np.random.Generator) -> dict[str, list]:
    """Records of ``n`` evaluations as the callback holds them."""
    record: dict[str, list] = {name: [] for name in evaluations.FIELDS}
    for i in range(n):
        record[evaluations.TIMESTEPS].append(20 * (i + 1))
        record[evaluations.RESULTS].append([float(x) for x in rng.normal(-10.0, 5.0, episodes)])
        record[evaluations.EP_LENGTHS].append([20] * episodes)
        record[evaluations.SUCCESSES].append([bool(x) for x in rng.random(episodes) < 0.5])
        record[evaluations.FINAL_SUCCESSES].append([bool(x) for x in rng.random(episodes) < 0.5])
        record[evaluations.EPISODES].append(i + 1)
        record[evaluations.AGENT_RETURNS].append(rng.normal(-10.0, 5.0, (episodes, agents)))
        record[evaluations.COLLISIONS].append([int(x) for x in rng.integers(0, 3, episodes)])
        record[evaluations.NUM_CODES].append(i)
        record[evaluations.COUNT1_FRACTION].append(float(rng.random()))
        record[evaluations.TRAINING_COLLISIONS].append(i)
    return record


def write_seconds(n: int, episodes: int, agents: int, repeats: int = 3) -> float:
    """The fastest of ``repeats`` writes of a record of ``n`` evaluations."""
    record = make_record(n, episodes, agents, np.random.default_rng(n))
    best = np.inf
    with tempfile.TemporaryDirectory() as folder:
        for _ in range(repeats):
            start = time.perf_counter()
            evaluations.save(os.path.join(folder, evaluations.FILE_NAME), record)
            best = min(best, time.perf_counter() - start)
    return best


def schedule(total: int, save_freq: int, growing: bool) -> list[int]:
    """The numbers of evaluations held at each write during a run of ``total`` evaluations (the final write included)."""
    held, last = [], 0
    for n in range(1, total + 1):
        if n - last >= (max(save_freq, n // 10) if growing else save_freq):
            held.append(n)
            last = n
    if not held or held[-1] != total:
        held.append(total)
    return held


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--evaluations", type=int, default=40_000, help="evaluations in a run")
    parser.add_argument("--episodes", type=int, default=10, help="episodes per evaluation")
    parser.add_argument("--agents", type=int, default=2)
    parser.add_argument("--save-freq", type=int, default=100)
    args = parser.parse_args()

    sizes = np.unique(np.linspace(args.evaluations // 20, args.evaluations, 5).astype(int))
    times = np.array([write_seconds(int(n), args.episodes, args.agents) for n in sizes])
    for n, t in zip(sizes, times):
        print(f"one write of {n:>7,} evaluations: {1000 * t:7.1f} ms")
    slope, intercept = np.polyfit(sizes, times, 1)
    totals = {}
    for name, growing in (("every_100", False), ("growing", True)):
        held = np.array(schedule(args.evaluations, args.save_freq, growing))
        totals[name] = (float(np.sum(intercept + slope * held)), len(held))
        print(f"schedule {name:>9}: {len(held):>4} writes, {totals[name][0]:7.1f} s per run (fitted)")
    print(
        f"evaluation_writes: per_run_s_every_100={totals['every_100'][0]:.1f} per_run_s_growing={totals['growing'][0]:.1f} "
        f"writes_every_100={totals['every_100'][1]} writes_growing={totals['growing'][1]}"
    )


if __name__ == "__main__":
    main()

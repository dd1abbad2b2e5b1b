"""
What the paper's evaluation protocol (10 noise-free episodes after every 20-step training episode: 40,000
evaluations in 8e5 steps) costs beside training, in two parts:

1. One evaluation of a pack of 8 runs at 64-64 on sparse Communicative Navigation (80 episodes as one batch), in ms:
   this checkout, and with ``--baseline DIR`` a second checkout, run in turn (A B A B ...) in fresh processes.
2. Writing ``evaluations.npz`` over a whole run, under two schedules: a write every ``save_freq`` (100)
   evaluations, as ``MultiAgentEvalCallback`` did before 0.12.0, and a write every ``save_freq`` evaluations or every
   tenth of those held where that is more, as it does now. A write's time is measured at several sizes on records
   shaped like the callback's (one entry per evaluation, values drawn at random), fitted with a line in the number
   of evaluations held, and summed over each schedule's writes.

    python benchmarks/evaluation_cost.py
    python benchmarks/evaluation_cost.py --baseline /tmp/base --rounds 3

Last line: ``evaluation_cost: eval_ms=<x> [baseline_eval_ms=<y>] per_run_write_s_every_100=<a>
per_run_write_s_growing=<b> writes_every_100=<n> writes_growing=<m>``.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

ENV = "sb3_macb/CommunicativeNavigation-v0"


def eval_worker(pack: int, blocks: int = 5, per_block: int = 20) -> None:
    """ms per evaluation of the checkout first on ``sys.path`` (median of ``blocks`` blocks): prints a JSON line."""
    import torch as th
    from stable_baselines3.common.noise import NormalActionNoise

    import sb3_macb
    from sb3_macb import MACB, MADDPG
    from sb3_macb.callbacks import MultiAgentEvalCallback, make_eval_vec_env
    from sb3_macb.envs.vec_tasks import make_task_vec_env

    th.set_num_threads(1)
    seeds = list(range(pack))
    model = MADDPG(
        "MlpPolicy", make_task_vec_env(ENV, pack, {"reward": "sparse"}), n_runs=pack, run_seeds=seeds,
        exploration=[MACB(beta=0.8, k=512) for _ in seeds],
        action_noise=[NormalActionNoise(np.zeros(5), 0.1 * np.ones(5)) for _ in seeds],
        batch_size=100, learning_starts=100 * pack, policy_kwargs=dict(net_arch=[64, 64]), buffer_size=10_000, device="cpu",
    )  # fmt: skip
    callback = MultiAgentEvalCallback(make_eval_vec_env(ENV, 10, seeds, {"reward": "sparse"}), n_eval_episodes=10,
                                      eval_freq=20, verbose=0, warn=False, dump_logs=False)  # fmt: skip
    model.learn(200 * pack, callback=callback)  # (100 updates: the actors are not at their initial weights)
    times = []
    for _ in range(blocks):
        start = time.perf_counter()
        for _ in range(per_block):
            callback._evaluate()
        times.append((time.perf_counter() - start) / per_block * 1e3)
    print(json.dumps({"version": sb3_macb.__version__, "ms": statistics.median(times)}))


def eval_ms(checkout: str, pack: int) -> float:
    """One fresh process of ``eval_worker`` with ``checkout`` first on its path."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([checkout, os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep))
    out = subprocess.run([sys.executable, os.path.abspath(__file__), "--worker", "--pack", str(pack)], env=env,
                         cwd=checkout, capture_output=True, text=True, check=True).stdout  # fmt: skip
    return float(json.loads(out.strip().splitlines()[-1])["ms"])


def make_record(n: int, episodes: int, agents: int, rng: np.random.Generator) -> dict[str, list]:
    """Records of ``n`` evaluations as the callback holds them."""
    from sb3_macb.common import evaluations

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
    from sb3_macb.common import evaluations

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
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--baseline", default=None, help="a second checkout (e.g. a git worktree of an earlier commit)")
    parser.add_argument("--rounds", type=int, default=3, help="processes per checkout for the evaluation time")
    parser.add_argument("--pack", type=int, default=8, help="runs in the pack evaluated")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--evaluations", type=int, default=40_000, help="evaluations in a run")
    parser.add_argument("--episodes", type=int, default=10, help="episodes per evaluation")
    parser.add_argument("--agents", type=int, default=2)
    parser.add_argument("--save-freq", type=int, default=100)
    args = parser.parse_args()
    if args.worker:
        sys.path.insert(0, os.getcwd())
        eval_worker(args.pack)
        return
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    sys.path.insert(0, root)
    checkouts = {"ours": root, **({"baseline": os.path.abspath(args.baseline)} if args.baseline else {})}
    ms: dict[str, list[float]] = {name: [] for name in checkouts}
    for _ in range(args.rounds):
        for name, checkout in checkouts.items():
            ms[name].append(eval_ms(checkout, args.pack))
            print(f"one evaluation of a pack of {args.pack} at 64-64, {name}: {ms[name][-1]:.1f} ms", flush=True)
    medians = {name: statistics.median(values) for name, values in ms.items()}

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
    baseline = f" baseline_eval_ms={medians['baseline']:.1f}" if "baseline" in medians else ""
    print(
        f"evaluation_cost: eval_ms={medians['ours']:.1f}{baseline} per_run_write_s_every_100={totals['every_100'][0]:.1f} "
        f"per_run_write_s_growing={totals['growing'][0]:.1f} writes_every_100={totals['every_100'][1]} "
        f"writes_growing={totals['growing'][1]}"
    )


if __name__ == "__main__":
    main()

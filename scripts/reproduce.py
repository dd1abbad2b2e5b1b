"""
Run the paper's experiments with the zoo's YAML and ``sb3-macb train``, and file the evaluation data as
``results/<Task>-<reward>/<variant>/seed_<s>/evaluations.npz`` with the run's wall time and command in
``run.json`` beside it.

    python scripts/reproduce.py --task comm-sparse --variants maddpg macb_joint --seeds 0 1 2 -n 200000 --fast -j 2
    python scripts/reproduce.py --task nav --variants maddpg ddpg macb_joint ddpg_macb --seeds 0 1 2

Variants are those of ``zoo/hyperparams/maddpg.yml``; ``--fast`` adds the ``fast`` variant (64-64 networks).
Runs already filed are skipped, so the script can be re-run to complete a set.
"""

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor

TASKS = {
    "comm-sparse": ("sb3_macb/CommunicativeNavigation-v0", "CommunicativeNavigation-sparse", "reward:'sparse'"),
    "comm-distance": ("sb3_macb/CommunicativeNavigation-v0", "CommunicativeNavigation-distance", "reward:'distance'"),
    "nav": ("sb3_macb/TwoAgentNavigation-v0", "TwoAgentNavigation-sparse", None),
}


def run_one(task: str, variant: str, seed: int, n_timesteps: int, fast: bool, out_root: str) -> str:
    env_id, folder, env_kwargs = TASKS[task]
    target = os.path.join(out_root, folder, variant, f"seed_{seed}")
    if os.path.isfile(os.path.join(target, "evaluations.npz")):
        return f"{target}: already there"
    variants = [variant] + (["fast"] if fast else [])
    with tempfile.TemporaryDirectory() as logs:
        cmd = [sys.executable, "-m", "sb3_macb", "train", "--env", env_id, "--seed", str(seed), "-n", str(n_timesteps),
               "-f", logs, "--variant", ",".join(variants), "--no-progress", "--verbose", "0"]  # fmt: skip
        if env_kwargs:
            cmd += ["--env-kwargs", env_kwargs]
        start = time.time()
        result = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.time() - start
        if result.returncode != 0:
            return f"{target}: FAILED\n{result.stdout[-2000:]}\n{result.stderr[-2000:]}"
        runs = [os.path.join(dp, f) for dp, _, files in os.walk(logs) for f in files if f == "evaluations.npz"]
        os.makedirs(target, exist_ok=True)
        shutil.copy(runs[0], os.path.join(target, "evaluations.npz"))
        printable = ["sb3-macb", *cmd[3:]]
        printable[printable.index("-f") + 1] = "LOGDIR"
        with open(os.path.join(target, "run.json"), "w") as file:
            json.dump({"command": " ".join(printable), "wall_time_s": round(wall, 1), "n_timesteps": n_timesteps,
                       "variants": variants, "seed": seed}, file, indent=1)  # fmt: skip
    return f"{target}: {wall:.0f} s"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", choices=sorted(TASKS), required=True)
    parser.add_argument("--variants", nargs="+", required=True)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("-n", "--n-timesteps", type=int, default=800_000)
    parser.add_argument("--fast", action="store_true", help="64-64 networks (the 'fast' variant)")
    parser.add_argument("-j", "--jobs", type=int, default=1, help="runs in parallel (one thread each)")
    parser.add_argument("-o", "--out", default="results")
    args = parser.parse_args()
    jobs = [(args.task, v, s, args.n_timesteps, args.fast, args.out) for s in args.seeds for v in args.variants]
    with ThreadPoolExecutor(args.jobs) as pool:
        for line in pool.map(lambda job: run_one(*job), jobs):
            print(line, flush=True)


if __name__ == "__main__":
    main()

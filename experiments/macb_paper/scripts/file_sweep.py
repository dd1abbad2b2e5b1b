"""
File a finished ``sb3-macb sweep`` under ``results/``: each trial's ``evaluations.npz`` goes to
``OUT/<param>_<value>_.../seed_<s>/`` and ``OUT/results.csv`` lists the trials with those folders.

    python scripts/file_sweep.py logs/sweeps/table1_fast results/CommunicativeNavigation-sparse/table1

Trial folders hold models and logs as well; only the evaluation data is kept.
"""

import argparse
import csv
import os
import shutil

from sb3_macb.common.evaluations import FILE_NAME


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sweep_folder", help="LOGDIR/STUDY_NAME of the sweep (holds results.csv)")
    parser.add_argument("out")
    args = parser.parse_args()
    with open(os.path.join(args.sweep_folder, "results.csv"), newline="") as file:
        rows = list(csv.DictReader(file))
    if not rows:
        raise SystemExit(f"{args.sweep_folder}/results.csv lists no finished trial")
    params = [name for name in rows[0] if name not in ("trial", "seed", "success_rate", "count1_fraction", "run_folder")]
    for row in rows:
        name = "_".join(f"{p.split('.')[-1]}_{row[p]}" for p in params)
        target = os.path.join(args.out, name, f"seed_{row['seed']}")
        os.makedirs(target, exist_ok=True)
        shutil.copy(os.path.join(row["run_folder"], FILE_NAME), os.path.join(target, FILE_NAME))
        row["run_folder"] = os.path.relpath(target, args.out)
    with open(os.path.join(args.out, "results.csv"), "w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print(f"{len(rows)} trials filed under {args.out}")


if __name__ == "__main__":
    main()

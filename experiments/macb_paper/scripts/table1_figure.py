"""
The figure of Table 1 at the paper's budget: the cells that ``scripts/table1_analysis.py`` reads (the grid's runs and
the headline's two cells from ``--base``), seeds ``0 .. expected-seeds - 1``, complete runs only, written as a sweep's
``results.csv`` (one row per run: ``exploration.k``, ``exploration.beta``, ``success_rate`` = final any-step success,
``count1_fraction`` = count-1 at the last evaluation) and drawn by ``sb3-macb plot table`` (``OUTPUT.csv``,
``OUTPUT.md``, ``OUTPUT.png``; the title names the grid's 64-64 networks and 4e4 episodes, and MADDPG's and the
constant bonus's seed means). Decides nothing: the decisions are the analysis script's.

    python scripts/table1_figure.py results/CommunicativeNavigation-sparse-table1-4e4 \\
        --base results/CommunicativeNavigation-sparse-4e4-1e6 --expected-seeds 3 -o img/table1_4e4
"""

import argparse
import csv
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from sb3_macb.zoo.plots import plot_table  # noqa: E402
from table1_analysis import load, success  # noqa: E402  (a sibling script)


def write_csv(task_folder: str, base_folder: str, seeds: int, path: str) -> str:
    """The runs of every cell as a sweep's results.csv; returns the title's note on MADDPG and the control."""
    cells, base, missing = load(task_folder, base_folder, seeds)
    if missing:
        raise SystemExit(f"table1_figure.py: short of {seeds} complete seeds: {', '.join(missing)}")
    with open(path, "w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(["exploration.k", "exploration.beta", "seed", "success_rate", "count1_fraction"])
        for (beta, k), runs in sorted(cells.items(), key=lambda item: (item[0][1], item[0][0])):
            for run in runs:
                writer.writerow([k, beta, run.seed, run.final_any, run.count1])
    return f"MADDPG {success(base['maddpg']):.2f}, constant bonus {success(base['macb_constant']):.2f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("task_folder", help="the grid's runs (reproduce.py --grid ... --suffix table1-4e4)")
    parser.add_argument("--base", required=True, help="the headline's 64-64 runs with the registered buffer")
    parser.add_argument("--expected-seeds", type=int, required=True, help="the seeds per cell (0 .. N-1)")
    parser.add_argument("-o", "--output", default="table1_4e4", help="output prefix (.csv, .md and .png)")
    args = parser.parse_args()
    for folder in (args.task_folder, args.base):
        if not os.path.isdir(folder):
            raise SystemExit(f"table1_figure.py: {folder} is not a folder")
    note = write_csv(args.task_folder, args.base, args.expected_seeds, f"{args.output}.csv")
    title = f"64-64, 4e4 episodes, final any-step success; {note}"
    print(plot_table(f"{args.output}.csv", args.output, title=title))


if __name__ == "__main__":
    main()

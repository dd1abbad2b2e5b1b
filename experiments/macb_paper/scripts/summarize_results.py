"""
Summarize ``results/<Task>-<reward>/<variant>/seed_<s>/`` as markdown: episodes to a success-rate threshold (mean and
spread over seeds), final success rate, wall time per run, and the commands that produced them.

    python scripts/summarize_results.py results/CommunicativeNavigation-sparse

Episodes to threshold: the first evaluation at which the success rate averaged over the last ``--window``
evaluations (10 evaluations = 100 evaluation episodes by default) reaches the threshold. A run that never reaches
it is censored at its last episode (marked ">"); the table says how many seeds reached it and gives the
Kaplan-Meier median (none while fewer than half reached it), never a mean over censored values.
``--metric final_successes`` uses the final-step success instead of the any-step success (the paper's).
``--max-episodes`` cuts every run at that many training episodes, to compare runs of different lengths at one budget
(a run's first N episodes are the run it would have been with that budget: the same seed gives the same run, and
nothing in the settings depends on the total budget).
"""

import argparse
import glob
import json
import os

import numpy as np

from sb3_macb.common import evaluations

episodes_to = evaluations.episodes_to
km_median = evaluations.km_median
load_run = evaluations.load


def sample_sd(values: list[float]) -> float:
    """The seeds' sample standard deviation (n - 1 in the denominator); 0 for a single seed."""
    return float(np.std(values, ddof=1)) if len(values) > 1 else 0.0


def summarize(
    task_folder: str,
    threshold: float,
    window: int,
    final: int,
    max_episodes: int | None = None,
    collisions: bool = False,
    metric: str = evaluations.SUCCESSES,
    complete_only: bool = False,
) -> str:
    name = evaluations.SUCCESS_METRICS.get(metric, metric)
    lines = [
        f"| variant | seeds | reached {threshold:.0%} {name} | Kaplan-Meier median episodes | episodes per seed | final "
        f"{name} (last {final} evals), mean +/- sample SD | per seed | episodes run | wall time per run |"
        + (" training collisions (mean +/- sample SD) |" if collisions else ""),
        "|---|---|---|---|---|---|---|---|---|" + ("---|" if collisions else ""),
    ]
    commands = []
    for variant in sorted(os.listdir(task_folder)):
        runs = sorted(glob.glob(os.path.join(task_folder, variant, "seed_*", evaluations.FILE_NAME)))
        if complete_only:
            runs = [path for path in runs if evaluations.is_complete(os.path.dirname(path))]
        if not runs:
            continue
        reached, hit, per_seed, finals, walls, crashes, lengths, packs = [], [], [], [], [], [], [], []
        for path in runs:
            data = load_run(path, max_episodes)
            if metric not in data:
                continue
            value, ok = episodes_to(data[metric], evaluations.episodes(data), threshold, window)
            reached.append(value)
            hit.append(ok)
            per_seed.append(f"{value:.0f}" if ok else f">{value:.0f}")
            finals.append(float(data[metric][-final:].mean()))
            lengths.append(int(evaluations.episodes(data)[-1]))
            if collisions:
                crashes.append(float(data[evaluations.TRAINING_COLLISIONS][-1]))
            meta_path = os.path.join(os.path.dirname(path), "run.json")
            if os.path.isfile(meta_path) and metric in load_run(path):
                with open(meta_path) as file:
                    meta = json.load(file)
                walls.append(meta["wall_time_s"])
                packs.append(int(meta.get("pack_size", 1)))
                commands.append(meta["command"])
        if not reached:
            continue
        wall = f"{np.mean(walls) / 60:.1f} min" if walls else "-"
        if packs and max(packs) > 1:  # the runs of a pack share one process: its wall time is theirs together
            wall += f" (a pack of {max(packs)})"
        median = km_median(reached, hit)
        median_text = "not reached" if median is None else f"{median:.0f}"
        finals_text = f"{np.mean(finals):.3f} +/- {sample_sd(finals):.3f} | {', '.join(f'{f:.3f}' for f in finals)}"
        lines.append(
            f"| {variant} | {len(reached)} | {sum(hit)} of {len(hit)} | {median_text} | "
            f"{', '.join(per_seed)} | {finals_text} | "
            f"{', '.join(map(str, lengths))} | {wall} |"
            + (f" {np.mean(crashes):.0f} +/- {sample_sd(crashes):.0f} |" if collisions else "")
        )
    text = "\n".join(lines)
    if commands:
        text += "\n\nCommands (one per run):\n\n```\n" + "\n".join(sorted(set(commands))) + "\n```\n"
    return text


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("task_folders", nargs="+")
    parser.add_argument("--threshold", type=float, default=0.9)
    parser.add_argument("--window", type=int, default=10)
    parser.add_argument("--final", type=int, default=50)
    parser.add_argument("--collisions", action="store_true", help="add the accumulated training collisions")
    parser.add_argument("--max-episodes", type=int, default=None, help="cut every run at this many training episodes")
    parser.add_argument("--metric", default=evaluations.SUCCESSES, choices=list(evaluations.SUCCESS_METRICS),
                        help="any-step success (the paper's) or final-step success")  # fmt: skip
    parser.add_argument("--complete-only", action="store_true", help="leave out runs still in progress")
    args = parser.parse_args()
    for value, name in ((args.window, "--window"), (args.final, "--final")):
        if value < 1:
            parser.error(f"{name} must be >= 1 (evaluations), got {value}")
    for folder in args.task_folders:
        print(f"### {os.path.basename(os.path.normpath(folder))}\n")
        print(summarize(folder, args.threshold, args.window, args.final, args.max_episodes, args.collisions, args.metric,
                        args.complete_only))  # fmt: skip
        print()


if __name__ == "__main__":
    main()

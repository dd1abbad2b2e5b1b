"""
The exploration study's curves: one figure per task, one panel per method, each seed's success rate (thin) and the
seed mean (thick) against training episodes, with plain MADDPG's seed mean (dashed) and the task's scripted and
random levels (gray) in every panel. Complete runs only.

    python scripts/plot_study.py --task spread3 -o img/spread3.png
    python scripts/plot_study.py --task spread3-400-300 -o img/spread3-400-300.png   # a 400-300 follow-up
"""

import argparse
import json
import os
import sys

import numpy as np

STUDY = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CHECKOUT = os.path.dirname(os.path.dirname(STUDY))
sys.path[:0] = [p for p in (CHECKOUT, os.path.join(STUDY, "scripts")) if p not in sys.path[:2]]

from analyze import load_runs  # noqa: E402
from run_study import METHODS  # noqa: E402
from sb3_macb.common import evaluations  # noqa: E402
from study_tasks import CANDIDATES  # noqa: E402


def _base_task(folder: str) -> str:
    """The candidate task a results folder belongs to (``spread3-400-300`` -> ``spread3``)."""
    matches = [t for t in CANDIDATES if folder == t or folder.startswith(t + "-")]
    if not matches:
        raise SystemExit(f"--task: {folder!r} is not a study task or a task's follow-up folder; tasks: {sorted(CANDIDATES)}")
    return max(matches, key=len)


def plot_task(results: str, folder: str, output: str, window: int, levels: dict[str, float] | None) -> list[str]:
    """
    Draw one task's figure.

    :param results: The study's results folder.
    :param folder: The task's folder under ``results`` (a task, or ``<task>-<sizes>`` for a follow-up).
    :param output: The image file to write.
    :param window: Evaluations in the trailing moving average of each curve (1: none).
    :param levels: The task's ``scripted`` and ``random`` levels; None: not drawn.
    :return: The methods drawn, with their numbers of complete seeds.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = {m: load_runs(results, folder, m) for m in METHODS}
    runs = {m: r for m, r in runs.items() if r}
    if not runs:
        raise SystemExit(f"no complete runs under {os.path.join(results, folder)}")

    def smoothed(run: dict[str, np.ndarray]) -> np.ndarray:
        return evaluations.moving_average(evaluations.rate(run), max(window, 1))

    def seed_mean(method: str) -> tuple[np.ndarray, np.ndarray]:
        curves = [smoothed(r) for r in runs[method].values()]
        length = min(len(c) for c in curves)
        x = evaluations.episodes(next(iter(runs[method].values())))[:length]
        return x, np.mean([c[:length] for c in curves], axis=0)

    columns = min(4, len(runs))
    rows = -(-len(runs) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(4.2 * columns, 3.3 * rows), sharex=True, sharey=True, squeeze=False)
    drawn = []
    for ax, (method, seeds) in zip(axes.flat, runs.items()):
        for seed, run in seeds.items():
            curve = smoothed(run)
            ax.plot(evaluations.episodes(run)[: len(curve)], curve, linewidth=0.7, alpha=0.6, label=f"seed {seed}")
        ax.plot(*seed_mean(method), color="black", linewidth=1.8, label="seed mean")
        if method != "maddpg" and "maddpg" in runs:
            ax.plot(*seed_mean("maddpg"), color="tab:red", linestyle="--", linewidth=1.2, label="maddpg's seed mean")
        if levels:
            ax.axhline(levels["scripted"], color="gray", linestyle="-.", linewidth=1, label="scripted")
            ax.axhline(levels["random"], color="gray", linestyle=":", linewidth=1, label="random actions")
        ax.set_title(f"{method} ({len(seeds)} seed{'' if len(seeds) == 1 else 's'})", fontsize=10)
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
        drawn.append(f"{method} ({len(seeds)})")
    for ax in axes.flat[len(runs) :]:
        ax.axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("training episodes")
    for ax in axes[:, 0]:
        ax.set_ylabel("success rate")
    axes.flat[0].legend(loc="upper left", fontsize=7)
    fig.suptitle(f"{folder}: evaluation success rate (10 episodes after each training episode), moving average of "
                 f"{max(window, 1)} evaluations; thin lines are seeds")  # fmt: skip
    fig.tight_layout()
    fig.savefig(output, dpi=100)
    plt.close(fig)
    return drawn


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", required=True, help="a task, or a follow-up's folder such as spread3-400-300")
    parser.add_argument("--results", default=os.path.join(STUDY, "results"))
    parser.add_argument("--levels", default=os.path.join(STUDY, "reference_levels.json"))
    parser.add_argument("--window", type=int, default=100, help="moving average, in evaluations (default 100)")
    parser.add_argument("-o", "--output", required=True, help="the image file (.png)")
    args = parser.parse_args()
    if args.window < 1:
        parser.error("--window must be >= 1 (1: no moving average)")
    task = _base_task(args.task)
    levels = None
    if os.path.isfile(args.levels):
        with open(args.levels) as file:
            levels = json.load(file)["levels"].get(task)
    print(", ".join(plot_task(args.results, args.task, args.output, args.window, levels)))


if __name__ == "__main__":
    main()

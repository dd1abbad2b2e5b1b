"""
``sb3-macb plot``: the paper's figures from evaluation files and sweep results.

    sb3-macb plot curves RUN_GROUP [RUN_GROUP ...] -o curves.png      # success rate and return vs episodes
    sb3-macb plot collisions RUN_GROUP [RUN_GROUP ...] -o collisions.png
    sb3-macb plot table logs/sweeps/NAME/results.csv -o table          # table.md and table.png (beta x k)
    sb3-macb plot simhash -o simhash.png                               # the paper's Figure 2

A run group is a folder holding one ``evaluations.npz`` per seed anywhere below it (e.g.
``results/CommunicativeNavigation-sparse/macb_joint`` with ``seed_0/``, ``seed_1/``, ...); it is labelled by its
folder name. Curves are the mean over seeds with a confidence band (75% by default, as the paper), after a moving
average over ``--smooth`` evaluations.
"""

import argparse
import csv
import json
import os
import warnings
from typing import Any

import numpy as np

from sb3_macb.common import evaluations

# two-sided Student t quantiles for small samples: {confidence: {degrees of freedom: t}}
_T = {
    0.75: {1: 2.414, 2: 1.604, 3: 1.423, 4: 1.344, 5: 1.301, 6: 1.273, 7: 1.254, 8: 1.240, 9: 1.230, 10: 1.221},
    0.95: {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306, 9: 2.262, 10: 2.228},
}
_Z = {0.75: 1.150, 0.95: 1.960}


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


load_group = evaluations.load_group


def mean_and_band(curves: list[np.ndarray], confidence: float) -> tuple[np.ndarray, np.ndarray]:
    """Mean over seeds and the half-width of the confidence interval of that mean (t-distribution)."""
    length = min(len(c) for c in curves)
    stacked = np.stack([c[:length] for c in curves])
    mean = stacked.mean(axis=0)
    if len(curves) < 2:
        return mean, np.zeros_like(mean)
    dof = len(curves) - 1
    t = _T.get(confidence, {}).get(dof, _Z.get(confidence, 1.0))
    return mean, t * stacked.std(axis=0, ddof=1) / np.sqrt(len(curves))


_x_axis = evaluations.episodes


def _label(folder: str, n_runs: int) -> str:
    """A group's legend entry: its folder name and how many seeds it averages."""
    return f"{os.path.basename(os.path.normpath(folder))} ({n_runs} seed{'' if n_runs == 1 else 's'})"


def _task(groups: list[str]) -> str:
    """The task folders the groups sit in (e.g. ``CommunicativeNavigation-sparse-4e4``), for the title."""
    names = sorted({os.path.basename(os.path.dirname(os.path.normpath(folder))) or "." for folder in groups})
    return ", ".join(names)


def _shortest(folder: str, runs: list[dict[str, np.ndarray]]) -> int:
    """The evaluations of the group's shortest run, with a warning when its runs differ in length."""
    lengths = [len(r[evaluations.SUCCESSES]) for r in runs]
    if min(lengths) != max(lengths):
        warnings.warn(
            f"{folder}: its runs have {min(lengths)} to {max(lengths)} evaluations; its curve ends at the shortest "
            f"(episode {int(_x_axis(runs[0])[min(lengths) - 1])}); --complete-only leaves runs in progress out",
            stacklevel=3,
        )
    return min(lengths)


def plot_curves(
    groups: list[str],
    output: str,
    window: int = 50,
    confidence: float = 0.75,
    reference: str | None = None,
    complete_only: bool = False,
) -> str:
    """
    Success rate (any-step and, where recorded, final-step) and mean evaluation return against training episodes,
    one line per run group; with ``reference`` (the JSON of the study's ``scripts/task_levels.py``) the scripted
    listeners' levels as horizontal lines. With ``complete_only``, runs still in progress are left out (otherwise
    a group's curve ends where its shortest run does, with a warning).

    :param groups: Run-group folders: every evaluations.npz below one (at any depth) is a run of that group.
    :param output: The image file to write.
    :param window: Evaluations in the trailing moving average (:func:`~sb3_macb.common.evaluations.moving_average`,
        whose first points average what is there); 0 or 1: none.
    :param confidence: Level of the band around the mean over seeds.
    :param reference: The scripted listeners' levels (JSON), drawn as horizontal lines; None: none.
    :param complete_only: Leave out runs whose ``run.json`` does not say ``complete``.
    :return: The figure's title (task folders, seeds' band, the smoothing actually applied, episodes shown).
    """
    window = max(int(window), 1)
    plt = _pyplot()
    all_runs = {folder: load_group(folder, complete_only=complete_only) for folder in groups}
    panels = [(evaluations.SUCCESSES, "any-step success rate"), (evaluations.RESULTS, "mean return")]
    if all(evaluations.FINAL_SUCCESSES in r for runs in all_runs.values() for r in runs):
        panels.insert(1, (evaluations.FINAL_SUCCESSES, "final-step success rate"))
    fig, axes = plt.subplots(1, len(panels), figsize=(6 * len(panels), 4.5))
    shortest = {folder: _shortest(folder, runs) for folder, runs in all_runs.items()}
    for folder, runs in all_runs.items():
        label = _label(folder, len(runs))
        x = _x_axis(runs[0])
        for ax, (key, _) in zip(axes, panels):
            if not all(key in r for r in runs):
                continue
            curves = [evaluations.moving_average(evaluations.rate(r, key), window) for r in runs]
            mean, band = mean_and_band(curves, confidence)
            xs = x[: len(mean)]
            ax.plot(xs, mean, label=label)
            ax.fill_between(xs, mean - band, mean + band, alpha=0.25)
    if reference:
        with open(reference) as file:
            levels = json.load(file)
        styles = {"random_landmark": ":", "landmark_tour": "--", "oracle": "-."}
        for ax, (key, _) in zip(axes, panels):
            field = {
                evaluations.SUCCESSES: "any_step",
                evaluations.FINAL_SUCCESSES: "final_step",
                evaluations.RESULTS: "mean_return",
            }[key]
            for name, level in levels.items():
                ax.axhline(level[field], color="gray", linestyle=styles.get(name, "-"), linewidth=1,
                           label=f"{name.replace('_', ' ')} (scripted)")  # fmt: skip
    for ax, (key, title) in zip(axes, panels):
        ylabel = "mean return" if key == evaluations.RESULTS else "success rate"
        ax.set(xlabel="training episodes", ylabel=ylabel, title=f"Evaluation: {title}")
        if key != evaluations.RESULTS:
            ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper left", fontsize=7)
    applied = min(window, max(shortest.values()))
    episodes = max(int(_x_axis(runs[0])[shortest[folder] - 1]) for folder, runs in all_runs.items())
    title = (f"{_task(groups)}: mean over seeds, {int(confidence * 100)}% confidence band, moving average of "
             f"{applied} evaluation{'' if applied == 1 else 's'}, {episodes} training episodes")  # fmt: skip
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(output, dpi=110)
    plt.close(fig)
    return title


def plot_collisions(groups: list[str], output: str, confidence: float = 0.75) -> None:
    """Accumulated collisions during training against episodes (the paper's collision figure)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for folder in groups:
        runs = [r for r in load_group(folder) if evaluations.TRAINING_COLLISIONS in r]
        if not runs:
            raise ValueError(
                f"{folder}: the evaluation files have no training_collisions (MultiAgentEvalCallback writes them)"
            )
        mean, band = mean_and_band([r[evaluations.TRAINING_COLLISIONS].astype(float) for r in runs], confidence)
        xs = _x_axis(runs[0])[: len(mean)]
        ax.plot(xs, mean, label=_label(folder, len(runs)))
        ax.fill_between(xs, mean - band, mean + band, alpha=0.25)
    ax.set(xlabel="training episodes", ylabel="accumulated collisions", title=f"{_task(groups)}: collisions during training")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(output, dpi=120)
    plt.close(fig)


def sweep_table(
    results_csv: str, row: str = "exploration.k", column: str = "exploration.beta"
) -> tuple[list, list, np.ndarray, np.ndarray, np.ndarray]:
    """Mean success rate and count-1 fraction over seeds for each (row, column) cell of a sweep."""
    with open(results_csv) as file:
        records = list(csv.DictReader(file))
    if not records:
        raise ValueError(f"{results_csv} holds no finished trials")
    for name in (row, column):
        if name not in records[0]:
            raise ValueError(f"{results_csv} has no column '{name}' (columns: {list(records[0])})")
    rows = sorted({float(r[row]) for r in records})
    cols = sorted({float(r[column]) for r in records})
    success = np.full((len(rows), len(cols)), np.nan)
    count1 = np.full((len(rows), len(cols)), np.nan)
    seeds = np.zeros((len(rows), len(cols)), dtype=int)
    for i, rv in enumerate(rows):
        for j, cv in enumerate(cols):
            cell = [r for r in records if float(r[row]) == rv and float(r[column]) == cv]
            if cell:
                success[i, j] = np.mean([float(r["success_rate"]) for r in cell])
                count1[i, j] = np.mean([float(r["count1_fraction"]) for r in cell])
                seeds[i, j] = len(cell)
    return rows, cols, success, count1, seeds


def plot_table(
    results_csv: str, output: str, row: str = "exploration.k", column: str = "exploration.beta", title: str | None = None
) -> str:
    """
    The paper's Table 1 (success rate, count-1 %) as ``OUTPUT.md`` and a heatmap ``OUTPUT.png``, both captioned with
    the sweep's name (the folder of a ``results.csv``, else the file's name without its extension), the seeds per cell
    and ``title``.
    """
    rows, cols, success, count1, seeds = sweep_table(results_csv, row, column)
    path = os.path.abspath(results_csv)
    name = os.path.basename(os.path.dirname(path) if os.path.basename(path) == "results.csv" else os.path.splitext(path)[0])
    n_seeds = sorted({int(n) for n in np.unique(seeds) if n > 0})
    caption = f"{name}: seeds per cell {'/'.join(map(str, n_seeds))}" + (f", {title}" if title else "")
    fmt = lambda v: f"{v:g}"  # noqa: E731
    lines = [f"| {row} \\ {column} | " + " | ".join(fmt(c) for c in cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for i, rv in enumerate(rows):
        cells = [
            "-" if np.isnan(success[i, j]) else f"{success[i, j]:.2f}, {100 * count1[i, j]:.0f}% (n={seeds[i, j]})"
            for j in range(len(cols))
        ]
        lines.append(f"| {fmt(rv)} | " + " | ".join(cells) + " |")
    markdown = f"{caption}\n\n" + "\n".join(lines) + "\n\ncells: success rate, count-1 percentage (n = seeds)\n"
    with open(f"{output}.md", "w") as file:
        file.write(markdown)

    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for ax, values, panel, cmap in (
        (axes[0], success, "success rate", "viridis"),
        (axes[1], 100 * count1, "count-1 %", "magma"),
    ):
        image = ax.imshow(values, cmap=cmap, aspect="auto", origin="lower")
        ax.set_xticks(range(len(cols)), [fmt(c) for c in cols])
        ax.set_yticks(range(len(rows)), [fmt(r) for r in rows])
        ax.set(xlabel=column, ylabel=row, title=panel)
        low, high = np.nanmin(values), np.nanmax(values)
        for i in range(len(rows)):
            for j in range(len(cols)):
                if not np.isnan(values[i, j]):
                    bright = high > low and (values[i, j] - low) / (high - low) > 0.6  # dark text on light cells
                    ax.text(j, i, f"{values[i, j]:.2f}" if panel == "success rate" else f"{values[i, j]:.0f}",
                            ha="center", va="center", color="k" if bright else "w", fontsize=9)  # fmt: skip
        fig.colorbar(image, ax=ax)
    fig.suptitle(caption)
    fig.tight_layout()
    fig.savefig(f"{output}.png", dpi=120)
    plt.close(fig)
    return markdown


def plot_simhash(output: str, ks: tuple[int, ...] = (8, 16, 32), n_points: int = 2000, seed: int = 0) -> None:
    """The paper's Figure 2: random 2-D points in (-1, 1)^2 coloured by their SimHash code, for several k."""
    from sb3_macb.exploration import SimHash

    plt = _pyplot()
    rng = np.random.default_rng(seed)
    points = rng.uniform(-1, 1, size=(n_points, 2)).astype(np.float32)
    fig, axes = plt.subplots(1, len(ks), figsize=(4.2 * len(ks), 4.2))
    for ax, k in zip(np.atleast_1d(axes), ks):
        keys = SimHash(k, 2, np.random.default_rng(seed), decimals=None).keys(points)
        _, groups = np.unique(keys, return_inverse=True)
        colours = np.random.default_rng(1).permutation(groups.max() + 1)[groups]
        ax.scatter(points[:, 0], points[:, 1], c=colours, cmap="hsv", s=6)
        ax.set(title=f"k = {k}: {groups.max() + 1} codes", xlim=(-1, 1), ylim=(-1, 1), aspect="equal")
    fig.suptitle(f"SimHash grouping of {n_points} random points (same colour = same code)")
    fig.tight_layout()
    fig.savefig(output, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="sb3-macb plot", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="what", required=True)
    curves = sub.add_parser("curves", help="success rate and return against episodes")
    curves.add_argument("groups", nargs="+")
    curves.add_argument("--smooth", type=int, default=50, help="moving average window, in evaluations")
    curves.add_argument("--confidence", type=float, default=0.75)
    curves.add_argument("-o", "--output", default="curves.png")
    curves.add_argument(
        "--reference", default=None, help="scripted listeners' levels (experiments/macb_paper/scripts/task_levels.py)"
    )
    curves.add_argument("--complete-only", action="store_true", help="leave out runs still in progress (no "
                        "'complete' in their run.json)")  # fmt: skip
    collisions = sub.add_parser("collisions", help="accumulated training collisions")
    collisions.add_argument("groups", nargs="+")
    collisions.add_argument("--confidence", type=float, default=0.75)
    collisions.add_argument("-o", "--output", default="collisions.png")
    table = sub.add_parser("table", help="the beta x k grid of a sweep (markdown and heatmap)")
    table.add_argument("results")
    table.add_argument("--row", default="exploration.k")
    table.add_argument("--column", default="exploration.beta")
    table.add_argument("-o", "--output", default="table", help="output prefix (.md and .png)")
    table.add_argument("--title", default=None, help="added to the heatmap's title, e.g. the budget")
    simhash = sub.add_parser("simhash", help="the SimHash grouping figure")
    simhash.add_argument("--k", type=int, nargs="+", default=[8, 16, 32])
    simhash.add_argument("--points", type=int, default=2000)
    simhash.add_argument("-o", "--output", default="simhash.png")
    args = parser.parse_args(argv)
    for path in [*getattr(args, "groups", []), *([args.results] if args.what == "table" else [])]:
        if not os.path.exists(path):
            raise FileNotFoundError(f"sb3-macb plot {args.what}: {path} does not exist")
    if args.what == "curves":
        plot_curves(args.groups, args.output, args.smooth, args.confidence, args.reference, args.complete_only)
    elif args.what == "collisions":
        plot_collisions(args.groups, args.output, args.confidence)
    elif args.what == "table":
        print(plot_table(args.results, args.output, args.row, args.column, args.title))
    else:
        plot_simhash(args.output, tuple(args.k), args.points)
    print(f"wrote {args.output}")

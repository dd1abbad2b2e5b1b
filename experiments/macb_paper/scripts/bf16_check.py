"""
The pre-registered check of bfloat16 products on learning (issue 30; the study's README.md, "bfloat16 products and
learning: pre-registered check"), applied mechanically:

    python scripts/bf16_check.py results/CommunicativeNavigation-sparse-bf16-2e5/maddpg+bf16 \\
        results/CommunicativeNavigation-sparse-paper/maddpg \\
        --also results/CommunicativeNavigation-sparse-paper-1e6/maddpg --plot img/bf16_check.png

Each folder holds ``seed_<s>/evaluations.npz``; every run is cut to its first ``--episodes`` training episodes
(10,000: 2e5 steps) and must have reached them. The rules, as registered (the headline's window of 200
evaluations and 90% any-step success):

- per run, L: the level at the cut, the mean any-step success of the last 200 evaluations before it; E: the
  episodes until the trailing 200-evaluation mean first reaches 0.9, counted at the cut if it never does;
- *uninformative* if the float32 seeds' mean L is below 0.5 (the task is not learnt by the cut, so the check could
  not see a harm); else bf16 *matches* float32 if its mean L is at least float32's minus 0.05 and its median E at
  most 1.25 times float32's; else *worse*.

``--also`` folders (float32 runs on another machine, say) are reported beside the two, not decided on: they show
how far two float32 readings of the same seeds lie apart. Their runs that have not reached the cut are left out.
"""

import argparse
import glob
import os
from dataclasses import dataclass

import numpy as np

from sb3_macb.common import evaluations

EPISODES, THRESHOLD, WINDOW = 10_000, 0.9, 200
LEVEL_MARGIN, EPISODES_RATIO, LEARNT = 0.05, 1.25, 0.5


def load_runs(folder: str, cut: int = EPISODES) -> dict[int, dict[str, np.ndarray]]:
    """The arrays of every ``seed_<s>`` run in ``folder``, cut at ``cut`` training episodes, by seed."""
    return {
        int(os.path.basename(os.path.dirname(path))[len("seed_") :]): evaluations.load(path, max_episodes=cut)
        for path in sorted(glob.glob(os.path.join(folder, "seed_*", evaluations.FILE_NAME)))
    }


def plot(groups: dict[str, str], output: str, cut: int = EPISODES) -> None:
    """
    One panel per seed: the trailing 200-evaluation mean of any-step success of every group, to episode ``cut``.

    :param groups: Label -> variant folder.
    :param output: The image file.
    :param cut: Training episodes shown.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = {label: load_runs(folder, cut) for label, folder in groups.items()}
    seeds = sorted(set().union(*runs.values()))
    fig, axes = plt.subplots(1, len(seeds), figsize=(5 * len(seeds), 4), sharey=True, squeeze=False)
    for ax, seed in zip(axes[0], seeds):
        for style, (label, by_seed) in zip(("-", "--", ":"), runs.items()):
            if seed in by_seed:
                data = by_seed[seed]
                moving = evaluations.moving_average(evaluations.rate(data), WINDOW, head="nan")
                ax.plot(evaluations.episodes(data), moving, style, label=label)
        ax.axhline(THRESHOLD, color="gray", linewidth=0.8)
        ax.set(title=f"seed {seed}", xlabel="training episodes", ylim=(-0.02, 1.02))
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel(f"any-step success, trailing mean of {WINDOW} evaluations")
    axes[0][0].legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(output, dpi=110)
    plt.close(fig)


@dataclass
class Reading:
    """One run cut at the registered episode: its seed, level L and episodes E to 90% (reached or censored)."""

    seed: int
    level: float
    episodes: float
    reached: bool


def read_group(folder: str, cut: int = EPISODES, skip_short: bool = False) -> list[Reading]:
    """
    The readings of every ``seed_<s>`` run in ``folder``, cut at ``cut`` training episodes.

    :param folder: A variant's folder (``.../<variant>``).
    :param cut: Training episodes per run to read.
    :param skip_short: Leave out runs that have not reached ``cut`` (for groups only reported); otherwise such a run
        stops the check with one line.
    :return: The readings, by seed.
    """
    readings = []
    for seed, data in sorted(load_runs(folder, cut).items()):
        run_episodes = evaluations.episodes(data)
        if len(run_episodes) == 0 or run_episodes[-1] < cut:
            if skip_short:
                continue
            reached = 0 if len(run_episodes) == 0 else int(run_episodes[-1])
            raise SystemExit(f"{os.path.join(folder, f'seed_{seed}')}: {reached} training episodes, the check needs {cut}")
        level = evaluations.final_level(data, evaluations.SUCCESSES, WINDOW)
        value, hit = evaluations.episodes_to(data[evaluations.SUCCESSES], run_episodes, THRESHOLD, WINDOW)
        readings.append(Reading(seed, level, value, hit))
    if not readings:
        raise SystemExit(f"{folder}: no seed_<s>/{evaluations.FILE_NAME} with {cut} training episodes")
    return readings


def decide(low: list[Reading], full: list[Reading]) -> tuple[str, str]:
    """The decision for bf16 (``low``) against float32 (``full``), and the figures behind it."""
    level_low, level_full = np.mean([r.level for r in low]), np.mean([r.level for r in full])
    median_low, median_full = np.median([r.episodes for r in low]), np.median([r.episodes for r in full])
    figures = (
        f"mean L {level_low:.3f} against {level_full:.3f} (bf16 needs at least {level_full - LEVEL_MARGIN:.3f}); "
        f"median E {median_low:.0f} against {median_full:.0f} episodes (bf16 needs at most "
        f"{EPISODES_RATIO * median_full:.0f})"
    )
    if level_full < LEARNT:
        return "uninformative", figures
    if level_low >= level_full - LEVEL_MARGIN and median_low <= EPISODES_RATIO * median_full:
        return "matches", figures
    return "worse", figures


def row(name: str, readings: list[Reading]) -> str:
    """One markdown row: seeds, L and E per seed, and their mean and median."""
    levels = ", ".join(f"{r.level:.3f}" for r in readings)
    times = ", ".join(f"{r.episodes:.0f}{'' if r.reached else '+'}" for r in readings)
    return (
        f"| {name} | {', '.join(str(r.seed) for r in readings)} | {np.mean([r.level for r in readings]):.3f} "
        f"({levels}) | {np.median([r.episodes for r in readings]):.0f} ({times}) |"
    )


def report(low_folder: str, full_folder: str, also: list[str], cut: int = EPISODES) -> str:
    """The markdown report: the table of every group and the registered decision."""
    low, full = read_group(low_folder, cut), read_group(full_folder, cut)
    lines = [
        f"| runs | seeds | L: any-step success over the last {WINDOW} evaluations before episode {cut}, mean (seeds) "
        f"| E: episodes to 90%, median (seeds; + never reached) |",
        "|---|---|---|---|",
        row(f"bf16: {low_folder}", low),
        row(f"float32: {full_folder}", full),
    ]
    for folder in also:
        readings = read_group(folder, cut, skip_short=True)  # runs short of the cut are left out of a reported group
        lines.append(row(f"float32, reported only (runs past episode {cut}): {folder}", readings))
    decision, figures = decide(low, full)
    lines += ["", f"- bf16 against float32 over the first {cut} episodes: **{decision}**. {figures}."]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("bf16_folder", help="the bf16 runs' variant folder")
    parser.add_argument("float32_folder", help="the float32 runs' variant folder")
    parser.add_argument("--also", nargs="*", default=[], help="more float32 folders, reported beside, not decided on")
    parser.add_argument("--episodes", type=int, default=EPISODES, help="training episodes per run to read (registered: 10000)")
    parser.add_argument("--plot", help="also draw the curves, a panel per seed, into this image file")
    args = parser.parse_args()
    print(report(args.bf16_folder, args.float32_folder, args.also, args.episodes))
    if args.plot:
        groups = {"bf16": args.bf16_folder, "float32": args.float32_folder}
        groups.update({f"float32 ({os.path.basename(os.path.dirname(os.path.normpath(f)))})": f for f in args.also})
        plot(groups, args.plot, args.episodes)


if __name__ == "__main__":
    main()

"""
Descriptive tables of how runs evolve, complete or not: the figures the study's README.md quotes beside the
pre-registered analysis (``scripts/headline_analysis.py``), from the files alone.

    python scripts/trajectories.py results/CommunicativeNavigation-sparse-paper
    python scripts/trajectories.py results/CommunicativeNavigation-sparse-paper-first-attempt --seeds 1 2

Per run (``<variant>/seed_<s>/evaluations.npz``):

- the training episodes it has reached (and whether ``run.json`` marks it complete);
- the first episode at which the trailing ``--window``-evaluation any-step success reaches ``--threshold``;
- the trailing ``--window``-evaluation any-step / final-step success at every ``--every``-th training episode;
- the share of evaluations after episode ``--after`` whose trailing any-step success is below ``--floor``
  ("collapsed"; a post-hoc measure, first used on the 64-64 runs, not part of the registration).

Per seed, for every pair of ``--pairs`` (default: MACB k 512 against the constant bonus): the last step up to which
the two runs' evaluations are identical (returns of every evaluation episode, per agent and in total). Two runs that
agree there have computed the same thing so far: their counts never changed a bonus that mattered.

With ``--twins OTHER``, per run filed in both the task folder and ``OTHER`` (the same variant and seed, e.g. the
short-buffer and registered-buffer headline runs): the last step up to which their evaluations are identical, and
each one's final any-step / final-step success (the last ``--final`` evaluations). Twins made on one machine compute
the same thing until their settings first matter (for the buffer: the first evaluation after the shorter one wraps).

    python scripts/trajectories.py results/CommunicativeNavigation-sparse-4e4 \\
        --twins results/CommunicativeNavigation-sparse-4e4-1e6

Nothing here decides anything: the registered decisions are ``scripts/headline_analysis.py``'s.
"""

import argparse
import glob
import os

import numpy as np

from sb3_macb.common import evaluations


def identical_until(first: dict[str, np.ndarray], second: dict[str, np.ndarray]) -> tuple[int | None, bool]:
    """
    The last step at which two runs' evaluations are still identical (returns per episode and per agent), and
    whether they are identical over everything both have recorded. ``None`` if they differ at the first evaluation.
    """
    n = min(len(first[evaluations.TIMESTEPS]), len(second[evaluations.TIMESTEPS]))
    if not np.array_equal(first[evaluations.TIMESTEPS][:n], second[evaluations.TIMESTEPS][:n]):
        raise SystemExit("the two runs evaluate at different steps: compare runs of one experiment")
    same = np.ones(n, dtype=bool)
    for name in (evaluations.RESULTS, evaluations.AGENT_RETURNS):
        if name in first and name in second:
            same &= np.all((first[name][:n] == second[name][:n]).reshape(n, -1), axis=1)
    if same.all():
        return (int(first[evaluations.TIMESTEPS][n - 1]) if n else None), True
    differs = int(np.argmin(same))
    return (int(first[evaluations.TIMESTEPS][differs - 1]) if differs else None), False


def run_row(run: dict[str, np.ndarray], args: argparse.Namespace, milestones: list[int]) -> list[str]:
    """The table cells of one run."""
    episodes = evaluations.episodes(run)
    any_step = evaluations.moving_average(evaluations.rate(run, evaluations.SUCCESSES), args.window, head="nan")
    final = (
        evaluations.moving_average(evaluations.rate(run, evaluations.FINAL_SUCCESSES), args.window, head="nan")
        if evaluations.FINAL_SUCCESSES in run
        else np.full(len(episodes), np.nan)
    )
    value, reached = evaluations.episodes_to(run[evaluations.SUCCESSES], episodes, args.threshold, args.window)
    cells = [f"{value:,.0f}" if reached else f"not by {episodes[-1]:,.0f}"]
    for milestone in milestones:
        at = np.flatnonzero(episodes == milestone)
        if len(at) and not np.isnan(any_step[at[0]]):
            cells.append(f"{any_step[at[0]]:.2f}/{final[at[0]]:.2f}")
        else:
            cells.append("")
    later = (episodes > args.after) & ~np.isnan(any_step)
    cells.append(f"{np.mean(any_step[later] < args.floor):.0%}" if later.any() else "")
    return cells


def report(task_folder: str, args: argparse.Namespace) -> str:
    """The markdown tables for one task folder."""
    runs, complete = load_folder(task_folder, args)
    if not runs:
        raise SystemExit(f"No {evaluations.FILE_NAME} below {task_folder} for these seeds and variants")
    last = max(float(evaluations.episodes(run)[-1]) for run in runs.values())
    milestones = list(range(args.every, int(last) + 1, args.every))
    lines = [f"### {os.path.basename(os.path.normpath(task_folder))}", ""]
    lines.append(
        f"Trailing {args.window}-evaluation any-step/final-step success at every {args.every:,}th training episode; "
        f"first episode at {args.threshold:.0%} any-step; share of evaluations after episode {args.after:,} with "
        f"trailing any-step below {args.floor} (collapsed)."
    )
    lines.append("")
    lines.append(
        "| seed | variant | episodes (complete?) | "
        + f"{args.threshold:.0%} any-step at episode | "
        + " | ".join(f"{m:,}" for m in milestones)
        + f" | collapsed after {args.after:,} |"
    )
    lines.append("|" + "---|" * (len(milestones) + 5))
    for (seed, variant), run in sorted(runs.items()):
        reached = f"{evaluations.episodes(run)[-1]:,.0f} ({'yes' if complete[seed, variant] else 'no'})"
        lines.append(f"| {seed} | {variant} | {reached} | " + " | ".join(run_row(run, args, milestones)) + " |")
    pair_lines = []
    for seed in sorted({seed for seed, _ in runs}):
        for pair in args.pairs:
            first, second = pair.split(":")
            if (seed, first) in runs and (seed, second) in runs:
                step, whole = identical_until(runs[seed, first], runs[seed, second])
                text = "differ from the first evaluation" if step is None else f"identical up to step {step:,}"
                pair_lines.append(
                    f"- seed {seed}: {first} and {second} {text}{' (everything recorded so far)' if whole else ''}."
                )
    if pair_lines:
        lines += [""] + pair_lines
    return "\n".join(lines)


def load_folder(task_folder: str, args: argparse.Namespace) -> tuple[dict[tuple[int, str], dict], dict[tuple[int, str], bool]]:
    """Every run below ``task_folder`` (within ``--seeds`` and ``--variants``), and whether each is complete."""
    runs: dict[tuple[int, str], dict[str, np.ndarray]] = {}
    complete: dict[tuple[int, str], bool] = {}
    for path in sorted(glob.glob(os.path.join(task_folder, "*", "seed_*", evaluations.FILE_NAME))):
        folder = os.path.dirname(path)
        variant, seed = os.path.basename(os.path.dirname(folder)), int(os.path.basename(folder)[len("seed_") :])
        if (args.seeds and seed not in args.seeds) or (args.variants and variant not in args.variants):
            continue
        runs[seed, variant] = evaluations.load(path)
        complete[seed, variant] = evaluations.is_complete(folder)
    return runs, complete


def twins_report(task_folder: str, other: str, args: argparse.Namespace) -> str:
    """The runs filed in both folders: how long they stay identical, and where each ends."""
    first, first_complete = load_folder(task_folder, args)
    second, second_complete = load_folder(other, args)
    shared = sorted(set(first) & set(second), key=lambda key: (key[1], key[0]))
    if not shared:
        raise SystemExit(f"No run (variant and seed) is filed both below {task_folder} and below {other}")
    names = [os.path.basename(os.path.normpath(folder)) for folder in (task_folder, other)]

    def final(run: dict[str, np.ndarray], done: bool) -> str:
        levels = [evaluations.final_level(run, metric, args.final) for metric in evaluations.SUCCESS_METRICS if metric in run]
        return " / ".join(f"{level:.3f}" for level in levels) + ("" if done else " (incomplete)")

    lines = [
        f"### Twins: {names[0]} and {names[1]}",
        "",
        f"Final any-step / final-step success: mean of the last {args.final} evaluations.",
        "",
        f"| run | identical through step | {names[0]} | {names[1]} |",
        "|---|---|---|---|",
    ]
    for seed, variant in shared:
        a, b = first[seed, variant], second[seed, variant]
        n = min(len(a[evaluations.TIMESTEPS]), len(b[evaluations.TIMESTEPS]))
        if np.array_equal(a[evaluations.TIMESTEPS][:n], b[evaluations.TIMESTEPS][:n]):
            step, whole = identical_until(a, b)
            same = "differ from the first evaluation" if step is None else f"{step:,}" + (" (all recorded)" if whole else "")
        else:
            same = "evaluated at different steps"
        lines.append(
            f"| {variant} seed {seed} | {same} | {final(a, first_complete[seed, variant])} | "
            f"{final(b, second_complete[seed, variant])} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("task_folders", nargs="+")
    parser.add_argument("--seeds", type=int, nargs="*", default=None, help="only these seeds (default: all)")
    parser.add_argument("--variants", nargs="*", default=None, help="only these variants (default: all)")
    parser.add_argument("--window", type=int, default=200, help="evaluations in the trailing mean")
    parser.add_argument("--threshold", type=float, default=0.9, help="any-step success threshold")
    parser.add_argument("--every", type=int, default=4000, help="training episodes between milestones")
    parser.add_argument("--after", type=int, default=4000, help="episode after which collapses are counted")
    parser.add_argument("--floor", type=float, default=0.15, help="trailing any-step success below which a run is collapsed")
    parser.add_argument("--pairs", nargs="*", default=["macb_joint:macb_constant"], help="variant pairs a:b to compare")
    parser.add_argument(
        "--twins",
        metavar="OTHER",
        default=None,
        help="compare each run with the run of the same variant and seed below OTHER instead",
    )
    parser.add_argument("--final", type=int, default=200, help="evaluations in the final level (with --twins)")
    args = parser.parse_args()
    for value, name in ((args.window, "--window"), (args.every, "--every")):
        if value < 1:
            parser.error(f"{name} must be at least 1, got {value}")
    for pair in args.pairs:
        if pair.count(":") != 1:
            parser.error(f"--pairs takes variant pairs as a:b, got {pair!r}")
    if args.final < 1:
        parser.error(f"--final must be at least 1, got {args.final}")
    if args.twins is not None:
        if len(args.task_folders) != 1:
            parser.error("--twins compares one task folder with OTHER: give one task folder")
        print(twins_report(args.task_folders[0], args.twins, args))
        return
    for folder in args.task_folders:
        print(report(folder, args))
        print()


if __name__ == "__main__":
    main()

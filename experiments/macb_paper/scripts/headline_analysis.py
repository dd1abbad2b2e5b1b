"""
The pre-registered analysis of the headline experiment (the study's README.md, "The headline experiment:
pre-registered analysis"), applied mechanically so that its decisions do not depend on who reads the data:

    python scripts/headline_analysis.py results/CommunicativeNavigation-sparse-paper --expected-seeds 3
    python scripts/headline_analysis.py results/CommunicativeNavigation-sparse-4e4 --expected-seeds 5

Only complete runs (``run.json`` with ``complete: true``) are used. With fewer complete seeds per variant than
``--expected-seeds`` every decision is printed as INTERIM (the registration decides on all seeds).

The rules, as registered (window 200 evaluations for every metric; "final level" = mean of the last 200
evaluations; thresholds on the trailing 200-evaluation mean):

- C1, the paper's claim: *confirmed* if every ``macb_joint`` seed reaches 90% any-step success and its Kaplan-Meier
  median episodes are at most half of MADDPG's, MADDPG's seeds that never reach it counting at their last episode
  (4e4); *refuted* if fewer than half of the ``macb_joint`` seeds reach 90%, or its median is more than half of
  MADDPG's; otherwise *inconclusive*.
- C2, counts or offset, for ``macb_joint`` (k 512) and ``macb_k32`` against ``macb_constant``: the differences of the
  seed means of the final levels, any-step and final-step success (MACB minus the constant bonus). The effect is
  *attributed to the reward offset* if either difference is below +0.05 (a negative difference is below it too) or
  the two have opposite signs, as registered. Counting is *credited* if MACB is ahead by at least 0.05 on both
  metrics and its worst seed is above the constant bonus's mean on both; ahead by 0.05 on both but not in every
  seed, the registration withholds credit (*not credited: not every seed*). The figures printed beside a decision
  include how far MACB's worst seed is from the constant bonus's mean, so a decision taken by a small margin shows.
- C3, communication: a run *communicates* if its final level of final-step success is at least 0.15 above the
  no-communication level (the higher final-step success of the two scripted listeners that ignore the message,
  from ``--reference``); reported per variant as "k of n seeds communicate".
"""

import argparse
import glob
import json
import os
from dataclasses import dataclass

import numpy as np

from sb3_macb.common import evaluations

THRESHOLD, WINDOW, MARGIN, COMMUNICATION_MARGIN = 0.9, 200, 0.05, 0.15
NO_COMMUNICATION = ("random_landmark", "landmark_tour")
REFERENCE_LEVELS = os.path.join(
    os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "results", "CommunicativeNavigation-sparse-reference.json"
)


@dataclass
class Run:
    """One complete run: its seed, episodes to 90% any-step success (or its last episode) and final levels."""

    seed: int
    episodes: float
    reached: bool
    final_any: float
    final_last: float


def complete_runs(task_folder: str, required: set[str]) -> tuple[list[tuple[str, int, dict]], dict[str, list[int]]]:
    """
    (variant, seed, evaluations) of every complete run below ``task_folder``, each checked to hold the ``required``
    arrays, and the seeds of the incomplete runs by variant.
    """
    done: list[tuple[str, int, dict]] = []
    incomplete: dict[str, list[int]] = {}
    for path in sorted(glob.glob(os.path.join(task_folder, "*", "seed_*", evaluations.FILE_NAME))):
        folder = os.path.dirname(path)
        variant, seed = os.path.basename(os.path.dirname(folder)), int(os.path.basename(folder)[len("seed_") :])
        if not evaluations.is_complete(folder):
            incomplete.setdefault(variant, []).append(seed)
            continue
        data = evaluations.load(path)
        missing = required - set(data)
        if missing:
            raise SystemExit(f"{path} has no {', '.join(sorted(missing))}: it predates the registered metrics")
        done.append((variant, seed, data))
    return done, incomplete


def load_runs(task_folder: str) -> tuple[dict[str, list[Run]], dict[str, list[int]]]:
    """The complete runs of every variant below ``task_folder``, and the seeds of the incomplete ones."""
    runs: dict[str, list[Run]] = {}
    done, incomplete = complete_runs(task_folder, {evaluations.SUCCESSES, evaluations.FINAL_SUCCESSES})
    for variant, seed, data in done:
        value, reached = evaluations.episodes_to(
            data[evaluations.SUCCESSES], evaluations.episodes(data), THRESHOLD, WINDOW
        )
        runs.setdefault(variant, []).append(
            Run(seed, value, reached, evaluations.final_level(data, evaluations.SUCCESSES, WINDOW),
                evaluations.final_level(data, evaluations.FINAL_SUCCESSES, WINDOW))  # fmt: skip
        )
    return runs, incomplete


def decide_c1(macb: list[Run], maddpg: list[Run]) -> tuple[str, str]:
    """C1: the decision and the figures behind it."""
    reached = sum(r.reached for r in macb)
    median = evaluations.km_median([r.episodes for r in macb], [r.reached for r in macb])
    reference = float(np.median([r.episodes for r in maddpg]))  # censored MADDPG seeds count at their last episode
    figures = (
        f"MACB(s, x): {reached} of {len(macb)} seeds reach 90% any-step success, Kaplan-Meier median "
        f"{'not reached' if median is None else f'{median:.0f} episodes'}; MADDPG median {reference:.0f} episodes "
        f"({sum(r.reached for r in maddpg)} of {len(maddpg)} reach it; runs that do not are counted at their last "
        "episode, as registered)"
    )
    if reached < len(macb) / 2 or median is None or median > reference / 2:
        return "refuted", figures
    if reached == len(macb):
        return "confirmed", figures
    return "inconclusive", figures


def decide_c2(macb: list[Run], constant: list[Run]) -> tuple[str, str]:
    """C2 for one MACB variant against the constant bonus: the decision and the figures behind it."""
    diffs, worst, worst_above = [], [], []
    for attribute in ("final_any", "final_last"):
        ours = np.array([getattr(r, attribute) for r in macb])
        theirs = float(np.mean([getattr(r, attribute) for r in constant]))
        diffs.append(float(ours.mean() - theirs))
        worst.append(float(ours.min() - theirs))
        worst_above.append(bool(ours.min() > theirs))
    figures = (
        f"difference of seed means {diffs[0]:+.4f} any-step, {diffs[1]:+.4f} final-step (credit needs +{MARGIN} on "
        f"both); MACB's worst seed minus the constant bonus's mean {worst[0]:+.4f} any-step, {worst[1]:+.4f} final-step"
        " (credit needs both above 0)"
    )
    if min(diffs) < MARGIN or np.sign(diffs[0]) != np.sign(diffs[1]):
        return "attributed to the reward offset", figures
    if all(worst_above):
        return "counting credited", figures
    return "not credited: not every seed", figures


def no_communication_level(reference_path: str) -> float:
    """The higher final-step success of the two scripted listeners that ignore the message."""
    with open(reference_path) as file:
        levels = json.load(file)
    return max(float(levels[name]["final_step"]) for name in NO_COMMUNICATION)


def analyse(task_folder: str, expected_seeds: int, reference_path: str) -> str:
    """The markdown report of C1-C3 for one task folder."""
    runs, incomplete = load_runs(task_folder)
    interim = any(len(runs.get(v, [])) < expected_seeds for v in set(runs) | set(incomplete)) or not runs
    tag = "INTERIM (fewer complete seeds than registered): " if interim else ""
    bar = no_communication_level(reference_path) + COMMUNICATION_MARGIN
    lines = [f"### {os.path.basename(os.path.normpath(task_folder))}", ""]
    lines.append("| variant | complete seeds | final any-step success, mean +/- sample SD (seeds) "
                 "| final final-step success | "
                 "reached 90% any-step | communicates | incomplete seeds |")  # fmt: skip
    lines.append("|---|---|---|---|---|---|---|")
    for variant in sorted(set(runs) | set(incomplete)):
        done = sorted(runs.get(variant, []), key=lambda r: r.seed)
        incomplete_seeds = ", ".join(map(str, sorted(incomplete.get(variant, [])))) or "-"
        if not done:
            lines.append(f"| {variant} | - | - | - | - | - | {incomplete_seeds} |")
            continue

        def level(attribute: str, done: list = done) -> str:
            values = [getattr(r, attribute) for r in done]
            spread = f" +/- {np.std(values, ddof=1):.3f}" if len(values) > 1 else ""
            return f"{np.mean(values):.3f}{spread} ({', '.join(f'{v:.3f}' for v in values)})"

        lines.append(
            f"| {variant} | {', '.join(str(r.seed) for r in done)} | {level('final_any')} | {level('final_last')} | "
            f"{sum(r.reached for r in done)} of {len(done)} | {sum(r.final_last >= bar for r in done)} of {len(done)} | "
            f"{incomplete_seeds} |"
        )
    lines.append("")
    if "macb_joint" in runs and "maddpg" in runs:
        decision, figures = decide_c1(runs["macb_joint"], runs["maddpg"])
        lines.append(f"- C1, the paper's claim: {tag}**{decision}**. {figures}.")
    for variant in ("macb_joint", "macb_k32"):
        if variant in runs and "macb_constant" in runs:
            decision, figures = decide_c2(runs[variant], runs["macb_constant"])
            lines.append(f"- C2, {variant} against macb_constant: {tag}**{decision}**; {figures}.")
    if not runs:
        lines.append("- No complete runs yet: nothing to decide.")
        return "\n".join(lines)
    lines.append(
        f"- C3, communication (final-step success at least {bar:.3f}, the no-communication level "
        f"{bar - COMMUNICATION_MARGIN:.3f} + {COMMUNICATION_MARGIN}): {tag}"
        + "; ".join(f"{v} {sum(r.final_last >= bar for r in rs)} of {len(rs)}" for v, rs in sorted(runs.items()))
        + "."
    )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("task_folders", nargs="+")
    parser.add_argument("--expected-seeds", type=int, required=True, help="the seeds per variant registered")
    parser.add_argument("--reference", default=REFERENCE_LEVELS,
                        help="the scripted listeners' levels (scripts/reference_levels.py)")  # fmt: skip
    args = parser.parse_args()
    for folder in args.task_folders:
        print(analyse(folder, args.expected_seeds, args.reference))
        print()


if __name__ == "__main__":
    main()

"""
The pre-registered analysis of 2-Agent Navigation at the paper's size (the study's README.md, "2-Agent Navigation at the
paper's size: pre-registered analysis"), applied mechanically:

    python scripts/nav_analysis.py results/TwoAgentNavigation-sparse-paper --expected-seeds 3

Only complete runs (``run.json`` with ``complete: true``) are used; with fewer complete seeds per variant than
``--expected-seeds`` every decision is printed as INTERIM.

The rules, as registered (window 200 evaluations; "final level" = mean of the last 200 evaluations; a run reaches a
threshold when its trailing 200-evaluation mean does; a run that never does is censored at its last episode):

- N1, the paper's claim (every MACB variant reaches MADDPG's final success level in at most half of MADDPG's
  episodes). The target T = max(0.9 x L, 0.2), L = MADDPG's seed mean of final any-step success. MADDPG's episodes
  E = the median over its seeds of the episodes to T, a seed that never reaches T counting at its last episode.
  A MACB variant (``macb_joint``, ``macb_local``, ``macb_state``) *meets* the claim if every seed reaches T and its
  Kaplan-Meier median is at most E / 2; it *fails* if fewer than half its seeds reach T or its median is more than
  E / 2; otherwise *inconclusive*. The claim is *confirmed* if all three meet it, *refuted* if any fails, otherwise
  *inconclusive*.
- N2, counts or offset: each MACB variant against ``macb_constant`` by the headline's rule C2 (final any-step and
  final-step success; credited only 0.05 ahead on both with the worst seed above the constant's mean; a difference
  below +0.05 on either metric, or of opposite signs, is *attributed to the reward offset*).
- N3, collisions (Fig. 3b; accumulated training collisions at the end of each run): variant A collides *less* than B
  if A's seed mean is at least 20% below B's and every seed of A is below every seed of B; *more* in the mirror case;
  otherwise *no difference detected*. Tested: ``macb_joint`` against ``maddpg`` and ``ddpg_macb`` against ``ddpg``
  (the paper: MACB vastly fewer), ``maddpg`` against ``ddpg`` (the paper: MADDPG more), and ``macb_constant`` against
  ``maddpg`` (whether the offset alone does what MACB does).
"""

import argparse
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from headline_analysis import WINDOW, Run, complete_runs, decide_c2  # noqa: E402  (a sibling script)
from sb3_macb.common import evaluations  # noqa: E402

MACB_VARIANTS = ("macb_joint", "macb_local", "macb_state")
FRACTION, FLOOR, COLLISION_FRACTION = 0.9, 0.2, 0.2
COLLISION_TESTS = (
    ("macb_joint", "maddpg", "the paper: fewer"),
    ("ddpg_macb", "ddpg", "the paper: fewer"),
    ("maddpg", "ddpg", "the paper: more"),
    ("macb_constant", "maddpg", "the offset alone"),
)


@dataclass
class NavRun:
    """One complete run: its seed, evaluations, final levels and accumulated training collisions."""

    seed: int
    data: dict[str, np.ndarray]
    final_any: float
    final_last: float
    collisions: float

    def episodes_to(self, threshold: float) -> tuple[float, bool]:
        """Episodes to ``threshold`` any-step success (the trailing window's mean), or the last episode."""
        return evaluations.episodes_to(self.data[evaluations.SUCCESSES], evaluations.episodes(self.data), threshold, WINDOW)


def load_runs(task_folder: str) -> tuple[dict[str, list[NavRun]], dict[str, list[int]]]:
    """The complete runs of every variant below ``task_folder`` (by seed), and the seeds of the incomplete ones."""
    runs: dict[str, list[NavRun]] = {}
    required = {evaluations.SUCCESSES, evaluations.FINAL_SUCCESSES, evaluations.TRAINING_COLLISIONS}
    done, incomplete = complete_runs(task_folder, required)
    for variant, seed, data in done:
        runs.setdefault(variant, []).append(
            NavRun(seed, data, evaluations.final_level(data, evaluations.SUCCESSES, WINDOW),
                   evaluations.final_level(data, evaluations.FINAL_SUCCESSES, WINDOW),
                   float(data[evaluations.TRAINING_COLLISIONS][-1]))  # fmt: skip
        )
    for group in runs.values():
        group.sort(key=lambda r: r.seed)
    return runs, incomplete


def target(maddpg: list[NavRun]) -> float:
    """T = max(0.9 x MADDPG's seed mean of final any-step success, 0.2)."""
    return max(FRACTION * float(np.mean([r.final_any for r in maddpg])), FLOOR)


def decide_n1_variant(macb: list[NavRun], maddpg: list[NavRun], threshold: float) -> tuple[str, str]:
    """N1 for one MACB variant: meets / fails / inconclusive, and the figures behind it."""
    crossings = [r.episodes_to(threshold) for r in macb]
    reached = sum(ok for _, ok in crossings)
    median = evaluations.km_median([e for e, _ in crossings], [ok for _, ok in crossings])
    reference = float(np.median([r.episodes_to(threshold)[0] for r in maddpg]))  # censored: at the last episode
    figures = (
        f"{reached} of {len(macb)} seeds reach {threshold:.3f}, Kaplan-Meier median "
        f"{'not reached' if median is None else f'{median:.0f} episodes'} against half of MADDPG's {reference / 2:.0f}"
    )
    if reached < len(macb) / 2 or median is None or median > reference / 2:
        return "fails", figures
    if reached == len(macb):
        return "meets", figures
    return "inconclusive", figures


def decide_n1(decisions: list[str]) -> str:
    """The paper's claim over the three MACB variants."""
    if "fails" in decisions:
        return "refuted"
    return "confirmed" if all(d == "meets" for d in decisions) else "inconclusive"


def decide_n3(a: list[NavRun], b: list[NavRun]) -> str:
    """Whether A collides less or more than B (seed means 20% apart and the seeds not overlapping)."""
    ours, theirs = np.array([r.collisions for r in a]), np.array([r.collisions for r in b])
    if ours.mean() <= (1 - COLLISION_FRACTION) * theirs.mean() and ours.max() < theirs.min():
        return "less"
    if theirs.mean() <= (1 - COLLISION_FRACTION) * ours.mean() and ours.min() > theirs.max():
        return "more"
    return "no difference detected"


def level(values: list[float], digits: int = 3) -> str:
    """Seed mean +/- sample SD, then the seeds' values."""
    spread = f" +/- {np.std(values, ddof=1):.{digits}f}" if len(values) > 1 else ""
    return f"{np.mean(values):.{digits}f}{spread} ({', '.join(f'{v:.{digits}f}' for v in values)})"


def variant_table(task_folder: str, runs: dict[str, list[NavRun]], incomplete: dict[str, list[int]], column: str,
                  cell: Callable[[list[NavRun]], str]) -> list[str]:  # fmt: skip
    """The per-variant table (final levels of both success metrics by seed) with one more ``column`` from ``cell``."""
    lines = [f"### {os.path.basename(os.path.normpath(task_folder))}", ""]
    lines.append("| variant | complete seeds | final any-step success, mean +/- sample SD (seeds) | final final-step "
                 f"success | {column} | incomplete seeds |")  # fmt: skip
    lines.append("|---|---|---|---|---|---|")
    for variant in sorted(set(runs) | set(incomplete)):
        done = runs.get(variant, [])
        waiting = ", ".join(map(str, sorted(incomplete.get(variant, [])))) or "-"
        if not done:
            lines.append(f"| {variant} | - | - | - | - | {waiting} |")
            continue
        lines.append(f"| {variant} | {', '.join(str(r.seed) for r in done)} | {level([r.final_any for r in done])} | "
                     f"{level([r.final_last for r in done])} | {cell(done)} | {waiting} |")  # fmt: skip
    return lines + [""]


def analyse(task_folder: str, expected_seeds: int) -> str:
    """The markdown report of N1-N3 for one task folder."""
    runs, incomplete = load_runs(task_folder)
    interim = any(len(runs.get(v, [])) < expected_seeds for v in set(runs) | set(incomplete)) or not runs
    tag = "INTERIM (fewer complete seeds than registered): " if interim else ""
    lines = variant_table(task_folder, runs, incomplete, "training collisions at the end",
                          lambda done: level([r.collisions for r in done], 0))  # fmt: skip
    if not runs:
        return "\n".join(lines + ["- No complete runs yet: nothing to decide."])
    if "maddpg" in runs and all(v in runs for v in MACB_VARIANTS):
        threshold = target(runs["maddpg"])
        decisions = []
        for variant in MACB_VARIANTS:
            decision, figures = decide_n1_variant(runs[variant], runs["maddpg"], threshold)
            decisions.append(decision)
            lines.append(f"- N1, {variant}: {tag}**{decision}**; {figures}.")
        lines.append(f"- N1, the paper's claim (target {threshold:.3f} any-step success): {tag}**{decide_n1(decisions)}**.")
    for variant in MACB_VARIANTS:
        if variant in runs and "macb_constant" in runs:
            as_runs = [[Run(r.seed, 0.0, False, r.final_any, r.final_last) for r in runs[v]]
                       for v in (variant, "macb_constant")]  # fmt: skip
            decision, figures = decide_c2(*as_runs)
            lines.append(f"- N2, {variant} against macb_constant: {tag}**{decision}**; {figures}.")
    for a, b, note in COLLISION_TESTS:
        if a in runs and b in runs:
            result = decide_n3(runs[a], runs[b])
            text = result if result == "no difference detected" else f"{a} collides {result}"
            lines.append(f"- N3, {a} against {b} ({note}): {tag}**{text}**.")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("task_folders", nargs="+")
    parser.add_argument("--expected-seeds", type=int, required=True, help="the seeds per variant registered")
    args = parser.parse_args()
    for folder in args.task_folders:
        print(analyse(folder, args.expected_seeds))
        print()


if __name__ == "__main__":
    main()

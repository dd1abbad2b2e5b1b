"""
The pre-registered analysis of the paper's Fig. 4 at its size (the study's README.md, "Fig. 4 and Table 1 at the
paper's budget: pre-registered analysis"), applied mechanically:

    python scripts/fig4_analysis.py results/CommunicativeNavigation-sparse-paper-1e6 \\
        results/CommunicativeNavigation-distance-paper --expected-seeds 3

Only complete runs (``run.json`` with ``complete: true``) are used; with fewer complete seeds per variant than
``--expected-seeds`` every decision is printed as INTERIM.

The rules, as registered (window 200 evaluations; "final level" = mean of the last 200 evaluations of any-step success;
a run reaches a threshold when its trailing 200-evaluation mean does; a run that never does is censored at its last
episode):

- *Ahead* (levels): A is ahead of B if A's seed mean of the final level is at least 0.05 above B's and A's worst seed
  is above B's seed mean; *behind* if B is ahead of A; otherwise *no difference detected*.
- *Faster* (episodes): the target T = max(0.9 x L, 0.2), L = MADDPG's seed mean of the final level; E = the median
  over MADDPG's seeds of the episodes to T (a seed that never reaches T counting at its last episode). A is *faster*
  if every seed of A reaches T and A's Kaplan-Meier median is at most 0.75 x E; *slower* if every MADDPG seed reaches
  T and fewer than half of A's seeds reach it, or A's median is at least E / 0.75; otherwise *no difference detected*.
- Sparse reward: F1, ``macb_local`` against ``maddpg`` (the paper: MACB(o_i, a_i) ~70% at 4e4 episodes, MADDPG ~40%):
  *confirmed* if ahead, *refuted* if behind, otherwise *not detected*. F2, ``macb_joint`` against ``macb_local`` (the
  paper: "the positive effect of centralization"), the same way. F3, ``macb_local`` against ``macb_constant`` by the
  headline's rule C2.
- Distance reward: F4, ``macb_joint`` against ``maddpg`` (the paper: MACB reduces the episodes the agents need):
  *confirmed* if faster, *refuted* if slower, otherwise *not detected*; their final levels are reported by the
  "ahead" rule beside it. F5, ``macb_joint`` against ``macb_constant`` by C2, and ``macb_constant`` against ``maddpg``
  by the "faster" rule (whether the offset alone does what MACB does).
"""

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from headline_analysis import MARGIN, WINDOW, Run, complete_runs, decide_c2  # noqa: E402  (sibling scripts)
from nav_analysis import FLOOR, FRACTION, NavRun, variant_table  # noqa: E402
from sb3_macb.common import evaluations  # noqa: E402

SPEEDUP = 0.75
CLAIM = {"ahead": "confirmed", "faster": "confirmed", "behind": "refuted", "slower": "refuted"}


def load_runs(task_folder: str) -> tuple[dict[str, list[NavRun]], dict[str, list[int]]]:
    """The complete runs of every variant below ``task_folder`` (by seed), and the seeds of the incomplete ones."""
    runs: dict[str, list[NavRun]] = {}
    done, incomplete = complete_runs(task_folder, {evaluations.SUCCESSES, evaluations.FINAL_SUCCESSES})
    for variant, seed, data in done:
        runs.setdefault(variant, []).append(
            NavRun(seed, data, evaluations.final_level(data, evaluations.SUCCESSES, WINDOW),
                   evaluations.final_level(data, evaluations.FINAL_SUCCESSES, WINDOW), float("nan"))  # fmt: skip
        )
    for group in runs.values():
        group.sort(key=lambda r: r.seed)
    return runs, incomplete


def ahead(a: list[NavRun], b: list[NavRun]) -> bool:
    """A's seed mean of the final level at least MARGIN above B's, and A's worst seed above B's mean."""
    ours, theirs = np.array([r.final_any for r in a]), float(np.mean([r.final_any for r in b]))
    return bool(ours.mean() - theirs >= MARGIN and ours.min() > theirs)


def decide_level(a: list[NavRun], b: list[NavRun]) -> tuple[str, str]:
    """Ahead / behind / no difference detected, and the figures behind it."""
    figures = (
        f"final any-step success {np.mean([r.final_any for r in a]):.3f} against {np.mean([r.final_any for r in b]):.3f}"
        f" (seed means; per seed {', '.join(f'{r.final_any:.3f}' for r in a)} against "
        f"{', '.join(f'{r.final_any:.3f}' for r in b)})"
    )
    if ahead(a, b):
        return "ahead", figures
    return ("behind" if ahead(b, a) else "no difference detected"), figures


def decide_speed(a: list[NavRun], maddpg: list[NavRun]) -> tuple[str, str]:
    """Faster / slower / no difference detected against MADDPG's episodes to its target, and the figures."""
    threshold = max(FRACTION * float(np.mean([r.final_any for r in maddpg])), FLOOR)
    crossings = [r.episodes_to(threshold) for r in a]
    reached = sum(ok for _, ok in crossings)
    median = evaluations.km_median([e for e, _ in crossings], [ok for _, ok in crossings])
    reference = [r.episodes_to(threshold) for r in maddpg]
    e = float(np.median([episodes for episodes, _ in reference]))  # censored seeds count at their last episode
    figures = (
        f"target {threshold:.3f} any-step success; {reached} of {len(a)} seeds reach it, Kaplan-Meier median "
        f"{'not reached' if median is None else f'{median:.0f} episodes'}; MADDPG {sum(ok for _, ok in reference)} of "
        f"{len(maddpg)}, median {e:.0f} episodes (faster: at most {SPEEDUP * e:.0f}; slower: at least {e / SPEEDUP:.0f})"
    )
    if reached == len(a) and median is not None and median <= SPEEDUP * e:
        return "faster", figures
    if all(ok for _, ok in reference) and (reached < len(a) / 2 or median is None or median >= e / SPEEDUP):
        return "slower", figures
    return "no difference detected", figures


def c2(a: list[NavRun], constant: list[NavRun]) -> tuple[str, str]:
    """The headline's rule C2 for ``a`` against the constant bonus."""
    as_runs = [[Run(r.seed, 0.0, False, r.final_any, r.final_last) for r in group] for group in (a, constant)]
    return decide_c2(*as_runs)


def episodes_to_90(runs: list[NavRun]) -> str:
    """Each run's episodes to 90% any-step success (">" and its last episode if it never gets there)."""
    return ", ".join(f"{e:.0f}" if ok else f">{e:.0f}" for e, ok in (r.episodes_to(0.9) for r in runs))


def analyse(task_folder: str, expected_seeds: int) -> str:
    """The markdown report of the rules that apply to one task folder (sparse: F1-F3; distance: F4-F5)."""
    runs, incomplete = load_runs(task_folder)
    interim = any(len(runs.get(v, [])) < expected_seeds for v in set(runs) | set(incomplete)) or not runs
    tag = "INTERIM (fewer complete seeds than registered): " if interim else ""
    lines = variant_table(task_folder, runs, incomplete, "episodes to 90% any-step (per seed)", episodes_to_90)
    name = os.path.basename(os.path.normpath(task_folder))
    if "-distance" in name:
        if "macb_joint" in runs and "maddpg" in runs:
            result, figures = decide_speed(runs["macb_joint"], runs["maddpg"])
            lines.append(f"- F4, macb_joint against maddpg: {tag}**{CLAIM.get(result, 'not detected')}** ({result}); "
                         f"{figures}.")  # fmt: skip
            result, figures = decide_level(runs["macb_joint"], runs["maddpg"])
            lines.append(f"- F4, final levels: {tag}macb_joint **{result}**; {figures}.")
        if "macb_joint" in runs and "macb_constant" in runs:
            decision, figures = c2(runs["macb_joint"], runs["macb_constant"])
            lines.append(f"- F5, macb_joint against macb_constant: {tag}**{decision}**; {figures}.")
        if "macb_constant" in runs and "maddpg" in runs:
            result, figures = decide_speed(runs["macb_constant"], runs["maddpg"])
            lines.append(f"- F5, macb_constant against maddpg: {tag}**{result}**; {figures}.")
    else:
        for rule, a, b in (("F1", "macb_local", "maddpg"), ("F2", "macb_joint", "macb_local")):
            if a in runs and b in runs:
                result, figures = decide_level(runs[a], runs[b])
                lines.append(f"- {rule}, {a} against {b}: {tag}**{CLAIM.get(result, 'not detected')}** ({a} {result}); "
                             f"{figures}.")  # fmt: skip
        if "macb_local" in runs and "macb_constant" in runs:
            decision, figures = c2(runs["macb_local"], runs["macb_constant"])
            lines.append(f"- F3, macb_local against macb_constant: {tag}**{decision}**; {figures}.")
    if not runs:
        lines.append("- No complete runs yet: nothing to decide.")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("task_folders", nargs="+", help="the sparse and the distance reward's folders")
    parser.add_argument("--expected-seeds", type=int, required=True, help="the seeds per variant registered")
    args = parser.parse_args()
    for folder in args.task_folders:
        print(analyse(folder, args.expected_seeds))
        print()


if __name__ == "__main__":
    main()

"""
The pre-registered analysis of the refcode experiment (the study's README.md, "The reference code's episode handling"),
applied mechanically:

    python scripts/refcode_analysis.py results/CommunicativeNavigation-sparse-refcode \\
        --plain results/CommunicativeNavigation-sparse-4e4 --expected-seeds 3
    python scripts/refcode_analysis.py results/CommunicativeNavigation-sparse-timeout-terminal --handling \\
        timeout_terminal --plain results/CommunicativeNavigation-sparse-4e4-1e6 --expected-seeds 3

``--handling`` names the zoo variant of the episode handling (``refcode``: episodes end on success and time limits
are terminal; ``timeout_terminal``: only the 20-step cut, stored as terminal); the runs are
``maddpg+<handling>`` and ``macb_constant+<handling>``, and ``<handling>`` stands for it in the rules below.

Only complete runs are used, and the decisions are printed as INTERIM until every variant has ``--expected-seeds``
complete seeds. The rules, as registered (final level: mean any-step success over the last 200 evaluations; a run
reaches 90% when its trailing 200-evaluation mean does):

- R1, the handling alone: ``maddpg+<handling>`` against the plain MADDPG runs of the same seeds (``--plain``). A
  *change* if the difference of the seed means is at least 0.05 in size and the two sets of seeds do not overlap
  (every seed of one above every seed of the other); otherwise *no change detected*.
- R2, the offset under that handling: ``macb_constant+<handling>`` against ``maddpg+<handling>``. The offset *helps* if
  its seed mean is at least 0.05 higher and its worst seed is above ``maddpg+<handling>``'s mean; it *hurts* if its
  seed mean is at least 0.05 lower and its best seed is below that mean; otherwise *no effect detected*.
- R3, the paper's picture: *reproduced through the offset* if ``macb_constant+<handling>`` reaches 90% any-step
  success in at least 2 of 3 seeds and ``maddpg+<handling>`` in none; otherwise *not reproduced*.
"""

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from headline_analysis import MARGIN, Run, load_runs  # noqa: E402  (a sibling script)

PLAIN = "maddpg"


def levels(runs: list[Run]) -> str:
    """Seed mean and per-seed final any-step levels."""
    values = [r.final_any for r in runs]
    return f"{np.mean(values):.3f} ({', '.join(f'{v:.3f}' for v in values)})"


def decide_r1(refcode: list[Run], plain: list[Run]) -> str:
    """R1: the handling alone changes MADDPG's final level, or no change is detected."""
    ours, theirs = np.array([r.final_any for r in refcode]), np.array([r.final_any for r in plain])
    apart = ours.min() > theirs.max() or ours.max() < theirs.min()
    return "change" if abs(ours.mean() - theirs.mean()) >= MARGIN and apart else "no change detected"


def decide_r2(constant: list[Run], maddpg: list[Run]) -> str:
    """R2: the constant offset helps, hurts, or has no detected effect under the reference handling."""
    ours = np.array([r.final_any for r in constant])
    reference = float(np.mean([r.final_any for r in maddpg]))
    if ours.mean() - reference >= MARGIN and ours.min() > reference:
        return "helps"
    if reference - ours.mean() >= MARGIN and ours.max() < reference:
        return "hurts"
    return "no effect detected"


def decide_r3(constant: list[Run], maddpg: list[Run]) -> str:
    """R3: the paper's picture (the offset reaches 90%, MADDPG does not) under the reference handling."""
    reproduced = sum(r.reached for r in constant) >= 2 and not any(r.reached for r in maddpg)
    return "reproduced through the offset" if reproduced else "not reproduced"


def analyse(folder: str, plain_folder: str, expected_seeds: int, handling: str = "refcode") -> str:
    """The markdown report of R1-R3 for the runs of one episode handling (a zoo variant's name)."""
    MADDPG, CONSTANT = f"maddpg+{handling}", f"macb_constant+{handling}"  # noqa: N806
    runs, incomplete = load_runs(folder)
    missing = [v for v in (MADDPG, CONSTANT) if len(runs.get(v, [])) < expected_seeds]
    tag = "INTERIM (fewer complete seeds than registered): " if missing or incomplete else ""
    lines = [f"### {os.path.basename(os.path.normpath(folder))}", ""]
    if not runs.get(MADDPG) or not runs.get(CONSTANT):
        return "\n".join(lines + [f"- Not enough complete runs to decide (complete: {sorted(runs)})."])
    maddpg, constant = (sorted(runs[v], key=lambda r: r.seed) for v in (MADDPG, CONSTANT))
    seeds = {r.seed for r in maddpg}
    plain = sorted((r for r in load_runs(plain_folder)[0].get(PLAIN, []) if r.seed in seeds), key=lambda r: r.seed)
    lines += ["| variant | seeds | final any-step success, mean (per seed) | reached 90% any-step |", "|---|---|---|---|"]
    for name, group in ((f"{PLAIN} (plain, {os.path.basename(os.path.normpath(plain_folder))})", plain),
                        (MADDPG, maddpg), (CONSTANT, constant)):  # fmt: skip
        if group:
            lines.append(f"| {name} | {', '.join(str(r.seed) for r in group)} | {levels(group)} | "
                         f"{sum(r.reached for r in group)} of {len(group)} |")  # fmt: skip
    lines.append("")
    if len(plain) == len(maddpg):
        lines.append(f"- R1, the handling alone ({MADDPG} against plain {PLAIN}): {tag}**{decide_r1(maddpg, plain)}**.")
    else:
        lines.append(f"- R1: the plain runs lack seeds {sorted(seeds - {r.seed for r in plain})}: not decided.")
    r2 = decide_r2(constant, maddpg)
    lines.append(f"- R2, the offset under that handling ({CONSTANT} against {MADDPG}): {tag}**{r2}**.")
    lines.append(f"- R3, the paper's picture: {tag}**{decide_r3(constant, maddpg)}**.")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folder", help="the refcode runs: <folder>/<variant>/seed_<s>/")
    parser.add_argument("--plain", required=True, help="the task folder holding the plain maddpg runs of the same seeds")
    parser.add_argument("--expected-seeds", type=int, required=True, help="the seeds per variant registered")
    parser.add_argument("--handling", default="refcode", choices=["refcode", "timeout_terminal"],
                        help="the zoo variant of the episode handling")  # fmt: skip
    args = parser.parse_args()
    print(analyse(args.folder, args.plain, args.expected_seeds, args.handling))


if __name__ == "__main__":
    main()

"""
The pre-registered analysis of the paper's Table 1 at its budget (4e4 episodes) with 64-64 networks and three seeds
(the study's README.md, "Fig. 4 and Table 1 at the paper's budget: pre-registered analysis"), applied mechanically:

    python scripts/table1_analysis.py results/CommunicativeNavigation-sparse-table1-4e4 \\
        --base results/CommunicativeNavigation-sparse-4e4-1e6 --expected-seeds 3

The grid's runs are ``macb_joint+exploration.beta=B+exploration.k=K`` (``scripts/reproduce.py --grid``); the cells
that equal runs of the headline experiment come from ``--base``: (0.8, 512) is ``macb_joint``, (0.8, 32) is
``macb_k32``, the beta = 0 column is ``maddpg`` and the control is ``macb_constant`` (beta 0.8, no counting). Only
seeds ``0 .. expected-seeds - 1`` are used in every cell, and only complete runs; with a cell short of them every
decision is printed as INTERIM.

The rules, as registered. A cell's *success* is its seed mean of the final level of any-step success (the mean of
the last 200 evaluations), its *count-1* the seed mean of the table's fraction of codes seen once at the last
evaluation.

- K1, "with MACB the success rate is higher than MADDPG's most of the time": a cell is *above* MADDPG if its success
  is at least 0.05 above MADDPG's and its worst seed is above MADDPG's seed mean; *below* in the mirror case. The
  claim is *confirmed* if at least 9 of the 16 cells are above, *refuted* if at least 8 are below, otherwise
  *inconclusive*.
- K2, "k = 32 loses information" (the paper's k = 32 row gains little over MADDPG, its k = 512 row is the best): the mean
  success of the k = 512 row against the k = 32 row (four cells each): *confirmed* if the k = 512 row is at least
  0.05 higher, *refuted* if the k = 32 row is at least 0.05 higher, otherwise *no difference detected*.
- K3, count-1 "increases as k, and at k = 512 converges to 100%": *confirmed* if in every beta column count-1
  rises strictly with k and is at least 0.99 at k = 512; otherwise *not confirmed*, with the columns that break it.
- K4, counts or offset: each cell of the beta = 0.8 column against ``macb_constant`` by the headline's rule C2.
- Reported, not decided: the best cell, and the best beta of each k row (the paper: a larger k needs a larger beta).
"""

import argparse
import os
import re
import sys
from dataclasses import dataclass

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from headline_analysis import MARGIN, WINDOW, Run, complete_runs, decide_c2  # noqa: E402  (a sibling script)
from sb3_macb.common import evaluations  # noqa: E402

BETAS, KS = (0.05, 0.2, 0.4, 0.8), (32, 64, 256, 512)
CELL = re.compile(r"^macb_joint\+exploration\.beta=([0-9.]+)\+exploration\.k=([0-9]+)$")
BASE_CELLS = {"macb_joint": (0.8, 512), "macb_k32": (0.8, 32)}
MAJORITY, COUNT1_AT_512 = 9, 0.99


@dataclass
class CellRun:
    """One complete run of a cell: its seed, final levels of any-step and final-step success, and final count-1."""

    seed: int
    final_any: float
    final_last: float
    count1: float


def load(task_folder: str, base_folder: str, seeds: int) -> tuple[dict, dict[str, list[CellRun]], list[str]]:
    """
    The grid's cells ({(beta, k): runs}), the base runs (``maddpg``, ``macb_constant``) and what is missing (cells or
    base variants short of ``seeds`` complete seeds).
    """
    required = {evaluations.SUCCESSES, evaluations.FINAL_SUCCESSES, evaluations.COUNT1_FRACTION}
    cells: dict[tuple[float, int], list[CellRun]] = {}
    base: dict[str, list[CellRun]] = {}
    for folder, named in ((task_folder, False), (base_folder, True)):
        done, _ = complete_runs(folder, required - ({evaluations.COUNT1_FRACTION} if named else set()))
        for variant, seed, data in done:
            if seed >= seeds:
                continue
            count1 = data.get(evaluations.COUNT1_FRACTION)
            run = CellRun(seed, evaluations.final_level(data, evaluations.SUCCESSES, WINDOW),
                          evaluations.final_level(data, evaluations.FINAL_SUCCESSES, WINDOW),
                          float(count1[-1]) if count1 is not None else float("nan"))  # fmt: skip
            match = CELL.match(variant)
            if named and variant in BASE_CELLS:
                cells.setdefault(BASE_CELLS[variant], []).append(run)
            elif named and variant in ("maddpg", "macb_constant"):
                base.setdefault(variant, []).append(run)
            elif not named and match:
                cells.setdefault((float(match.group(1)), int(match.group(2))), []).append(run)
    for group in [*cells.values(), *base.values()]:
        group.sort(key=lambda r: r.seed)
    missing = [f"beta {b}, k {k}" for b in BETAS for k in KS if len(cells.get((b, k), [])) < seeds]
    missing += [v for v in ("maddpg", "macb_constant") if len(base.get(v, [])) < seeds]
    return cells, base, missing


def above(a: list[CellRun], b: list[CellRun]) -> bool:
    """A's success at least MARGIN above B's, and A's worst seed above B's seed mean."""
    ours, theirs = np.array([r.final_any for r in a]), float(np.mean([r.final_any for r in b]))
    return bool(ours.mean() - theirs >= MARGIN and ours.min() > theirs)


def success(runs: list[CellRun]) -> float:
    return float(np.mean([r.final_any for r in runs]))


def analyse(task_folder: str, base_folder: str, seeds: int) -> str:
    """The markdown report of K1-K4 and the table."""
    cells, base, missing = load(task_folder, base_folder, seeds)
    tag = "INTERIM (cells short of the registered seeds): " if missing else ""
    lines = ["### Table 1: final any-step success (seed mean, per seed) and count-1 at the end", ""]
    lines.append("| k \\ beta | 0 (MADDPG) | " + " | ".join(str(b) for b in BETAS) + " |")
    lines.append("|---|---|" + "---|" * len(BETAS))
    maddpg = base.get("maddpg", [])
    first = f"{success(maddpg):.3f} ({', '.join(f'{r.final_any:.2f}' for r in maddpg)})" if maddpg else "-"
    for k in KS:
        row = [f"{first if k == KS[0] else ''}"]
        for beta in BETAS:
            runs = cells.get((beta, k), [])
            row.append(f"{success(runs):.3f} ({', '.join(f'{r.final_any:.2f}' for r in runs)}), "
                       f"{100 * np.mean([r.count1 for r in runs]):.1f}%" if runs else "-")  # fmt: skip
        lines.append(f"| {k} | " + " | ".join(row) + " |")
    lines.append("")
    if missing:
        lines.append(f"- Short of {seeds} complete seeds: {'; '.join(missing)}.")
    complete = {cell: runs for cell, runs in cells.items() if runs}
    if maddpg and complete:
        up = [cell for cell, runs in complete.items() if above(runs, maddpg)]
        down = [cell for cell, runs in complete.items() if above(maddpg, runs)]
        decision = "confirmed" if len(up) >= MAJORITY else "refuted" if len(down) >= 16 - MAJORITY + 1 else "inconclusive"
        lines.append(f"- K1, MACB above MADDPG in most cells: {tag}**{decision}**; {len(up)} of {len(complete)} cells "
                     f"above MADDPG's {success(maddpg):.3f}, {len(down)} below (confirmed at {MAJORITY} above, refuted at "
                     f"{16 - MAJORITY + 1} below).")  # fmt: skip
    rows = {k: [success(cells[(b, k)]) for b in BETAS if cells.get((b, k))] for k in (32, 512)}
    if all(rows.values()):
        difference = float(np.mean(rows[512]) - np.mean(rows[32]))
        decision = "confirmed" if difference >= MARGIN else "refuted" if difference <= -MARGIN else "no difference detected"
        lines.append(f"- K2, k = 512 row against k = 32 row: {tag}**{decision}**; row means {np.mean(rows[512]):.3f} "
                     f"and {np.mean(rows[32]):.3f} (difference {difference:+.3f}, decided at +/-{MARGIN}).")  # fmt: skip
    counts = {(b, k): float(np.mean([r.count1 for r in runs])) for (b, k), runs in complete.items()}
    if len(counts) == len(BETAS) * len(KS):
        broken = [b for b in BETAS if any(counts[(b, k1)] >= counts[(b, k2)] for k1, k2 in zip(KS, KS[1:]))
                  or counts[(b, 512)] < COUNT1_AT_512]  # fmt: skip
        decision = "confirmed" if not broken else f"not confirmed (beta {', '.join(map(str, broken))})"
        lines.append(f"- K3, count-1 rises with k and reaches {COUNT1_AT_512} at k = 512: {tag}**{decision}**.")
    for k in KS:
        if cells.get((0.8, k)) and base.get("macb_constant"):
            as_runs = [[Run(r.seed, 0.0, False, r.final_any, r.final_last) for r in g]
                       for g in (cells[(0.8, k)], base["macb_constant"])]  # fmt: skip
            decision, figures = decide_c2(*as_runs)
            lines.append(f"- K4, beta 0.8, k {k} against macb_constant: {tag}**{decision}**; {figures}.")
    if complete:
        best = max(complete, key=lambda cell: success(complete[cell]))
        lines.append(f"- Reported: the best cell is beta {best[0]}, k {best[1]} ({success(complete[best]):.3f}); the best "
                     "beta per k: " + ", ".join(
                         f"k {k}: {max((b for b in BETAS if (b, k) in complete), key=lambda b: success(complete[(b, k)]))}"
                         for k in KS if any((b, k) in complete for b in BETAS)) + ".")  # fmt: skip
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("task_folder", help="the grid's runs (reproduce.py --grid ... --suffix table1-4e4)")
    parser.add_argument("--base", required=True, help="the headline's 64-64 runs with the registered buffer")
    parser.add_argument("--expected-seeds", type=int, required=True, help="the seeds per cell registered (0 .. N-1)")
    args = parser.parse_args()
    print(analyse(args.task_folder, args.base, args.expected_seeds))


if __name__ == "__main__":
    main()

"""
The exploration study's registered readings (README.md), applied to the runs under ``results/``: the entry rule of
each task (from the pilot), the informative k (from the pilot's ``count1.json``), and per task the metrics and
decisions of every method. Written and committed before any pilot or study run.

    python scripts/analyze.py                       # every task with runs; prints markdown
    python scripts/analyze.py --json decisions.json
    python scripts/analyze.py --followup            # also the 400-300 follow-up of each task's best method

The follow-up's rules (README.md, "The 400-300 follow-up") were added on 2026-12-05, before any study run was
analysed; the tables' Kaplan-Meier medians and episodes to 50% were added then too (reported, deciding nothing).

Only complete runs count (``run.json`` says ``complete``); a method with fewer seeds than registered is reported
as incomplete and decided on nothing.
"""

import argparse
import json
import os
import sys

import numpy as np

STUDY = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CHECKOUT = os.path.dirname(os.path.dirname(STUDY))
sys.path[:0] = [p for p in (CHECKOUT, os.path.join(STUDY, "scripts")) if p not in sys.path[:2]]

from sb3_macb.common import evaluations  # noqa: E402
from study_tasks import CANDIDATES  # noqa: E402

WINDOW = 200  # evaluations: the final level's window and the moving average of the episodes to a threshold
ENTRY_MAX_FINAL = 0.30  # plain MADDPG's final success below this ...
ENTRY_MIN_SEEDS = 2  # ... in at least this many of the pilot's three seeds
SCRIPTED_MIN = 0.90  # the scripted policy's success, at least
COUNT1_MAX = 0.90  # the informative k: the largest k whose pilot count-1 fraction is below this
PROBE_KS = (8, 16, 32, 64, 128, 256, 512)
PILOT_SEEDS = (0, 1, 2)
STUDY_SEEDS = (0, 1, 2, 3, 4)
MARGIN = 0.2  # a method helps when its seed-mean final success is at least this much above the baseline's ...
THRESHOLDS = (0.5, 0.9)
# credit: (method, the baseline it must beat); MADDPG is every method's first baseline
CREDIT = {
    "macb_paper": ("maddpg",),
    "macb_k": ("maddpg",),
    "macb_k_center": ("maddpg", "macb_k"),  # centering: against the same estimator added plainly
    "macb_k_center_int": ("maddpg", "macb_k"),  # the intrinsic critic: the same
    "macb_k_sketch": ("maddpg", "macb_k_center"),  # the count-min sketch: against the exact table, centered alike
    "rnd": ("maddpg",),
    "constant": ("maddpg",),
}


def load_runs(results: str, task: str, method: str) -> dict[int, dict[str, np.ndarray]]:
    """The complete runs of a method on a task, by seed."""
    folder = os.path.join(results, task, method)
    runs = {}
    if os.path.isdir(folder):
        for name in sorted(os.listdir(folder)):
            path = os.path.join(folder, name)
            if name.startswith("seed_") and evaluations.is_complete(path):
                runs[int(name[5:])] = evaluations.load(path)
    return runs


def summary(runs: dict[int, dict[str, np.ndarray]]) -> dict[str, object]:
    """Per seed: the final level and the (censored) episodes to each threshold; and their seed means."""
    out: dict[str, object] = {"seeds": sorted(runs)}
    finals = [evaluations.final_level(runs[s], evaluations.SUCCESSES, WINDOW) for s in sorted(runs)]
    out["final"] = finals
    out["final_mean"] = float(np.mean(finals)) if finals else None
    for threshold in THRESHOLDS:
        hits = [evaluations.episodes_to(runs[s][evaluations.SUCCESSES], evaluations.episodes(runs[s]), threshold, WINDOW)
                for s in sorted(runs)]  # fmt: skip
        out[f"episodes_to_{threshold}"] = [h[0] for h in hits]
        out[f"reached_{threshold}"] = [h[1] for h in hits]
        out[f"episodes_to_{threshold}_mean"] = float(np.mean([h[0] for h in hits])) if hits else None
        out[f"episodes_to_{threshold}_km_median"] = evaluations.km_median([h[0] for h in hits], [h[1] for h in hits])
    return out


def helps(method: dict, baseline: dict) -> bool:
    """
    The registered rule: the method's seed-mean final success exceeds the baseline's by at least 0.2 and its worst
    seed is above the baseline's mean, or it reaches 90% in every seed in at most half the baseline's seed-mean
    episodes to 90% (the baseline's censored seeds counting at their last episode).
    """
    level = (method["final_mean"] - baseline["final_mean"] >= MARGIN - 1e-12
             and min(method["final"]) > baseline["final_mean"])  # fmt: skip
    speed = all(method["reached_0.9"]) and method["episodes_to_0.9_mean"] <= 0.5 * baseline["episodes_to_0.9_mean"]
    return bool(level or speed)


def entry(results: str, task: str, scripted: float | None) -> dict[str, object]:
    """The entry rule from the pilot (MADDPG, seeds 0-2) and the scripted level; None where runs are missing."""
    pilot = {s: r for s, r in load_runs(results, task, "maddpg").items() if s in PILOT_SEEDS}
    if len(pilot) < len(PILOT_SEEDS):
        return {"decided": False, "why": f"pilot incomplete: {len(pilot)} of {len(PILOT_SEEDS)} seeds"}
    finals = [evaluations.final_level(pilot[s], evaluations.SUCCESSES, WINDOW) for s in PILOT_SEEDS]
    failing = sum(f < ENTRY_MAX_FINAL for f in finals)
    solvable = scripted is not None and scripted >= SCRIPTED_MIN
    return {"decided": True, "enters": bool(failing >= ENTRY_MIN_SEEDS and solvable), "pilot_final": finals,
            "pilot_seeds_below": failing, "scripted": scripted}  # fmt: skip


def informative_k(results: str, task: str) -> dict[str, object]:
    """The largest probed k whose count-1 fraction, averaged over the pilot's seeds, is below 0.9 (else 8)."""
    levels = []
    for seed in PILOT_SEEDS:
        path = os.path.join(results, task, "maddpg", f"seed_{seed}", "count1.json")
        if not os.path.isfile(path):
            return {"k": None, "why": f"{path} missing"}
        with open(path) as file:
            levels.append(json.load(file)["count1_fraction"])
    means = {k: float(np.mean([level[str(k)] for level in levels])) for k in PROBE_KS}
    below = [k for k in PROBE_KS if means[k] < COUNT1_MAX]
    return {"k": max(below) if below else min(PROBE_KS), "count1_mean": means}


def decide(results: str, task: str) -> dict[str, object]:
    """Every method's summary and the registered decisions on one task."""
    summaries = {m: summary(load_runs(results, task, m)) for m in ("maddpg", *CREDIT)}
    complete = {m for m, s in summaries.items() if tuple(s["seeds"]) == STUDY_SEEDS}
    decisions: dict[str, object] = {}
    for method, baselines in CREDIT.items():
        if method not in complete or any(b not in complete for b in baselines):
            decisions[method] = "incomplete"
            continue
        beats = {b: helps(summaries[method], summaries[b]) for b in baselines}
        verdict = {"helps_vs_maddpg": beats["maddpg"], "beats": beats}
        if method != "constant":  # a bonus is credited with what its estimator knows only beyond a reward offset
            verdict["beats_constant"] = "constant" in complete and helps(summaries[method], summaries["constant"])
        verdict["credited"] = all(beats.values()) and verdict.get("beats_constant", True)
        decisions[method] = verdict
    return {"summaries": summaries, "decisions": decisions}


FOLLOWUP_NET = (400, 300)  # the follow-up's networks ...
FOLLOWUP_SEEDS = (0, 1, 2)  # ... and seeds


def best_method(task_report: dict[str, object]) -> str | None:
    """
    The method a task's 400-300 follow-up runs: the credited method with the highest seed-mean final success (ties:
    the fewer seed-mean episodes to 90%, then study.yml's order); None when no method is credited.
    """
    decisions, summaries = task_report["decisions"], task_report["summaries"]
    credited = [m for m, d in decisions.items() if isinstance(d, dict) and d["credited"]]
    if not credited:
        return None
    order = list(CREDIT)
    return min(credited, key=lambda m: (-summaries[m]["final_mean"], summaries[m]["episodes_to_0.9_mean"], order.index(m)))


def followup(results: str, task: str, method: str) -> dict[str, object]:
    """
    The registered 400-300 follow-up of one task: ``method`` against MADDPG, both at 400-300, seeds 0-2, filed under
    ``<task>-400-300``. It *holds* if the method helps against MADDPG by the study's rule; MADDPG is also judged by
    the entry rule (below 0.30 in at least 2 of 3 seeds: the task is still hard for the larger networks).
    """
    folder = "-".join([task, *map(str, FOLLOWUP_NET)])
    runs = {m: {s: r for s, r in load_runs(results, folder, m).items() if s in FOLLOWUP_SEEDS} for m in ("maddpg", method)}
    summaries = {m: summary(r) for m, r in runs.items()}
    missing = [f"{m} ({len(r)} of {len(FOLLOWUP_SEEDS)} seeds)" for m, r in runs.items() if len(r) < len(FOLLOWUP_SEEDS)]
    if missing:
        return {"folder": folder, "method": method, "decided": False, "why": "incomplete: " + ", ".join(missing),
                "summaries": summaries}  # fmt: skip
    below = sum(f < ENTRY_MAX_FINAL for f in summaries["maddpg"]["final"])
    return {"folder": folder, "method": method, "decided": True, "holds": helps(summaries[method], summaries["maddpg"]),
            "maddpg_seeds_below": below, "still_hard": below >= ENTRY_MIN_SEEDS, "summaries": summaries}  # fmt: skip


def _table(summaries: dict[str, dict], decisions: dict[str, object]) -> None:
    """Print the methods' metrics and decisions as a markdown table."""
    print("| method | seeds | final success per seed | mean | reached 50% | episodes to 50% (mean, censored; KM median) "
          "| reached 90% | episodes to 90% (mean, censored; KM median) | decision |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")
    for method, s in summaries.items():
        finals = ", ".join(f"{f:.3f}" for f in s["final"])
        mean = "-" if s["final_mean"] is None else f"{s['final_mean']:.3f}"
        cells = []
        for threshold in THRESHOLDS:
            cells.append(f"{sum(s[f'reached_{threshold}'])} of {len(s['seeds'])}")
            episodes, median = s[f"episodes_to_{threshold}_mean"], s[f"episodes_to_{threshold}_km_median"]
            cells.append("-" if episodes is None else f"{episodes:.0f}; " + ("none" if median is None else f"{median:.0f}"))
        print(f"| {method} | {len(s['seeds'])} | {finals} | {mean} | {' | '.join(cells)} | "
              f"{decisions.get(method, '(baseline)')} |")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--results", default=os.path.join(STUDY, "results"))
    parser.add_argument(
        "--levels",
        default=os.path.join(STUDY, "reference_levels.json"),
        help="scripted and random levels (scripts/task_levels.py --json)",
    )
    parser.add_argument("--json", help="also write everything to this file")
    parser.add_argument("--followup", action="store_true", help="also each task's 400-300 follow-up (README.md)")
    args = parser.parse_args()
    levels: dict[str, dict[str, float]] = {}
    if os.path.isfile(args.levels):
        with open(args.levels) as file:
            levels = json.load(file)["levels"]
    scripted = {t: v["scripted"] for t, v in levels.items()}
    report = {}
    for task in CANDIDATES:
        if not os.path.isdir(os.path.join(args.results, task)):
            continue
        report[task] = {"entry": entry(args.results, task, scripted.get(task)), "k": informative_k(args.results, task),
                        **decide(args.results, task)}  # fmt: skip
        e = report[task]["entry"]
        print(f"## {task}\nentry: {e}\ninformative k: {report[task]['k']}")
        if task in levels:
            print(f"scripted level {levels[task]['scripted']:.3f}, random level {levels[task]['random']:.3f}")
        _table(report[task]["summaries"], report[task]["decisions"])
        if args.followup and e.get("enters"):
            best = best_method(report[task])
            if "incomplete" in report[task]["decisions"].values():
                print("\n400-300 follow-up: not chosen until every method of the task is complete")
            elif best is None:
                report[task]["followup"] = {"method": None}
                print("\n400-300 follow-up: none (no method is credited on this task)")
            else:
                report[task]["followup"] = f = followup(args.results, task, best)
                if f["decided"]:
                    hard = "still hard" if f["still_hard"] else "not hard"
                    verdict = (f"{'holds' if f['holds'] else 'does not hold'}; 400-300 MADDPG below 0.30 in "
                               f"{f['maddpg_seeds_below']} of 3 seeds ({hard})")  # fmt: skip
                else:
                    verdict = f["why"]
                print(f"\n400-300 follow-up ({f['folder']}): {best} against maddpg: {verdict}")
                _table(f["summaries"], {best: "holds" if f.get("holds") else "-"})
        print()
    if args.json:
        with open(args.json, "w") as file:
            json.dump(report, file, indent=1)


if __name__ == "__main__":
    main()

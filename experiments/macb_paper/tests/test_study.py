"""
The paper study's scripts (experiments/macb_paper/scripts/): episodes to a threshold, cutting runs at a budget, filing a
sweep.
"""

import csv
import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sb3_macb.exploration import MACB
from sb3_macb.zoo.plots import plot_table, sweep_table
from sb3_macb.zoo.sweep import load_config

STUDY = Path(__file__).resolve().parents[1]  # experiments/macb_paper
ROOT = STUDY.parents[1]  # the repository
sys.path.insert(0, str(STUDY / "scripts"))  # the scripts import their siblings, as when run from their folder


def load_script(name: str):
    spec = importlib.util.spec_from_file_location(name, STUDY / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def write_run(path: Path, rates: list[float]) -> None:
    """An evaluations.npz with one evaluation per training episode and 10 episodes per evaluation."""
    successes = np.array([[i < round(10 * r) for i in range(10)] for r in rates], dtype=bool)
    episodes = np.arange(1, len(rates) + 1)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, timesteps=20 * episodes, episodes=episodes, successes=successes,
             results=np.zeros((len(rates), 10)), count1_fraction=np.full(len(rates), 0.5),
             training_collisions=3 * episodes)  # fmt: skip


def test_episodes_to_threshold_uses_the_moving_average():
    summary = load_script("summarize_results")
    rates = np.array([0.0] * 5 + [1.0] * 5)
    successes = np.stack([np.arange(10) < 10 * r for r in rates])
    episodes = np.arange(1, 11) * 7
    # the 4-evaluation average first reaches 0.75 at the 8th evaluation (three of the last four are 1.0)
    assert summary.episodes_to(successes, episodes, 0.75, 4) == (56.0, True)
    assert summary.episodes_to(successes, episodes, 0.75, 1) == (42.0, True)
    # a mean exactly at the threshold reaches it, although its floating-point sum may land just below
    exact = np.stack([np.arange(10) < 10 * r for r in [0.0] * 20 + [1.0] * 180 + [0.0] * 20])
    assert summary.episodes_to(exact, np.arange(1, 221), 0.9, 200) == (200.0, True)
    # never reached: the whole budget, flagged
    assert summary.episodes_to(successes, episodes, 1.01, 1) == (70.0, False)


def test_max_episodes_cuts_every_per_evaluation_array(tmp_path):
    summary = load_script("summarize_results")
    write_run(tmp_path / "v" / "seed_0" / "evaluations.npz", [0.1] * 6 + [0.9] * 4)
    data = summary.load_run(str(tmp_path / "v" / "seed_0" / "evaluations.npz"), max_episodes=6)
    assert len(data["episodes"]) == len(data["successes"]) == len(data["timesteps"]) == 6
    assert data["successes"].mean() == pytest.approx(0.1)
    table = summary.summarize(str(tmp_path), threshold=0.5, window=1, final=2, max_episodes=6)
    assert "| v | 1 | 0 of 1 | not reached | >6 | 0.100 +/- 0.000 |" in table  # censored, never averaged
    assert "| v | 1 | 1 of 1 | 7 | 7 |" in summary.summarize(str(tmp_path), threshold=0.5, window=1, final=2)
    with_collisions = summary.summarize(str(tmp_path), 0.5, 1, 2, max_episodes=6, collisions=True)
    assert with_collisions.splitlines()[2].endswith("| 18 +/- 0 |")  # accumulated at the cut: 3 per episode


def test_file_sweep_copies_the_evaluations_and_keeps_the_table(tmp_path):
    sweep = tmp_path / "logs" / "study"
    rows = []
    for trial, (beta, k) in enumerate([(0.2, 32), (0.8, 32), (0.2, 512)]):
        run = sweep / f"trial_{trial}" / "run"
        write_run(run / "evaluations.npz", [beta] * 3)
        rows.append({"trial": trial, "exploration.beta": beta, "exploration.k": k, "seed": 0,
                     "success_rate": beta, "count1_fraction": k / 1000, "run_folder": str(run)})  # fmt: skip
    with open(sweep / "results.csv", "w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    out = tmp_path / "results" / "table"
    done = subprocess.run([sys.executable, str(STUDY / "scripts" / "file_sweep.py"), str(sweep), str(out)],
                          capture_output=True, text=True)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert (out / "beta_0.8_k_32" / "seed_0" / "evaluations.npz").is_file()
    with open(out / "results.csv", newline="") as file:
        filed = list(csv.DictReader(file))
    assert [r["run_folder"] for r in filed] == ["beta_0.2_k_32/seed_0", "beta_0.8_k_32/seed_0", "beta_0.2_k_512/seed_0"]
    rows_, cols, success, count1, seeds = sweep_table(str(out / "results.csv"))
    assert rows_ == [32, 512] and cols == [0.2, 0.8]
    assert success[0, 1] == pytest.approx(0.8) and np.isnan(success[1, 1]) and count1[1, 0] == pytest.approx(0.512)


@pytest.mark.parametrize("name", ["table1.yml", "table1_fast.yml"])
def test_table1_sweep_configs_are_valid(name):
    config = load_config(str(ROOT / "zoo" / "sweeps" / name))
    assert config["grid"] == {"exploration.beta": [0.05, 0.2, 0.4, 0.8], "exploration.k": [32, 64, 256, 512]}
    for beta in config["grid"]["exploration.beta"]:
        for k in config["grid"]["exploration.k"]:
            MACB(beta=beta, k=k)  # every cell is a valid MACB


def test_kaplan_meier_median_counts_censored_runs():
    km = load_script("summarize_results").km_median
    assert km([100, 200, 300], [True, True, True]) == 200
    assert km([100, 400, 400], [True, False, False]) is None  # one of three reached it: no median
    assert km([100, 150, 400, 400], [True, True, False, False]) == 150  # half reached it
    assert km([50, 300, 400], [False, True, True]) == 300  # censored early: S(300) = 1 - 1/2
    sd = load_script("summarize_results").sample_sd
    assert sd([1.0, 2.0, 3.0]) == pytest.approx(1.0)  # n - 1: a population SD would be 0.816
    assert sd([0.4]) == 0.0


def write_headline_run(folder: Path, any_step: list[float], final_step: list[float], complete: bool = True) -> None:
    """A run as reproduce.py files it: evaluations.npz with both success metrics, and run.json."""
    def block(rates):
        return np.array([[i < round(10 * r) for i in range(10)] for r in rates], dtype=bool)

    episodes = np.arange(1, len(any_step) + 1) * 100
    folder.mkdir(parents=True, exist_ok=True)
    np.savez(folder / "evaluations.npz", timesteps=20 * episodes, episodes=episodes, successes=block(any_step),
             final_successes=block(final_step), results=np.zeros((len(any_step), 10)))  # fmt: skip
    (folder / "run.json").write_text(f'{{"complete": {str(complete).lower()}}}')


def test_headline_analysis_applies_the_registered_rules(tmp_path):
    analysis = load_script("headline_analysis")
    reference = tmp_path / "reference.json"
    reference.write_text('{"random_landmark": {"final_step": 0.35}, "landmark_tour": {"final_step": 0.18},'
                         ' "oracle": {"final_step": 1.0}}')  # fmt: skip
    task = tmp_path / "task"
    n = 1000  # evaluations of 100 episodes each; 90% needs 200 consecutive evaluations averaging 0.9
    for seed in range(3):
        write_headline_run(task / "maddpg" / f"seed_{seed}", [0.4] * n, [0.3] * n)
        # MACB reaches 90% at evaluations 200, 210, 240 (episodes 20000, 21000, 24000), and communicates
        start = 30 * seed
        write_headline_run(task / "macb_joint" / f"seed_{seed}", [0.0] * start + [1.0] * (n - start), [0.9] * n)
        write_headline_run(task / "macb_constant" / f"seed_{seed}", [0.9, 1.0, 1.0, 1.0, 1.0] * (n // 5), [0.3] * n)
    write_headline_run(task / "macb_k32" / "seed_0", [0.2] * n, [0.1] * n, complete=False)
    # a variant without its registered seeds complete makes every decision interim
    assert "C1, the paper's claim: INTERIM" in analysis.analyse(str(task), 3, str(reference))
    for seed in range(3):
        write_headline_run(task / "macb_k32" / f"seed_{seed}", [0.2] * n, [0.1] * n, complete=seed > 0)
    report = analysis.analyse(str(task), 3, str(reference))
    assert "C1, the paper's claim: INTERIM" in report  # seed 0 of macb_k32 still runs
    write_headline_run(task / "macb_k32" / "seed_0", [0.2] * n, [0.1] * n)
    report = analysis.analyse(str(task), 3, str(reference))
    assert "C1, the paper's claim: **confirmed**" in report
    assert "Kaplan-Meier median 21000 episodes; MADDPG median 100000" in report
    # MACB +0.02 any-step (1.0 against 0.98) and +0.6 final-step: one difference below 0.05
    assert "C2, macb_joint against macb_constant: **attributed to the reward offset**" in report
    assert "macb_constant 0 of 3; macb_joint 3 of 3; macb_k32 0 of 3; maddpg 0 of 3." in report
    # MACB behind by 0.05 or more on both metrics: below +0.05, so attributed to the offset as registered
    assert "C2, macb_k32 against macb_constant: **attributed to the reward offset**" in report

    # with one seed fewer than registered, every decision is interim
    assert "C1, the paper's claim: INTERIM" in analysis.analyse(str(task), 4, str(reference))

    # one MACB seed that never reaches 90%: not every seed, but the median still at most half of MADDPG's; then two
    write_headline_run(task / "macb_joint" / "seed_2", [0.5] * n, [0.9] * n)
    assert "**inconclusive**" in analysis.analyse(str(task), 3, str(reference))
    write_headline_run(task / "macb_joint" / "seed_1", [0.5] * n, [0.9] * n)
    assert "**refuted**" in analysis.analyse(str(task), 3, str(reference))


@pytest.mark.parametrize(
    "macb, constant, decision",
    [
        ([(0.8, 0.7)] * 3, [(0.6, 0.5)] * 3, "counting credited"),
        ([(0.8, 0.7), (0.8, 0.7), (0.55, 0.45)], [(0.6, 0.5)] * 3, "not credited: not every seed"),
        ([(0.5, 0.4)] * 3, [(0.6, 0.5)] * 3, "attributed to the reward offset"),  # behind: below +0.05
        ([(0.63, 0.7)] * 3, [(0.6, 0.5)] * 3, "attributed to the reward offset"),
        ([(0.7, 0.4)] * 3, [(0.6, 0.5)] * 3, "attributed to the reward offset"),
    ],
)
def test_headline_c2_outcomes(macb, constant, decision):
    analysis = load_script("headline_analysis")
    runs = lambda levels: [analysis.Run(i, 0.0, False, a, f) for i, (a, f) in enumerate(levels)]  # noqa: E731
    assert analysis.decide_c2(runs(macb), runs(constant))[0] == decision


def write_nav_run(folder: Path, any_step: list[float], collisions: float, complete: bool = True) -> None:
    """A 2-Agent Navigation run as reproduce.py files it: both success metrics and accumulated collisions."""
    write_headline_run(folder, any_step, any_step, complete)
    arrays = dict(np.load(folder / "evaluations.npz"))
    arrays["training_collisions"] = np.linspace(0, collisions, len(any_step))
    np.savez(folder / "evaluations.npz", **arrays)


def test_nav_analysis_applies_its_registered_rules(tmp_path):
    analysis = load_script("nav_analysis")
    task, n = tmp_path / "nav", 1000  # evaluations of 100 episodes each
    for seed in range(3):
        # MADDPG ends at 0.9 (target 0.81) and reaches it at evaluation ~700: episodes ~70,000
        write_nav_run(task / "maddpg" / f"seed_{seed}", [0.3] * 500 + [0.9] * 500, 2000 + 100 * seed)
        for variant in ("macb_joint", "macb_local", "macb_state"):  # at 1.0 from evaluation 100 + 10 * seed
            write_nav_run(task / variant / f"seed_{seed}", [0.0] * (100 + 10 * seed) + [1.0] * (900 - 10 * seed),
                          1000 + 100 * seed)  # fmt: skip
        write_nav_run(task / "macb_constant" / f"seed_{seed}", [0.9] * n, 1900 + 150 * seed, complete=seed < 2)
        write_nav_run(task / "ddpg" / f"seed_{seed}", [0.1] * n, 1500 + 100 * seed)
        write_nav_run(task / "ddpg_macb" / f"seed_{seed}", [0.1] * n, 1400 + 100 * seed)
    assert "N1, the paper's claim (target 0.810 any-step success): INTERIM" in analysis.analyse(str(task), 3)
    write_nav_run(task / "macb_constant" / "seed_2", [0.9] * n, 2200)
    report = analysis.analyse(str(task), 3)
    assert "- N1, macb_joint: **meets**" in report
    assert "N1, the paper's claim (target 0.810 any-step success): **confirmed**" in report
    # MACB 1.0 against the constant's 0.9 on both metrics, and every MACB seed above: credited
    assert "- N2, macb_state against macb_constant: **counting credited**" in report
    assert "- N3, macb_joint against maddpg (the paper: fewer): **macb_joint collides less**" in report
    assert "- N3, ddpg_macb against ddpg (the paper: fewer): **no difference detected**" in report  # 7% fewer
    assert "- N3, maddpg against ddpg (the paper: more): **maddpg collides more**" in report
    assert "- N3, macb_constant against maddpg (the offset alone): **no difference detected**" in report  # overlap
    # one MACB variant that never reaches the target refutes the claim for every variant together
    for seed in range(3):
        write_nav_run(task / "macb_local" / f"seed_{seed}", [0.5] * n, 1000)
    report = analysis.analyse(str(task), 3)
    assert "- N1, macb_local: **fails**" in report
    assert "the paper's claim (target 0.810 any-step success): **refuted**" in report
    # MADDPG that learns little: the target is the floor, 0.2
    for seed in range(3):
        write_nav_run(task / "maddpg" / f"seed_{seed}", [0.05] * n, 2000)
    assert "target 0.200 any-step success" in analysis.analyse(str(task), 3)
    runs = lambda values: [analysis.NavRun(i, {}, 0.0, 0.0, c) for i, c in enumerate(values)]  # noqa: E731
    assert analysis.decide_n3(runs([70, 75, 80]), runs([100, 110, 120])) == "less"
    assert analysis.decide_n3(runs([70, 75, 101]), runs([100, 110, 120])) == "no difference detected"
    assert analysis.decide_n3(runs([85, 85, 85]), runs([100, 100, 100])) == "no difference detected"  # 15% only
    assert analysis.decide_n3(runs([100, 110, 120]), runs([70, 75, 80])) == "more"


def test_fig4_analysis_applies_its_registered_rules(tmp_path):
    analysis = load_script("fig4_analysis")
    sparse, distance, n = tmp_path / "CommunicativeNavigation-sparse-x", tmp_path / "CommunicativeNavigation-distance-x", 1000
    for seed in range(3):
        write_headline_run(sparse / "maddpg" / f"seed_{seed}", [0.4] * n, [0.3] * n)
        write_headline_run(sparse / "macb_local" / f"seed_{seed}", [0.7 + 0.01 * seed] * n, [0.6] * n)
        write_headline_run(sparse / "macb_joint" / f"seed_{seed}", [0.72] * n, [0.6] * n, complete=seed < 2)
        write_headline_run(sparse / "macb_constant" / f"seed_{seed}", [0.6] * n, [0.5] * n)
        # distance: MADDPG at 0.8 (target 0.72) from evaluation 400 (reached at ~episode 50,000); MACB from 100-120
        write_headline_run(distance / "maddpg" / f"seed_{seed}", [0.0] * 400 + [0.8] * 600, [0.5] * n)
        write_headline_run(distance / "macb_joint" / f"seed_{seed}", [0.0] * (100 + 10 * seed) + [0.8] * (900 - 10 * seed),
                           [0.5] * n)  # fmt: skip
        write_headline_run(distance / "macb_constant" / f"seed_{seed}", [0.0] * 600 + [0.8] * 400, [0.5] * n)
    report = analysis.analyse(str(sparse), 3)
    assert "- F1, macb_local against maddpg: INTERIM (fewer complete seeds than registered): **confirmed**" in report
    write_headline_run(sparse / "macb_joint" / "seed_2", [0.72] * n, [0.6] * n)
    report = analysis.analyse(str(sparse), 3)
    assert "- F1, macb_local against maddpg: **confirmed** (macb_local ahead)" in report
    assert "- F2, macb_joint against macb_local: **not detected** (macb_joint no difference detected)" in report
    assert "- F3, macb_local against macb_constant: **counting credited**" in report  # +0.11 and +0.1, every seed above
    assert "F4" not in report
    report = analysis.analyse(str(distance), 3)
    assert "- F4, macb_joint against maddpg: **confirmed** (faster)" in report
    assert "- F4, final levels: macb_joint **no difference detected**" in report
    assert "- F5, macb_joint against macb_constant: **attributed to the reward offset**" in report
    assert "- F5, macb_constant against maddpg: **slower**" in report  # 80,000 against MADDPG's ~59,900 / 0.75
    # the mirror of "ahead" and a worst seed at the other's mean
    runs = lambda levels: [analysis.NavRun(i, {}, a, a, 0.0) for i, a in enumerate(levels)]  # noqa: E731
    assert analysis.decide_level(runs([0.3, 0.3, 0.3]), runs([0.5, 0.5, 0.5]))[0] == "behind"
    assert analysis.decide_level(runs([0.6, 0.6, 0.5]), runs([0.5, 0.5, 0.5]))[0] == "no difference detected"


def test_table1_analysis_applies_its_registered_rules(tmp_path):
    analysis = load_script("table1_analysis")
    grid, base, n = tmp_path / "table1", tmp_path / "base", 300

    def write(folder: Path, level: float, count1: float) -> None:
        write_headline_run(folder, [level] * n, [level - 0.1] * n)
        arrays = dict(np.load(folder / "evaluations.npz"))
        arrays["count1_fraction"] = np.full(n, count1)
        np.savez(folder / "evaluations.npz", **arrays)

    counts = {32: 0.8, 64: 0.95, 256: 0.999, 512: 0.9999}
    for seed in range(4):  # seed 3 is not registered: left out
        for beta in analysis.BETAS:
            for k in analysis.KS:
                level = 0.5 if k == 32 else 0.6
                if (beta, k) == (0.8, 512):
                    write(base / "macb_joint" / f"seed_{seed}", level, counts[k])
                elif (beta, k) == (0.8, 32):
                    write(base / "macb_k32" / f"seed_{seed}", level, counts[k])
                elif seed < 3 and not (beta == 0.05 and k == 64 and seed == 2):
                    write(grid / f"macb_joint+exploration.beta={beta}+exploration.k={k}" / f"seed_{seed}", level, counts[k])
        write(base / "maddpg" / f"seed_{seed}", 0.5 if seed < 3 else 0.0, 0.0)
        write(base / "macb_constant" / f"seed_{seed}", 0.5, 0.0)
    report = analysis.analyse(str(grid), str(base), 3)
    assert "- Short of 3 complete seeds: beta 0.05, k 64." in report and "INTERIM" in report
    figure = load_script("table1_figure")  # the figure refuses a grid short of the seeds, as the analysis flags it
    with pytest.raises(SystemExit, match="short of 3 complete seeds: beta 0.05, k 64"):
        figure.write_csv(str(grid), str(base), 3, str(tmp_path / "t1.csv"))
    write(grid / "macb_joint+exploration.beta=0.05+exploration.k=64" / "seed_2", 0.6, counts[64])
    report = analysis.analyse(str(grid), str(base), 3)
    assert "INTERIM" not in report
    assert figure.write_csv(str(grid), str(base), 3, str(tmp_path / "t1.csv")) == "MADDPG 0.50, constant bonus 0.50"
    assert len((tmp_path / "t1.csv").read_text().splitlines()) == 1 + 16 * 3  # seed 3 left out
    table = plot_table(str(tmp_path / "t1.csv"), str(tmp_path / "t1"))
    assert "| 32 | 0.50, 80% (n=3) | 0.50, 80% (n=3) | 0.50, 80% (n=3) | 0.50, 80% (n=3) |" in table
    assert "| 512 | 0.60, 100% (n=3) | 0.60, 100% (n=3) | 0.60, 100% (n=3) | 0.60, 100% (n=3) |" in table
    # 12 cells at 0.6 are above MADDPG's 0.5; the four k = 32 cells equal it
    assert "- K1, MACB above MADDPG in most cells: **confirmed**; 12 of 16 cells above MADDPG's 0.500, 0 below" in report
    assert "- K2, k = 512 row against k = 32 row: **confirmed**; row means 0.600 and 0.500" in report
    assert "- K3, count-1 rises with k and reaches 0.99 at k = 512: **confirmed**" in report
    assert "- K4, beta 0.8, k 512 against macb_constant: **counting credited**" in report
    assert "- K4, beta 0.8, k 32 against macb_constant: **attributed to the reward offset**" in report
    assert "| 512 |  | 0.600 (0.60, 0.60, 0.60), 100.0% |" in report
    write(base / "maddpg" / "seed_0", 0.8, 0.0)  # MADDPG at 0.6 on average: no cell above, none 0.05 below
    assert "**inconclusive**; 0 of 16 cells above MADDPG's 0.600, 0 below" in analysis.analyse(str(grid), str(base), 3)
    for seed in range(3):
        write(base / "maddpg" / f"seed_{seed}", 0.8, 0.0)
    assert "**refuted**; 0 of 16 cells above MADDPG's 0.800, 16 below" in analysis.analyse(str(grid), str(base), 3)
    write(grid / "macb_joint+exploration.beta=0.2+exploration.k=512" / "seed_0", 0.6, 0.95)
    assert "**not confirmed (beta 0.2)**" in analysis.analyse(str(grid), str(base), 3)


def test_complete_only_leaves_out_runs_in_progress(tmp_path):
    from sb3_macb.common import evaluations

    write_headline_run(tmp_path / "v" / "seed_0", [0.5] * 30, [0.4] * 30)
    write_headline_run(tmp_path / "v" / "seed_1", [0.5] * 10, [0.4] * 10, complete=False)
    assert [len(r["successes"]) for r in evaluations.load_group(str(tmp_path / "v"))] == [30, 10]
    assert [len(r["successes"]) for r in evaluations.load_group(str(tmp_path / "v"), complete_only=True)] == [30]
    (tmp_path / "v" / "seed_0" / "run.json").unlink()
    with pytest.raises(FileNotFoundError, match="No complete run below"):
        evaluations.load_group(str(tmp_path / "v"), complete_only=True)


def test_trajectories_milestones_collapse_share_and_identical_prefix(tmp_path):
    import argparse

    trajectories = load_script("trajectories")
    task = tmp_path / "task"
    n = 100  # evaluations after episodes 100, 200, ..., 10000
    joint = [0.0] * 20 + [1.0] * 40 + [0.0] * 40
    write_headline_run(task / "macb_joint" / "seed_0", joint, [0.5] * n, complete=False)
    write_headline_run(task / "macb_constant" / "seed_0", joint, [0.5] * n, complete=False)
    write_headline_run(task / "maddpg" / "seed_0", [0.4] * n, [0.3] * n)
    # the constant bonus's run departs from MACB's at evaluation 31 (episode 3100, step 62,000)
    path = task / "macb_constant" / "seed_0" / "evaluations.npz"
    arrays = dict(np.load(path))
    arrays["results"] = arrays["results"].copy()
    arrays["results"][30:] += 1.0
    np.savez(path, **arrays)
    args = argparse.Namespace(seeds=None, variants=None, window=10, threshold=0.9, every=2000, after=2000, floor=0.15,
                              pairs=["macb_joint:macb_constant", "maddpg:absent"])  # fmt: skip
    report = trajectories.report(str(task), args)
    rows = {line.split(" | ")[1]: line for line in report.splitlines() if line.startswith("| 0 |")}
    # trailing 10 at episodes 2000 (0 ones), 4000 and 6000 (all ones), 8000 and 10000 (none); 90% at episode 2900;
    # collapsed after 2000: evaluation 21 (trailing 0.1) and 69-100 (at most one 1.0 in the window) = 33 of 80
    assert rows["macb_joint"] == (
        "| 0 | macb_joint | 10,000 (no) | 2,900 | 0.00/0.50 | 1.00/0.50 | 1.00/0.50 | 0.00/0.50 | 0.00/0.50 | 41% |"
    )
    assert rows["maddpg"].startswith("| 0 | maddpg | 10,000 (yes) | not by 10,000 | 0.40/0.30 |")
    assert rows["maddpg"].endswith("| 0% |")
    assert "- seed 0: macb_joint and macb_constant identical up to step 60,000." in report
    assert "absent" not in report
    # runs identical over everything recorded say so
    np.savez(path, **{**arrays, "results": np.zeros_like(arrays["results"])})
    assert "identical up to step 200,000 (everything recorded so far)" in trajectories.report(str(task), args)


def test_trajectories_twins_compare_runs_of_one_variant_and_seed_in_two_folders(tmp_path):
    import argparse

    trajectories = load_script("trajectories")
    short, long = tmp_path / "short", tmp_path / "long"
    n = 300
    write_headline_run(short / "maddpg" / "seed_0", [0.4] * n, [0.3] * n)
    write_headline_run(long / "maddpg" / "seed_0", [0.4] * 100 + [1.0] * 200, [0.3] * 100 + [0.9] * 200, complete=False)
    write_headline_run(short / "macb_joint" / "seed_1", [0.1] * n, [0.0] * n)  # filed in one folder only
    write_headline_run(long / "macb_joint" / "seed_2", [0.1] * n, [0.0] * n)
    # the long-buffer run's returns depart at evaluation 101 (step 202,000)
    path = long / "maddpg" / "seed_0" / "evaluations.npz"
    arrays = dict(np.load(path))
    arrays["results"] = arrays["results"].copy()
    arrays["results"][100:] += 1.0
    np.savez(path, **arrays)
    args = argparse.Namespace(seeds=None, variants=None, final=200)
    report = trajectories.twins_report(str(short), str(long), args)
    assert "| maddpg seed 0 | 200,000 | 0.400 / 0.300 | 1.000 / 0.900 (incomplete) |" in report
    assert "macb_joint" not in report
    with pytest.raises(SystemExit, match="No run"):
        trajectories.twins_report(str(short), str(long), argparse.Namespace(seeds=[1], variants=None, final=200))


def test_collapse_diagnostics_measures_saturation_and_value_bounds(tmp_path):
    import json

    import torch as th

    from sb3_macb import MACB, MADDPG
    from sb3_macb.envs.vec_tasks import make_task_vec_env

    diagnostics = load_script("collapse_diagnostics")
    model = MADDPG("MlpPolicy", make_task_vec_env(diagnostics.ENV_ID, 2), n_runs=2, run_seeds=[0, 1],
                   exploration=[None, MACB(0.8, counts=False)], policy_kwargs=dict(net_arch=[16]))  # fmt: skip
    experiment = tmp_path / "experiment.json"
    runs = [{"variants": ["maddpg"], "hyperparams": {"exploration": None}},
            {"variants": ["macb_constant"], "hyperparams": {"exploration": {"beta": 0.8, "counts": False}}}]  # fmt: skip
    experiment.write_text(json.dumps({"config": {"runs": runs}}))
    assert diagnostics.run_labels(str(experiment), model) == [("maddpg", 0.0, False), ("macb_constant", 0.8, True)]
    # without the experiment file the bonus still comes from the model (a filed run's model.zip has none beside it)
    assert diagnostics.run_labels(None, model) == [("run 0", 0.0, False), ("run 1", 0.8, True)]
    experiment.write_text(json.dumps({"config": {"runs": runs + runs[:1]}}))
    with pytest.raises(SystemExit, match="not this pack's experiment"):
        diagnostics.run_labels(str(experiment), model)

    fresh = diagnostics.diagnose(model, 1, 0.8, True, episodes=6, seed=0)
    assert fresh["Q range"] == pytest.approx((-20.0, 80.0))  # (0.8 - 1) / 0.01 and 0.8 / 0.01
    assert diagnostics.diagnose(model, 0, 0.0, False, episodes=6, seed=0)["Q range"] == pytest.approx((-100.0, 0.0))
    assert 0.0 <= fresh["final"] <= fresh["any"] <= 1.0
    assert fresh["sat lis"] < 0.5 and fresh["pre lis"] < 3.0 and fresh["pre spk"] < 3.0  # a fresh actor is not saturated
    with th.no_grad():
        for parameter in model.actor.parameters():
            parameter.mul_(50.0)
    saturated = diagnostics.diagnose(model, 1, 0.8, True, episodes=6, seed=0)
    assert saturated["sat lis"] > 0.9 and saturated["sat spk"] > 0.9 and saturated["pre lis"] > 10.0


def test_collapse_diagnostics_measures_two_agent_navigation_with_its_reward_range():
    import torch as th

    from sb3_macb import MACB, MADDPG
    from sb3_macb.envs.vec_tasks import make_task_vec_env

    diagnostics = load_script("collapse_diagnostics")
    env_id, _ = diagnostics.TASKS["nav"]
    model = MADDPG("MlpPolicy", make_task_vec_env(env_id, 2), n_runs=2, run_seeds=[0, 1],
                   exploration=[None, MACB(0.8, counts=False)], policy_kwargs=dict(net_arch=[16]))  # fmt: skip
    fresh = diagnostics.diagnose(model, 1, 0.8, True, episodes=6, seed=0, task="nav")
    # the sparse reward lies in [-1.5, 0]: (-1.5 + 0.8) / 0.01 and 0.8 / 0.01 with the constant bonus, -1.5 / 0.01 without
    assert fresh["Q range"] == pytest.approx((-70.0, 80.0))
    plain = diagnostics.diagnose(model, 0, 0.0, False, episodes=6, seed=0, task="nav")
    assert plain["Q range"] == pytest.approx((-150.0, 0.0))
    assert 0.0 <= fresh["final"] <= fresh["any"] <= 1.0
    assert {"sat agent_0", "sat agent_1", "pre agent_0", "pre agent_1", "Q agent_0", "Q agent_1"} <= set(fresh)
    assert fresh["sat agent_0"] < 0.5 and fresh["pre agent_1"] < 3.0  # a fresh actor is not saturated
    with th.no_grad():
        for parameter in model.actor.parameters():
            parameter.mul_(50.0)
    saturated = diagnostics.diagnose(model, 1, 0.8, True, episodes=6, seed=0, task="nav")
    assert saturated["sat agent_0"] > 0.9 and saturated["sat agent_1"] > 0.9 and saturated["pre agent_0"] > 10.0


def test_collapse_diagnostics_per_goal_splits_the_same_episodes_by_goal():
    from sb3_macb import MADDPG
    from sb3_macb.envs.vec_tasks import make_task_vec_env

    diagnostics = load_script("collapse_diagnostics")
    assert diagnostics.display_name("results/x/macb_joint/seed_1/model.zip") == "macb_joint/seed_1"
    assert diagnostics.display_name("logs/archive/seed_1/step_100000.zip") == "step_100000.zip"
    assert diagnostics.display_name("logs/x/checkpoint/step_300000/") == "step_300000"
    model = MADDPG("MlpPolicy", make_task_vec_env(diagnostics.ENV_ID, 2), n_runs=2, run_seeds=[0, 1], learning_starts=40,
                   batch_size=8, policy_kwargs=dict(net_arch=[16]))  # fmt: skip
    model.learn(2 * 200)
    for k in (0, 1):
        rows = diagnostics.per_goal(model, k, episodes=60, seed=5)
        whole = diagnostics.diagnose(model, k, 0.0, False, episodes=60, seed=5)  # the same 60 episodes
        assert [row["goal"] for row in rows] == [0, 1, 2] and sum(row["episodes"] for row in rows) == 60
        # the landmark the listener ends at (from the last observation) agrees with the env's own success flags
        assert sum(row["final"] * row["episodes"] for row in rows) / 60 == pytest.approx(whole["final"])
        assert sum(row["any"] * row["episodes"] for row in rows) / 60 == pytest.approx(whole["any"])
        for row in rows:
            assert sum(row["ends"]) == pytest.approx(1.0) and row["ends"][row["goal"]] == pytest.approx(row["final"])
            assert row["message sd"] < 1e-6  # the speaker sees only the goal's colour: one message per goal
            assert np.all((row["message"] >= 0) & (row["message"] <= 1))  # messages are in [0, 1]

    # a scripted pair whose listener goes to landmark 0 when the goal is 2 (as a speaker that conflates them would)
    import types

    import torch as th

    from reference_policies import GoalListener

    class Conflating(GoalListener):
        def _choose(self, obs, starting):
            super()._choose(obs, starting)
            self.targets = np.where(self.targets == 2, 0, self.targets)

    listener = Conflating()
    scripted = types.SimpleNamespace(agent_layout=model.agent_layout, policy=types.SimpleNamespace(unscale_action=lambda a: a),
                                     actor=lambda obs: th.as_tensor(listener.predict(obs.numpy())[0]),
                                     device=th.device("cpu"))  # fmt: skip
    model.get_run = lambda k: scripted
    rows = diagnostics.per_goal(model, 0, episodes=90, seed=6)
    assert rows[0]["final"] > 0.9 and rows[1]["final"] > 0.9 and rows[2]["final"] == 0.0
    assert rows[2]["ends"][0] > 0.9 and rows[0]["ends"][0] == rows[0]["final"] and rows[1]["ends"][1] == rows[1]["final"]


def test_collapse_diagnostics_continues_a_checkpoint_from_its_exact_state(tmp_path):
    import pickle
    import random

    import torch as th

    from sb3_macb import MACB, MADDPG
    from sb3_macb.common.snapshot import snapshot
    from sb3_macb.envs.vec_tasks import make_task_vec_env

    diagnostics = load_script("collapse_diagnostics")
    model = MADDPG("MlpPolicy", make_task_vec_env(diagnostics.ENV_ID, 2), n_runs=2, run_seeds=[0, 1], learning_starts=40,
                   batch_size=8, exploration=[None, MACB(0.8, counts=False)], policy_kwargs=dict(net_arch=[16]))  # fmt: skip
    model.learn(2 * 60)
    # a checkpoint as Experiment.save_checkpoint writes it
    model.save(tmp_path / "model.zip")
    np.savez(tmp_path / "buffer.npz", **model.replay_buffer.state_arrays())
    state = {"train_env": snapshot(model.env),
             "rng": {"numpy": np.random.get_state(), "python": random.getstate(), "torch": th.get_rng_state()}}  # fmt: skip
    (tmp_path / "state.pkl").write_bytes(pickle.dumps(state))

    first = diagnostics.continue_from_checkpoint(str(tmp_path), 30, 1e-3)
    again = diagnostics.continue_from_checkpoint(str(tmp_path), 30, 1e-3)
    plain = diagnostics.continue_from_checkpoint(str(tmp_path), 30, 0.0)
    assert first.num_timesteps == model.num_timesteps + 2 * 30 and first.preactivation_reg == 1e-3
    weights = lambda m: th.cat([p.detach().cpu().flatten() for p in m.actor.parameters()])  # noqa: E731
    assert th.equal(weights(first), weights(again))  # the same state and settings give the same continuation
    assert not th.equal(weights(first), weights(model)) and not th.equal(weights(first), weights(plain))


def test_collapse_diagnostics_on_buffer_measures_each_critic_against_its_own_target():
    import torch as th

    from sb3_macb import MACB, MADDPG
    from sb3_macb.envs.vec_tasks import make_task_vec_env

    diagnostics = load_script("collapse_diagnostics")
    model = MADDPG("MlpPolicy", make_task_vec_env(diagnostics.ENV_ID, 2), n_runs=2, run_seeds=[0, 1], learning_starts=40,
                   batch_size=8, exploration=[None, MACB(0.8, counts=False)], policy_kwargs=dict(net_arch=[16]))  # fmt: skip
    model.learn(2 * 100)
    buffer = model.replay_buffer
    assert list(diagnostics.buffer_rows(model)) == list(range(100))
    assert list(diagnostics.buffer_rows(model, 30)) == list(range(70, 100))
    trained = diagnostics.on_buffer(model, 1, diagnostics.buffer_rows(model), 500, seed=3)
    assert trained["|TD| spk"] >= abs(trained["TD spk"]) > 0 and trained["lis speed"] > 0 and trained["lis dist"] > 0
    with th.no_grad():  # critics that say 0 everywhere: each TD error is minus the reward the critic learns
        for parameter in [*model.critic.parameters(), *model.critic_target.parameters()]:
            parameter.zero_()
    candidates = diagnostics.buffer_rows(model, 50)
    rows = candidates[np.random.default_rng(3).integers(0, len(candidates), size=500)]
    for k, bonus in ((0, 0.0), (1, 0.8)):  # MADDPG's run gets no bonus, the constant-bonus run 0.8 on every transition
        d = diagnostics.on_buffer(model, k, candidates, 500, seed=3)
        rewards = buffer.agent_rewards[rows, k].astype(np.float64) + bonus
        assert d["Q spk"] == 0.0 and d["Q lis"] == 0.0
        assert d["TD spk"] == pytest.approx(-rewards[:, 0].mean(), abs=1e-5)
        assert d["TD lis"] == pytest.approx(-rewards[:, 1].mean(), abs=1e-5)
    # the gap: a target critic that is the sum of the listener's action components, a target policy that puts them at
    # +1: at s' the policy's action is worth 2 - (the listener's next stored action summed); an episode's last
    # transition (row 19 of the 20-step first episode) has no next action in its episode and is left out
    listener = model.agent_layout.action_slices[1]
    assert model.agent_layout.agents[1].startswith("listener") and buffer.dones[19, 1] == 1 and buffer.dones[:19, 1].sum() == 0
    model.critic_target = lambda obs, act: act[..., listener].sum(-1)[None, :, None, :].expand(1, 2, 2, -1)
    model.actor_target = lambda obs: th.ones((*obs.shape[:-1], 5), device=obs.device)
    first_episode = np.arange(20)
    rows = first_episode[np.random.default_rng(4).integers(0, 20, size=300)]
    rows = rows[rows < 19]
    expected = (2.0 - buffer.actions[rows + 1, 1, listener].sum(-1)).mean()
    d = diagnostics.on_buffer(model, 1, first_episode, 300, seed=4)
    assert d["continuing"] == pytest.approx(len(rows) / 300)
    for key in ("gap spk", "gap lis", "gap lis spk", "gap lis lis"):
        assert d[key] == pytest.approx(expected, abs=1e-5)
    # a buffer that has wrapped around: the newest rows are those just before the write position
    buffer.full, buffer.pos = True, 10
    assert list(diagnostics.buffer_rows(model, 3)) == [7, 8, 9] and len(diagnostics.buffer_rows(model)) == buffer.buffer_size


@pytest.mark.slow
def test_reproduce_files_combined_variants_and_refuses_to_pack_different_envs(tmp_path):
    import json

    import yaml

    def reproduce(*variants: str, pack: int, work: str = "work", out: str = "out", returncode: int = 0) -> str:
        command = [sys.executable, "scripts/reproduce.py", "--task", "comm-sparse", "--variants", *variants, "--seeds", "0",
                   "--fast", "--pack", str(pack), "-n", "60", "--checkpoint-freq", "40", "--work", str(tmp_path / work),
                   "-o", str(tmp_path / out)]  # fmt: skip
        done = subprocess.run(command, capture_output=True, text=True, timeout=300, cwd=STUDY)
        assert done.returncode == returncode, done.stderr
        return done.stdout + done.stderr

    out = reproduce("maddpg,refcode", pack=1)
    assert "done" in out and "ERROR" not in out
    run = tmp_path / "out" / "CommunicativeNavigation-sparse" / "maddpg+refcode" / "seed_0"
    config = yaml.safe_load((run / "config.yml").read_text())
    assert config["variants"] == ["maddpg", "refcode", "fast"] and config["exploration"] is None
    assert config["replay_buffer_kwargs"] == "dict(handle_timeout_termination=False)"
    assert (run / "evaluations.npz").exists()
    pack = tmp_path / "work" / "CommunicativeNavigation-sparse" / "maddpg+refcode_seeds0"
    experiment = json.loads((pack / "experiment.json").read_text())
    assert experiment["config"]["env_kwargs"] == {"reward": "sparse", "terminate_on_success": True}
    # the two cannot share a pack's env: a clear error for that pack, nothing run
    out = reproduce("maddpg", "maddpg,refcode", pack=2, work="work2", out="out2", returncode=1)
    assert "share one env, but their env_kwargs differ" in out and "1 of 1 packs failed" in out
    assert not (tmp_path / "out2" / "CommunicativeNavigation-sparse" / "maddpg" / "seed_0").exists()


def test_reproduce_grid_files_one_run_per_point_and_checks_every_setting_first(tmp_path):
    import json

    import yaml

    from sb3_macb.zoo.experiment import make_run

    reproduce = load_script("reproduce")
    grid = reproduce.expand_grid(["macb_joint", "maddpg,refcode"], ["exploration.beta=0.05,0.8", "exploration.k=32"])
    assert grid == ["macb_joint,exploration.beta=0.05,exploration.k=32", "macb_joint,exploration.beta=0.8,exploration.k=32",
                    "maddpg,refcode,exploration.beta=0.05,exploration.k=32",
                    "maddpg,refcode,exploration.beta=0.8,exploration.k=32"]  # fmt: skip
    assert reproduce.expand_grid(["a"], []) == ["a"]
    assert reproduce.split_variant(grid[2]) == (["maddpg", "refcode"], {"exploration.beta": 0.05, "exploration.k": 32})
    # a point that repeats a variant's own settings is that variant's run (Table 1's beta 0.8, k 512 cell)
    env_id = "sb3_macb/CommunicativeNavigation-v0"
    same = make_run(env_id, 0, "f", ["macb_joint"], reproduce.split_variant("x,exploration.beta=0.8,exploration.k=512")[1])
    assert same[0].hyperparams == make_run(env_id, 0, "f", ["macb_joint"])[0].hyperparams

    def reproduce_cli(*extra: str) -> subprocess.CompletedProcess:
        command = [sys.executable, "scripts/reproduce.py", "--task", "comm-sparse", "--seeds", "0", "--fast", "-n", "60",
                   "--checkpoint-freq", "40", "--work", str(tmp_path / "work"), "-o", str(tmp_path / "out"),
                   *extra]  # fmt: skip
        return subprocess.run(command, capture_output=True, text=True, timeout=300, cwd=STUDY)

    # bad settings: one line naming the run and what is allowed, before anything is created
    for extra, message in [
        (["--variants", "macb_joint", "--grid", "exploration.k=32,-1"], "k (the hash code length) must be an integer >= 1"),
        (["--variants", "macb_joint", "--grid", "exploration.bta=1"], "Unknown MACB option(s) ['bta']"),
        (["--variants", "macb_joint", "--grid", "exploration.k=32,,64"], "give KEY=VALUE[,VALUE...]"),
        (["--variants", "macb_joint,bogus=1"], "Unknown hyperparameter(s)"),
        (["--variants", "macb_joint,exploration.k=[1"], "the value of 'exploration.k' is not valid YAML"),
    ]:
        done = reproduce_cli(*extra)
        assert done.returncode == 2 and message in done.stderr and len(done.stderr.strip().splitlines()) == 1, done.stderr
        assert not (tmp_path / "out").exists() and not (tmp_path / "work").exists()
    done = reproduce_cli("--variants", "macb_joint", "--grid", "exploration.beta=0.05", "--grid", "exploration.k=32,64")
    assert done.returncode == 0, done.stderr
    task = tmp_path / "out" / "CommunicativeNavigation-sparse"
    assert sorted(os.listdir(task)) == ["macb_joint+exploration.beta=0.05+exploration.k=32",
                                        "macb_joint+exploration.beta=0.05+exploration.k=64"]  # fmt: skip
    for k in (32, 64):
        run = task / f"macb_joint+exploration.beta=0.05+exploration.k={k}" / "seed_0"
        config = yaml.safe_load((run / "config.yml").read_text())
        assert config["exploration"] == {"beta": 0.05, "k": k, "scope": "joint"} and config["variants"] == [
            "macb_joint",
            "fast",
        ]
        assert json.loads((run / "run.json").read_text())["complete"] is True
    assert "already complete" in reproduce_cli("--variants", "macb_joint,exploration.beta=0.05,exploration.k=64").stdout
    # a pack of a grid's runs has a work folder name that fits a file system's 255 bytes, one per set of runs
    import argparse

    args = argparse.Namespace(task="comm-sparse", suffix="", work="w", out=str(tmp_path / "plan"), seeds=[0],
                              pack=8, mix_seeds=False, variants=reproduce.expand_grid(
                                  ["macb_joint"], ["exploration.beta=0.05,0.2", "exploration.k=32,64,256,512"]))  # fmt: skip
    (work, jobs), = reproduce.plan(args)
    name = os.path.basename(work)
    assert (
        len(jobs) == 8 and len(name) < 255 and name.startswith("macb_joint+exploration.beta=0.05+exploration.k=32-and-7-more-")
    )
    args.variants = args.variants[:7]
    assert os.path.basename(reproduce.plan(args)[0][0]) != name


@pytest.mark.slow
def test_reproduce_mix_seeds_fills_packs_across_seeds_with_the_same_runs(tmp_path):
    import argparse
    import json

    reproduce = load_script("reproduce")
    args = argparse.Namespace(task="comm-sparse", suffix="x", work="w", out=str(tmp_path / "plan"), seeds=[0, 1, 2],
                              variants=["a", "b,c"], pack=4, mix_seeds=True)  # fmt: skip
    packs = reproduce.plan(args)
    assert [jobs for _, jobs in packs] == [[("a", 0), ("b,c", 0), ("a", 1), ("b,c", 1)], [("a", 2), ("b,c", 2)]]
    assert [os.path.basename(work) for work, _ in packs] == ["a-b+c_seeds0-1", "a-b+c_seeds2"]
    args.mix_seeds = False  # the default: one seed per pack
    by_seed = [[("a", 0), ("b,c", 0)], [("a", 1), ("b,c", 1)], [("a", 2), ("b,c", 2)]]
    assert [jobs for _, jobs in reproduce.plan(args)] == by_seed
    # runs complete under -o are left out (a partial run is not); the packs of what is left are named by their runs
    for variant, seed, done in [("a", 1, True), ("b+c", 2, True), ("a", 2, False)]:
        folder = tmp_path / "plan" / "CommunicativeNavigation-sparse-x" / variant / f"seed_{seed}"
        folder.mkdir(parents=True)
        (folder / "run.json").write_text(json.dumps({"complete": done}))
    packs = reproduce.plan(args)
    assert [jobs for _, jobs in packs] == [[("a", 0), ("b,c", 0)], [("b,c", 1)], [("a", 2)]]
    assert [os.path.basename(work) for work, _ in packs] == ["a-b+c_seeds0", "b+c_seeds1", "a_seeds2"]
    args.pack = 1  # one-run packs of different variants never share a work folder
    assert len({work for work, _ in reproduce.plan(args)}) == 4

    def run(seeds: list[str], out: str, *extra: str) -> Path:
        command = [sys.executable, "scripts/reproduce.py", "--task", "comm-sparse", "--variants", "maddpg", "--seeds", *seeds,
                   "--fast", "-n", "300", "--checkpoint-freq", "200", "--work", str(tmp_path / out / "work"),
                   "-o", str(tmp_path / out), *extra]  # fmt: skip
        done = subprocess.run(command, capture_output=True, text=True, timeout=300, cwd=STUDY)
        assert done.returncode == 0, done.stderr
        run.stdout = done.stdout
        return tmp_path / out / "CommunicativeNavigation-sparse" / "maddpg"

    mixed = run(["0", "1"], "mixed", "--mix-seeds", "--pack", "2")
    assert (tmp_path / "mixed" / "work" / "CommunicativeNavigation-sparse" / "maddpg_seeds0-1").is_dir()
    alone = run(["1"], "alone")
    a, b = np.load(mixed / "seed_1" / "evaluations.npz"), np.load(alone / "seed_1" / "evaluations.npz")
    assert len(a["results"]) > 0 and np.array_equal(a["results"], b["results"])
    # the same command with the checkpoints gone (another machine): the complete run is neither trained nor rewritten
    shutil.rmtree(tmp_path / "alone" / "work")
    stamp = (alone / "seed_1" / "evaluations.npz").stat().st_mtime_ns
    run(["1"], "alone")
    assert "already complete, left out" in run.stdout and "every run is complete" in run.stdout
    assert (alone / "seed_1" / "evaluations.npz").stat().st_mtime_ns == stamp and not (tmp_path / "alone" / "work").exists()
    assert not np.array_equal(a["results"], np.load(mixed / "seed_0" / "evaluations.npz")["results"])


def test_refcode_analysis_applies_its_registered_rules(tmp_path):
    analysis = load_script("refcode_analysis")
    n = 1000
    plain, refcode = tmp_path / "plain", tmp_path / "refcode"
    for seed, level in enumerate([0.3, 0.4, 0.3, 0.9, 0.9]):  # seeds 3 and 4 are not among the refcode seeds
        write_headline_run(plain / "maddpg" / f"seed_{seed}", [level] * n, [level] * n)
    for seed in range(3):
        write_headline_run(refcode / "maddpg+refcode" / f"seed_{seed}", [0.6] * n, [0.6] * n)
        write_headline_run(refcode / "macb_constant+refcode" / f"seed_{seed}", [1.0] * n, [1.0] * n, complete=seed < 2)
    assert "R2, the offset under that handling (macb_constant+refcode against maddpg+refcode): INTERIM" in \
        analysis.analyse(str(refcode), str(plain), 3)  # fmt: skip
    write_headline_run(refcode / "macb_constant+refcode" / "seed_2", [1.0] * n, [1.0] * n)
    report = analysis.analyse(str(refcode), str(plain), 3)
    assert "| maddpg (plain, plain) | 0, 1, 2 | 0.333 (0.300, 0.400, 0.300) | 0 of 3 |" in report
    assert "**change**" in report and "**helps**" in report and "**reproduced through the offset**" in report
    # MADDPG reaching 90% once is enough to say the paper's picture is not reproduced
    write_headline_run(refcode / "maddpg+refcode" / "seed_1", [0.9] * n, [0.9] * n)
    report = analysis.analyse(str(refcode), str(plain), 3)
    assert "**not reproduced**" in report and "**helps**" in report  # 1.0 against a mean of 0.7

    runs = lambda levels: [analysis.Run(i, 0.0, False, a, a) for i, a in enumerate(levels)]  # noqa: E731
    assert analysis.decide_r1(runs([0.40, 0.45, 0.50]), runs([0.38, 0.41, 0.38])) == "no change detected"  # overlap
    assert analysis.decide_r1(runs([0.42, 0.45, 0.50]), runs([0.38, 0.41, 0.38])) == "change"
    assert analysis.decide_r1(runs([0.42, 0.42, 0.42]), runs([0.38, 0.41, 0.38])) == "no change detected"  # < 0.05
    assert analysis.decide_r2(runs([0.1, 0.2, 0.3]), runs([0.6, 0.6, 0.6])) == "hurts"
    assert analysis.decide_r2(runs([0.1, 0.2, 0.7]), runs([0.6, 0.6, 0.6])) == "no effect detected"
    assert analysis.decide_r2(runs([0.7, 0.7, 0.5]), runs([0.6, 0.6, 0.6])) == "no effect detected"

    # the same rules for the timeout_terminal handling: its own variant names
    handled = tmp_path / "timeout"
    for seed in range(3):
        write_headline_run(handled / "maddpg+timeout_terminal" / f"seed_{seed}", [0.3] * n, [0.2] * n)
        write_headline_run(handled / "macb_constant+timeout_terminal" / f"seed_{seed}", [0.3] * n, [0.2] * n)
    report = analysis.analyse(str(handled), str(plain), 3, handling="timeout_terminal")
    assert "R1, the handling alone (maddpg+timeout_terminal against plain maddpg): **no change detected**" in report
    assert "**no effect detected**" in report and "**not reproduced**" in report
    assert "Not enough complete runs" in analysis.analyse(str(refcode), str(plain), 3, handling="timeout_terminal")


def test_reproduce_trains_with_the_library_of_its_own_checkout(tmp_path):
    """A worktree's reproduce.py imports that worktree's sb3_macb, not the one the environment has installed."""
    checkout = tmp_path / "worktree"
    scripts = checkout / "experiments" / "macb_paper" / "scripts"
    scripts.mkdir(parents=True)
    (checkout / "sb3_macb").mkdir()
    shutil.copy(STUDY / "scripts" / "reproduce.py", scripts)
    (checkout / "sb3_macb" / "__init__.py").write_text("raise SystemExit('the worktree library was imported')\n")
    command = [sys.executable, str(scripts / "reproduce.py"), "--task", "comm-sparse", "--variants", "maddpg",
               "--work", str(tmp_path / "work"), "-o", str(tmp_path / "out")]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert done.returncode == 1 and "the worktree library was imported" in done.stderr, done.stderr
    assert not (tmp_path / "work").exists() and not (tmp_path / "out").exists()


def test_summarize_refuses_a_window_below_one_in_one_line(tmp_path):
    write_run(tmp_path / "v" / "seed_0" / "evaluations.npz", [0.1] * 6)
    command = [sys.executable, str(STUDY / "scripts" / "summarize_results.py"), str(tmp_path), "--window", "0"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=120, cwd=STUDY)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines()[-1].endswith("--window must be >= 1 (evaluations), got 0")


def test_bf16_check_cuts_the_runs_and_applies_its_registered_rules(tmp_path):
    check = load_script("bf16_check")
    n, cut = 600, 500  # one evaluation per training episode; the check reads episodes 1-500, window 200

    def group(name: str, rates_by_seed: list[list[float]]) -> str:
        for seed, rates in enumerate(rates_by_seed):
            write_run(tmp_path / name / f"seed_{seed}" / "evaluations.npz", rates)
        return str(tmp_path / name)

    # float32 reaches 90% at episode 280 (100 evaluations at 0, then 1.0: 180 of 200 at 1.0) and holds L = 1.0
    full = group("fp32", [[0.0] * 100 + [1.0] * (n - 100)] * 3)
    # episodes after the cut do not count: a collapse at 501 changes nothing
    same = group("same", [[0.0] * 100 + [1.0] * (cut - 100) + [0.0] * (n - cut)] * 3)
    report = check.report(same, full, [], cut)
    assert "**matches**" in report and "median E 280 against 280" in report
    # later by 150 episodes: 430 > 1.25 * 280 = 350, worse though L at the cut is the same
    late = group("late", [[0.0] * 250 + [1.0] * (n - 250)] * 3)
    assert "**worse**" in check.report(late, full, [], cut)
    # L 0.9 against 1.0 (more than 0.05 below), reaching 90% as early
    low = group("low", [[0.0] * 100 + [0.9] * (n - 100)] * 3)
    assert check.decide(check.read_group(low, cut), check.read_group(full, cut))[0] == "worse"
    # float32 not learnt by the cut: nothing to decide
    unlearnt = group("unlearnt", [[0.3] * n] * 3)
    assert check.decide(check.read_group(same, cut), check.read_group(unlearnt, cut))[0] == "uninformative"
    # runs that never reach 90% count at the cut ("+" in the table)
    assert "500+" in check.report(unlearnt, full, [same], cut)
    # a run short of the cut is refused with one line where it is decided on, and left out where only reported
    short = group("short", [[1.0] * (cut - 1)])
    with pytest.raises(SystemExit, match="499 training episodes, the check needs 500"):
        check.read_group(short, cut)
    mixed = group("mixed", [[1.0] * n, [1.0] * (cut - 1)])
    assert f"reported only (runs past episode {cut}): {mixed} | 0 | 1.000" in check.report(same, full, [mixed], cut)
    check.plot({"bf16": same, "float32": full, "mixed": mixed}, str(tmp_path / "curves.png"), cut)
    assert (tmp_path / "curves.png").stat().st_size > 0

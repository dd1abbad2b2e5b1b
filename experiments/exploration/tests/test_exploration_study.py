import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

STUDY = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(STUDY / "scripts"))

import run_study  # noqa: E402
from sb3_macb.zoo.experiment import load_hyperparams  # noqa: E402
from study_tasks import BUDGET, CANDIDATES, EPISODE_STEPS  # noqa: E402


def study(*args, cwd=STUDY):
    return subprocess.run([sys.executable, str(STUDY / "scripts" / "run_study.py"), *args], cwd=cwd,
                          capture_output=True, text=True, timeout=600)  # fmt: skip


def test_every_method_builds_for_every_task_and_differs_from_maddpg_only_as_registered():
    assert set(CANDIDATES) == set(BUDGET) == set(EPISODE_STEPS)
    base = load_hyperparams(CANDIDATES["spread3"][0], str(STUDY / "study.yml"), ["maddpg"])
    assert base["policy_kwargs"] == "dict(net_arch=[64, 64])" and base["exploration"] is None
    for method in run_study.METHODS:
        for env_id, _ in CANDIDATES.values():
            hyperparams = load_hyperparams(env_id, str(STUDY / "study.yml"), [method], {"exploration.k": 16})
            changed = {key for key in base if hyperparams.get(key) != base[key]} | (set(hyperparams) - set(base))
            assert changed <= {"exploration", "intrinsic_critic"}, (method, changed)
    assert len(set(run_study.METHOD_TAGS.values())) == len(run_study.METHODS)


def test_a_pilot_files_its_runs_with_count1_levels_and_a_rerun_leaves_them(tmp_path):
    out, work = tmp_path / "results", tmp_path / "work"
    common = ["--task", "nav-success", "--seeds", "0", "1", "--pack-by", "method", "-n", "240",
              "--checkpoint-freq", "100", "-o", str(out), "--work", str(work)]  # fmt: skip
    done = study("--methods", "maddpg", "macb_k_center_int", "--k", "8", "--pilot", *common)
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in (work / "nav-success").iterdir()) == ["kci_seeds0-1", "m_seeds0-1"]  # a pack each
    for method, seed in [(m, s) for m in ("maddpg", "macb_k_center_int") for s in (0, 1)]:
        run = out / "nav-success" / method / f"seed_{seed}"
        assert json.loads((run / "run.json").read_text())["complete"]
        assert yaml.safe_load((run / "config.yml").read_text())["env_kwargs"] == {"reward": "success"}
        levels = json.loads((run / "count1.json").read_text())
        assert levels["transitions"] == 240
        fractions = [levels["count1_fraction"][str(k)] for k in run_study.PROBE_KS]
        assert all(0 < f <= 1 for f in fractions) and fractions[-1] > fractions[0]  # longer codes repeat less
        evaluations = np.load(run / "evaluations.npz")
        assert len(evaluations["timesteps"]) == 240 // EPISODE_STEPS["nav-success"]
        assert json.loads((run / "run.json").read_text())["pack_size"] == 2
    seeds = [json.loads((out / "nav-success" / "maddpg" / f"seed_{s}" / "count1.json").read_text()) for s in (0, 1)]
    assert seeds[0] != seeds[1]  # each run's own transitions
    k = yaml.safe_load((out / "nav-success" / "macb_k_center_int" / "seed_0" / "config.yml").read_text())
    assert k["exploration"]["k"] == 8 and k["intrinsic_critic"] is True
    before = (out / "nav-success" / "maddpg" / "seed_0" / "evaluations.npz").read_bytes()
    again = study("--methods", "maddpg", "--pilot", *common)
    assert again.returncode == 0 and "already complete" in again.stdout
    assert (out / "nav-success" / "maddpg" / "seed_0" / "evaluations.npz").read_bytes() == before


def test_the_informative_methods_need_k():
    refused = study("--task", "spread3", "--methods", "macb_k")
    assert refused.returncode != 0 and "--k" in refused.stderr and "Traceback" not in refused.stderr


def fake_run(folder, levels, episodes=1000, reach_at=None):
    """A complete run whose success rate is ``levels`` (one per seed-like run) from ``reach_at`` on (else throughout)."""
    folder.mkdir(parents=True)
    n = episodes
    rate = np.full(n, levels)
    if reach_at is not None:
        rate[:reach_at] = 0.0
    successes = (np.arange(10)[None, :] < np.round(rate * 10)[:, None]).astype(float)
    np.savez(folder / "evaluations.npz", timesteps=np.arange(1, n + 1) * 20, successes=successes,
             episodes=np.arange(1, n + 1))  # fmt: skip
    (folder / "run.json").write_text(json.dumps({"complete": True}))


def test_the_registered_rules_on_made_up_runs(tmp_path):
    import analyze

    results = tmp_path / "results"
    task = results / "spread3"
    for seed, level in enumerate([0.1, 0.5, 0.2, 0.1, 0.1]):
        fake_run(task / "maddpg" / f"seed_{seed}", level)
    for seed in range(5):
        fake_run(task / "macb_k" / f"seed_{seed}", 0.4)  # +0.2 over MADDPG's 0.2, every seed above it: helps
        fake_run(task / "macb_k_center" / f"seed_{seed}", [0.7, 0.7, 0.7, 0.7, 0.3][seed])  # +0.32, worst 0.3 > 0.2
        fake_run(task / "constant" / f"seed_{seed}", 0.2)
        fake_run(task / "rnd" / f"seed_{seed}", 1.0, reach_at=300)  # 90% in every seed, MADDPG never: faster
        fake_run(task / "macb_paper" / f"seed_{seed}", [0.9, 0.9, 0.9, 0.9, 0.1][seed])  # mean +0.54, worst 0.1: no
        (task / "maddpg" / f"seed_{seed}" / "count1.json").write_text(json.dumps(
            {"count1_fraction": {str(k): min(1.0, 0.5 + k / 100) for k in analyze.PROBE_KS}}))  # fmt: skip
    entry = analyze.entry(str(results), "spread3", scripted=0.93)
    assert entry["enters"] and entry["pilot_seeds_below"] == 2
    assert not analyze.entry(str(results), "spread3", scripted=0.85)["enters"]
    assert analyze.informative_k(str(results), "spread3")["k"] == 32  # 0.82 at 32, 1.0 at 64
    report = analyze.decide(str(results), "spread3")
    decisions = report["decisions"]
    assert decisions["macb_k"]["helps_vs_maddpg"] and decisions["macb_k"]["credited"]
    center = decisions["macb_k_center"]
    assert center["helps_vs_maddpg"] and not center["beats"]["macb_k"] and not center["credited"]  # 0.62 vs 0.4
    assert decisions["rnd"]["helps_vs_maddpg"] and decisions["rnd"]["credited"]
    assert not decisions["macb_paper"]["helps_vs_maddpg"]
    assert decisions["macb_k_center_int"] == "incomplete" and decisions["macb_k_sketch"] == "incomplete"
    assert report["summaries"]["maddpg"]["reached_0.9"] == [False] * 5
    (task / "rnd" / "seed_4" / "run.json").write_text(json.dumps({"complete": False}))  # a run in progress
    assert analyze.decide(str(results), "spread3")["decisions"]["rnd"] == "incomplete"


def test_net_arch_files_the_runs_beside_the_study_and_bad_sizes_are_refused(tmp_path):
    out, work = tmp_path / "results", tmp_path / "work"
    done = study("--task", "nav-success", "--methods", "maddpg", "--seeds", "0", "-n", "40", "--net-arch", "8", "6",
                 "-o", str(out), "--work", str(work))  # fmt: skip
    assert done.returncode == 0, done.stderr
    run = out / "nav-success-8-6" / "maddpg" / "seed_0"
    assert json.loads((run / "run.json").read_text())["complete"] and not (out / "nav-success").exists()
    assert yaml.safe_load((run / "config.yml").read_text())["policy_kwargs"] == "dict(net_arch=[8, 6])"
    assert [p.name for p in (work / "nav-success-8-6").iterdir()] == ["m_seeds0"]
    refused = study("--task", "nav-success", "--methods", "maddpg", "--net-arch", "0", "-o", str(out), "--work", str(work))
    assert refused.returncode != 0 and "--net-arch" in refused.stderr and "Traceback" not in refused.stderr


def test_the_followup_picks_the_best_credited_method_and_applies_the_rule(tmp_path):
    import analyze

    results = tmp_path / "results"
    task = results / "spread3"
    levels = {"maddpg": 0.1, "macb_paper": 0.1, "macb_k": 0.1, "macb_k_center": 0.6, "macb_k_center_int": 0.7,
              "macb_k_sketch": 0.2, "rnd": 0.65, "constant": 0.1}  # fmt: skip
    for method, level in levels.items():
        for seed in range(5):
            fake_run(task / method / f"seed_{seed}", level)
    report = analyze.decide(str(results), "spread3")
    credited = sorted(m for m, d in report["decisions"].items() if d["credited"])
    assert credited == ["macb_k_center", "macb_k_center_int", "rnd"]
    assert analyze.best_method(report) == "macb_k_center_int"  # the highest mean of the credited
    assert not analyze.followup(str(results), "spread3", "macb_k_center_int")["decided"]  # nothing run yet
    big = results / "spread3-400-300"
    for seed in range(3):
        fake_run(big / "maddpg" / f"seed_{seed}", [0.1, 0.5, 0.2][seed])
        fake_run(big / "macb_k_center_int" / f"seed_{seed}", 0.6)
    f = analyze.followup(str(results), "spread3", "macb_k_center_int")
    assert f["decided"] and f["holds"] and f["maddpg_seeds_below"] == 2 and f["still_hard"]
    fake_run(big / "maddpg" / "seed_3", 0.9)  # not one of the follow-up's seeds: ignored
    assert analyze.followup(str(results), "spread3", "macb_k_center_int")["holds"]
    fake_run(big / "rnd" / "seed_0", 0.9)
    assert not analyze.followup(str(results), "spread3", "rnd")["decided"]  # 1 of 3 seeds
    (tmp_path / "levels.json").write_text(json.dumps({"levels": {"spread3": {"scripted": 0.99, "random": 0.0}}}))
    printed = subprocess.run([sys.executable, str(STUDY / "scripts" / "analyze.py"), "--results", str(results),
                              "--levels", str(tmp_path / "levels.json"), "--followup"],
                             capture_output=True, text=True, timeout=120)  # fmt: skip
    assert printed.returncode == 0, printed.stderr
    assert "spread3-400-300): macb_k_center_int against maddpg: holds" in printed.stdout
    assert "KM median" in printed.stdout


def test_the_study_curves_draw_every_complete_method_and_refuse_an_unknown_task(tmp_path):
    results = tmp_path / "results"
    for method, seeds in (("maddpg", 5), ("rnd", 2)):
        for seed in range(seeds):
            fake_run(results / "spread3-400-300" / method / f"seed_{seed}", 0.1 * seed, episodes=300)
    (results / "spread3-400-300" / "rnd" / "seed_1" / "run.json").write_text(json.dumps({"complete": False}))
    script = str(STUDY / "scripts" / "plot_study.py")
    done = subprocess.run([sys.executable, script, "--task", "spread3-400-300", "--results", str(results),
                           "-o", str(tmp_path / "c.png")], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "maddpg (5), rnd (1)" and (tmp_path / "c.png").stat().st_size > 10_000
    refused = subprocess.run([sys.executable, script, "--task", "spread", "--results", str(results), "-o", "x.png"],
                             capture_output=True, text=True, timeout=120)  # fmt: skip
    assert refused.returncode != 0 and "--task" in refused.stderr and "Traceback" not in refused.stderr


def test_coverage_tells_the_scripted_policy_from_random_actions():
    import coverage
    from sb3_macb.envs.scripted import scripted_actions

    rng = np.random.default_rng(0)
    scripted = coverage.coverage("spread3", lambda obs, env: scripted_actions(env), 20, seed=5)
    random = coverage.coverage("spread3", lambda obs, env: rng.uniform(-1, 1, (env.num_envs, 6)), 20, seed=5)
    assert scripted["covered_last"] > 2.5 and scripted["near_success"] == 1.0 and scripted["distance_last"] < 0.1
    assert random["covered_last"] < 0.5 and random["distance_last"] > 0.3


def test_listener_reach_tells_the_scripted_policy_from_random_actions():
    import coverage
    from sb3_macb.envs.scripted import scripted_actions

    rng = np.random.default_rng(0)
    scripted = coverage.listener_reach("comm6-wide", lambda obs, env: scripted_actions(env), 40, seed=5)
    random = coverage.listener_reach("comm6-wide", lambda obs, env: rng.uniform(0, 1, (env.num_envs, 5)) * 2 - 1, 40, 5)
    assert scripted["goal"] == 1.0 and scripted["any_landmark"] == 1.0 and scripted["goal_distance_last"] < 0.1
    assert random["goal"] < 0.3 and random["goal_distance_last"] > 0.5
    assert random["any_landmark"] >= random["goal"] and random["landmark_distance_last"] <= random["goal_distance_last"]
    with pytest.raises(SystemExit, match="not a Communicative Navigation task"):
        coverage.listener_reach("spread3", lambda obs, env: scripted_actions(env), 2, seed=5)

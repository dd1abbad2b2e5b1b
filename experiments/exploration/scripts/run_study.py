"""
Run the exploration study's methods on one candidate task, packed, with checkpoints, and file each run as
``results/<task>/<method>/seed_<s>/`` (``evaluations.npz``, ``config.yml``, ``run.json`` with ``complete``).

    python scripts/run_study.py --task spread3 --methods maddpg --seeds 0 1 2 --pack-by method --pilot  # the pilot
    python scripts/run_study.py --task spread3 --k 16 --seeds 0 1 2 3 4 -j 2                           # the study
    python scripts/run_study.py --task spread3 --k 16 --methods maddpg rnd --seeds 0 1 2 --net-arch 400 300


Methods are the variants of ``study.yml``; ``--k`` sets the code length of the methods named ``macb_k*`` (the
informative k, chosen by README.md's rule from the pilot's ``count1.json``). The runs of one seed share a process
(a pack: each run is the same experiment it would be alone), except those with intrinsic critics, which cannot be
packed with the others and get their own. Evaluation after every training episode, 10 episodes, as in the headline.
Each pack checkpoints into ``--work`` every ``--checkpoint-freq`` steps; the same command again resumes unfinished
packs and skips finished ones. ``--pilot`` also writes each run's count-1 levels when it finishes (the share of
SimHash codes seen once over all the run's transitions, joint observation and action, at k = 8 ... 512) to
``count1.json``. ``--net-arch`` replaces study.yml's 64-64 networks (actors and critics) and files the runs under
``results/<task>-<sizes>/`` (e.g. ``spread3-400-300``; the 400-300 follow-up of README.md). The script trains with
the sb3_macb of the checkout it lives in.
"""

import argparse
import json
import os
import shlex
import sys

STUDY = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # experiments/exploration
CHECKOUT = os.path.dirname(os.path.dirname(STUDY))
sys.path[:0] = [p for p in (CHECKOUT, os.path.join(STUDY, "scripts")) if p not in sys.path[:2]]

from sb3_macb.zoo.processes import run_packs  # noqa: E402
from study_tasks import BUDGET, CANDIDATES, EPISODE_STEPS  # noqa: E402

CONFIG = os.path.join(STUDY, "study.yml")
METHODS = ("maddpg", "macb_paper", "macb_k", "macb_k_center", "macb_k_center_int", "macb_k_sketch", "rnd", "constant")
METHOD_TAGS = dict(zip(METHODS, ("m", "p", "k", "kc", "kci", "ks", "r", "c")))  # (short names for work folders)
PROBE_KS = (8, 16, 32, 64, 128, 256, 512)


def task_folder(args: argparse.Namespace) -> str:
    """The task's folder name under ``--out`` and ``--work``: the task, and the network sizes when they are not
    study.yml's (``spread3-400-300``)."""
    return args.task if args.net_arch is None else "-".join([args.task, *map(str, args.net_arch)])


def _complete(args: argparse.Namespace, method: str, seed: int) -> bool:
    path = os.path.join(args.out, task_folder(args), method, f"seed_{seed}", "run.json")
    if not os.path.isfile(path):
        return False
    with open(path) as file:
        return bool(json.load(file).get("complete"))


def plan(args: argparse.Namespace) -> list[tuple[str, list[tuple[str, int]]]]:
    """
    The packs: (work folder, [(method, seed), ...]). ``--pack-by seed``: per seed, the methods that can share a pack;
    ``--pack-by method``: per method, all its seeds. A method with intrinsic critics cannot share a pack with the
    others, so its seeds always form their own pack. Runs already complete under ``--out`` are left out (never
    trained again or overwritten); a pack's work folder is named by its methods and seeds, so the same command
    finds it again.
    """
    todo = []
    for seed in args.seeds:
        for method in args.methods:
            if _complete(args, method, seed):
                print(f"{task_folder(args)} {method} seed {seed}: already complete in {args.out}", flush=True)
            else:
                todo.append((method, seed))
    groups: list[list[tuple[str, int]]] = []
    for method in [m for m in args.methods if m.endswith("_int")]:
        groups.append([(m, s) for m, s in todo if m == method])
    rest = [(m, s) for m, s in todo if not m.endswith("_int")]
    if args.pack_by == "seed":
        groups += [[(m, s) for m, s in rest if s == seed] for seed in args.seeds]
    else:
        groups += [[(m, s) for m, s in rest if m == method] for method in args.methods]
    packs = []
    for group in filter(None, groups):
        methods = dict.fromkeys(m for m, _ in group)
        seeds = dict.fromkeys(s for _, s in group)
        tag = "-".join(METHOD_TAGS[m] for m in methods) + "_seeds" + "-".join(map(str, seeds))
        packs.append((os.path.join(args.work, task_folder(args), tag), group))
    return packs


def count1_levels(model, seeds: list[int]) -> list[dict]:
    """Each run's share of codes seen once over its buffer's transitions, for every k of :data:`PROBE_KS`."""
    from sb3_macb.exploration import MACB

    buffer = model.replay_buffer
    rows = buffer.buffer_size if buffer.full else buffer.pos
    levels = []
    for run, seed in enumerate(seeds):
        obs, actions = buffer.observations[:rows, run], buffer.actions[:rows, run]
        row = {}
        for k in PROBE_KS:
            probe = MACB(beta=0.0, k=k, scope="joint", seed=seed)
            probe.setup(model.agent_layout)
            probe.count(probe.keys(obs, actions))
            row[str(k)] = probe.count1_fraction
        levels.append({"transitions": int(rows), "count1_fraction": row})
    return levels


def run_pack(args: argparse.Namespace, work: str, jobs: list[tuple[str, int]], command: str) -> tuple[str, bool]:
    """Train (or resume) one pack; (the line to print, whether it failed)."""
    import torch as th

    from sb3_macb.zoo.experiment import Experiment, ExperimentConfig, ExperimentError, make_run, run_or_resume

    th.set_num_threads(1)
    env_id, env_kwargs = CANDIDATES[args.task]
    steps = BUDGET[args.task] if args.n_timesteps is None else args.n_timesteps
    runs = []
    try:
        for method, seed in jobs:
            overrides: dict = {"exploration.k": args.k} if method.startswith("macb_k") else {}
            if args.net_arch is not None:
                overrides["policy_kwargs"] = f"dict(net_arch={list(args.net_arch)})"
            folder = os.path.join(args.out, task_folder(args), method, f"seed_{seed}")
            runs.append(make_run(env_id, seed, folder, [method], overrides, conf_file=CONFIG, n_timesteps=steps)[0])
        config = ExperimentConfig(env_id, runs, n_timesteps=steps, eval_freq=EPISODE_STEPS[args.task], eval_episodes=10,
                                  env_kwargs=dict(env_kwargs), command=command)  # fmt: skip
        experiment = Experiment(config, work, checkpoint_freq=args.checkpoint_freq)
        run_or_resume(experiment)
        if args.pilot and experiment.model is not None:  # (a pack finished earlier wrote its count1.json then)
            for run, levels in zip(runs, count1_levels(experiment.model, [r.seed for r in runs])):
                with open(os.path.join(run.folder, "count1.json"), "w") as file:
                    json.dump(levels, file, indent=1)
    except ExperimentError as exc:
        return f"{work}: ERROR {exc}", True
    return f"{work}: done ({', '.join(f'{m} seed {s}' for m, s in jobs)})", False


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", choices=sorted(CANDIDATES), required=True)
    parser.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--k", type=int, help="code length of the macb_k* methods (required when one is run)")
    parser.add_argument("-n", "--n-timesteps", type=int, help="steps per run (default: the task's budget in study_tasks.py)")
    parser.add_argument(
        "--pack-by",
        choices=("seed", "method"),
        default="seed",
        help="pack the methods of a seed together (default) or the seeds of a method",
    )
    parser.add_argument(
        "--net-arch",
        type=int,
        nargs="+",
        metavar="UNITS",
        help="hidden layer sizes of every actor and critic instead of study.yml's 64 64; runs go to <task>-<sizes>",
    )
    parser.add_argument("--pilot", action="store_true", help="write each finished run's count1.json")
    parser.add_argument("-j", "--jobs", type=int, default=1, help="packs in parallel (one thread each)")
    parser.add_argument("--checkpoint-freq", type=int, default=20_000, help="steps per run between checkpoints")
    parser.add_argument("-o", "--out", default=os.path.join(STUDY, "results"), help="default: the study's results/")
    parser.add_argument("--work", default=os.path.join(STUDY, "logs"), help="checkpoints (not for git)")
    args = parser.parse_args()
    if any(m.startswith("macb_k") for m in args.methods) and (args.k is None or args.k < 1):
        parser.error("--k (an integer >= 1) is required for the macb_k* methods")
    if args.jobs < 1 or args.checkpoint_freq < 1 or (args.n_timesteps is not None and args.n_timesteps < 1):
        parser.error("-j, --checkpoint-freq and -n must be >= 1")
    if args.net_arch is not None and min(args.net_arch) < 1:
        parser.error("--net-arch takes layer sizes >= 1, e.g. --net-arch 400 300")
    command = "python scripts/run_study.py " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    import sb3_macb

    print(f"sb3_macb {sb3_macb.__version__} from {os.path.dirname(os.path.abspath(sb3_macb.__file__))}", flush=True)
    packs = plan(args)
    failed = run_packs(run_pack, [(args, work, jobs, command) for work, jobs in packs], args.jobs)
    if failed:
        sys.exit(f"{failed} of {len(packs)} packs failed (see above)")


if __name__ == "__main__":
    main()

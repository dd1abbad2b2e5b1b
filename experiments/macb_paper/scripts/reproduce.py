"""
Run the paper's experiments with the zoo's YAML, several runs packed in one process, with checkpoints, and file
each run's evaluations as ``results/<Task>-<reward>[-<suffix>]/<variant>/seed_<s>/evaluations.npz`` with
``config.yml`` and ``run.json`` (command, wall time, ``complete``) beside it.

    python scripts/reproduce.py --task comm-sparse --variants maddpg macb_joint macb_constant --seeds 0 1 2 \\
        --suffix paper --pack 3 -j 2
    python scripts/reproduce.py --task comm-sparse --variants maddpg macb_joint macb_local macb_constant macb_k32 \\
        --seeds 0 1 2 3 4 --fast --suffix 4e4 --pack 5 -j 2

Variants are those of the repository's ``zoo/hyperparams/maddpg.yml``, alone or combined with commas
(``maddpg,refcode``: filed as ``maddpg+refcode``); ``--fast`` adds the ``fast`` variant (64-64 networks). A
``KEY=VALUE`` item sets one hyperparameter on top of them (dotted keys set nested ones, the value is read as YAML):
``macb_joint,exploration.k=32`` is filed as ``macb_joint+exploration.k=32``. ``--grid KEY=V1,V2,...`` (repeatable)
crosses every variant with a grid of such settings, one run per point and seed, as for the paper's Table 1:

    python scripts/reproduce.py --task comm-sparse --variants macb_joint --grid exploration.beta=0.05,0.2,0.4 \
        --grid exploration.k=32,64,256,512 --seeds 0 1 2 --fast --suffix table1-4e4

Every run's settings are checked before anything is created or trained. The
runs of one seed are packed together (``--pack`` runs per process at most; each run is the same experiment it
would be alone), or with ``--mix-seeds`` the runs of all seeds, ``--pack`` to a process (for few variants and many
seeds). Runs already complete under ``-o`` (``run.json`` says ``complete``) are left out: never trained again or
overwritten. Each pack checkpoints into ``--work/<Task>-<reward>[-<suffix>]/<variants>_seeds<seeds>/`` every
``--checkpoint-freq`` steps; running the same command again resumes unfinished packs from their checkpoints and
skips finished ones, so the script can be stopped at any moment and re-run to go on. The ``evaluations.npz`` under
results/ is rewritten at every checkpoint: it always holds the evaluations reached so far (``run.json`` says
``complete`` only at the end).

The script trains with the sb3_macb of the checkout it lives in (the repository root goes first on ``sys.path``, and
the packs' processes inherit it), not with whatever sb3_macb the environment has installed: a git worktree of a fixed
commit runs that commit's library even when the virtual environment holds an editable install of another checkout.
"""

import argparse
import hashlib
import itertools
import os
import shlex
import sys
from typing import Any

import yaml

STUDY = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # experiments/macb_paper
CHECKOUT = os.path.dirname(os.path.dirname(STUDY))
if sys.path[:1] != [CHECKOUT]:
    sys.path.insert(0, CHECKOUT)  # this checkout's sb3_macb; spawned pack processes start with the same sys.path

from sb3_macb.common import evaluations  # noqa: E402 (after the checkout goes first on sys.path)

MAX_NAME = 120  # longest variants part of a pack's work folder name kept as it is (a name may have 255 bytes)
TASKS = {
    "comm-sparse": ("sb3_macb/CommunicativeNavigation-v0", "CommunicativeNavigation-sparse", {"reward": "sparse"}),
    "comm-distance": ("sb3_macb/CommunicativeNavigation-v0", "CommunicativeNavigation-distance", {"reward": "distance"}),
    "nav": ("sb3_macb/TwoAgentNavigation-v0", "TwoAgentNavigation-sparse", {}),
}


def split_variant(variant: str) -> tuple[list[str], dict[str, Any]]:
    """
    A variant string's names (from the zoo YAML's ``variants``, in order) and its ``KEY=VALUE`` settings (values read
    as YAML): ``"macb_joint,exploration.k=32"`` -> ``(["macb_joint"], {"exploration.k": 32})``.
    """
    names, overrides = [], {}
    for item in variant.split(","):
        key, is_setting, value = item.partition("=")
        if is_setting:
            try:
                overrides[key] = yaml.safe_load(value)
            except yaml.YAMLError:
                raise ValueError(f"{item!r}: the value of {key!r} is not valid YAML") from None
        else:
            names.append(item)
    return names, overrides


def expand_grid(variants: list[str], grid: list[str]) -> list[str]:
    """
    Every variant crossed with every point of the grid (``KEY=V1,V2,...`` items, the last key varying fastest): the
    variant strings with the point's ``KEY=VALUE`` settings appended, in that order.
    """
    axes = []
    for item in grid:
        key, _, values = item.partition("=")
        if not key or "," in key or not all(values.split(",")):
            raise ValueError(f"--grid {item!r}: give KEY=VALUE[,VALUE...], e.g. exploration.k=32,64")
        axes.append([f"{key}={value}" for value in values.split(",")])
    keys = [axis[0].partition("=")[0] for axis in axes]
    if len(set(keys)) < len(keys):
        raise ValueError(f"--grid: each key once, got {keys}")
    return [",".join([variant, *point]) for variant in variants for point in itertools.product(*axes)]


def check_variants(args: argparse.Namespace) -> None:
    """Build every run's settings once (nothing is created): a bad variant, key or value raises its one-line error."""
    from sb3_macb.zoo.experiment import ExperimentConfig, ExperimentError, make_run

    env_id, _, env_kwargs = TASKS[args.task]
    for variant in args.variants:
        names, overrides = split_variant(variant)
        if not all(names) or any(not key for key in overrides):
            raise ValueError(f"--variants {variant!r}: an empty name or key")
        try:
            names += ["fast"] if args.fast else []
            run, _ = make_run(env_id, 0, "check", names, overrides, n_timesteps=args.n_timesteps)
            ExperimentConfig(env_id, [run], n_timesteps=args.n_timesteps, env_kwargs=env_kwargs)
        except (ExperimentError, ValueError) as exc:
            raise ValueError(f"--variants {variant!r}: {exc}") from None


def results_name(args: argparse.Namespace) -> str:
    """The runs' folder under ``-o`` and ``--work``: ``<Task>-<reward>[-<suffix>]``."""
    return TASKS[args.task][1] + (f"-{args.suffix}" if args.suffix else "")


def run_folder(args: argparse.Namespace, variant: str, seed: int) -> str:
    """Where a run is filed: ``<out>/<Task>-<reward>[-<suffix>]/<variant, commas as '+'>/seed_<seed>``."""
    return os.path.join(args.out, results_name(args), variant.replace(",", "+"), f"seed_{seed}")


def plan(args: argparse.Namespace) -> list[tuple[str, list[tuple[str, int]]]]:
    """
    The packs: (work folder, [(variant, seed), ...]) of the runs not yet complete under ``-o``; the runs of one seed
    together, at most ``pack`` per pack, or with ``--mix-seeds`` the runs of every seed in order (seed by seed, the
    variants of each in the order given) cut into packs of ``pack``, so that few variants and several seeds still
    fill every process. A pack's work folder is named by its variants and seeds, so that the same command finds it
    again and commands for other variants never meet it (a long list of variants by the first, their number and a
    digest of them all).
    """
    todo = []
    for seed in args.seeds:
        for variant in args.variants:
            if evaluations.is_complete(run_folder(args, variant, seed)):
                print(f"{run_folder(args, variant, seed)}: already complete, left out", flush=True)
            else:
                todo.append((variant, seed))
    if args.mix_seeds:
        groups = [todo[start : start + args.pack] for start in range(0, len(todo), args.pack)]
    else:
        groups = []
        for seed in args.seeds:
            runs = [(v, s) for v, s in todo if s == seed]
            groups += [runs[start : start + args.pack] for start in range(0, len(runs), args.pack)]
    packs = []
    for jobs in groups:
        names = list(dict.fromkeys(v.replace(",", "+") for v, _ in jobs))
        variants = "-".join(names)
        if len(variants) > MAX_NAME:  # a grid's packs: the first run's name, how many more, and a digest of them all
            digest = hashlib.sha256(variants.encode()).hexdigest()[:12]
            variants = f"{names[0]}-and-{len(names) - 1}-more-{digest}"
        seeds = "-".join(dict.fromkeys(str(s) for _, s in jobs))
        packs.append((os.path.join(args.work, results_name(args), f"{variants}_seeds{seeds}"), jobs))
    return packs


def run_pack(args: argparse.Namespace, work: str, jobs: list[tuple[str, int]], command: str) -> tuple[str, bool]:
    """Train (or resume) one pack; (the line to print, whether it failed)."""
    import torch as th

    from sb3_macb.zoo.experiment import Experiment, ExperimentConfig, ExperimentError, make_run, run_or_resume

    th.set_num_threads(1)
    env_id, _, env_kwargs = TASKS[args.task]
    runs = []
    try:
        for variant, seed in jobs:
            names, overrides = split_variant(variant)  # "maddpg,refcode": applied in order, then the settings
            folder = run_folder(args, variant, seed)
            names += ["fast"] if args.fast else []
            runs.append(make_run(env_id, seed, folder, names, overrides, n_timesteps=args.n_timesteps)[0])
        config = ExperimentConfig(env_id, runs, n_timesteps=args.n_timesteps, env_kwargs=env_kwargs, command=command)
        run_or_resume(Experiment(config, work, checkpoint_freq=args.checkpoint_freq, keep_models=args.keep_models))
    except ExperimentError as exc:
        return f"{work}: ERROR {exc}", True
    return f"{work}: done ({', '.join(f'{v} seed {s}' for v, s in jobs)})", False


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", choices=sorted(TASKS), required=True)
    parser.add_argument("--variants", nargs="+", required=True,
                        help="zoo variants, combined with commas, with optional KEY=VALUE settings")
    parser.add_argument("--grid", action="append", default=[], metavar="KEY=V1,V2,...",
                        help="cross every variant with these values of KEY (repeat for a grid)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("-n", "--n-timesteps", type=int, default=800_000, help="steps per run (the paper's 4e4 episodes)")
    parser.add_argument("--fast", action="store_true", help="64-64 networks (the 'fast' variant)")
    parser.add_argument("--pack", type=int, default=1, help="runs trained together in one process (at most)")
    parser.add_argument("--mix-seeds", action="store_true",
                        help="fill packs with the runs of several seeds (resume with the same seeds, variants and --pack)")
    parser.add_argument("-j", "--jobs", type=int, default=1, help="packs in parallel (one thread each)")
    parser.add_argument("--checkpoint-freq", type=int, default=20_000, help="steps per run between checkpoints")
    parser.add_argument("--keep-models", action="store_true",
                        help="keep every checkpoint's model in <work>/<pack>/models/ (for scripts/collapse_diagnostics.py)")
    parser.add_argument("--suffix", default="", help="results/<Task>-<reward>-SUFFIX/")
    parser.add_argument("-o", "--out", default=os.path.join(STUDY, "results"), help="default: the study's results/")
    parser.add_argument("--work", default=os.path.join(STUDY, "logs", "reproduce"),
                        help="checkpoints (not for git; default: the study's logs/reproduce)")
    args = parser.parse_args()
    if args.pack < 1:
        parser.error("--pack must be >= 1")
    from sb3_macb.zoo.experiment import ExperimentError

    try:
        args.variants = expand_grid(args.variants, args.grid)
        check_variants(args)
    except (ExperimentError, ValueError) as exc:
        parser.exit(2, f"reproduce.py: error: {str(exc).splitlines()[0]}\n")
    command = "python scripts/reproduce.py " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    import sb3_macb

    print(f"sb3_macb {sb3_macb.__version__} from {os.path.dirname(os.path.abspath(sb3_macb.__file__))}", flush=True)
    from sb3_macb.zoo.processes import run_packs

    packs = plan(args)
    if not packs:
        print("every run is complete", flush=True)
        return
    failed = run_packs(run_pack, [(args, work, jobs, command) for work, jobs in packs], args.jobs)
    if failed:
        sys.exit(f"{failed} of {len(packs)} packs failed (see above)")


if __name__ == "__main__":
    main()

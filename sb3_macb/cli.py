"""The ``sb3-macb`` command (also ``python -m sb3_macb``): train, enjoy, sweep, plot."""

import sys

USAGE = """usage: sb3-macb {train,enjoy,sweep,plot} ...

  train   one run with the zoo's YAML, evaluated as the paper does (sb3-macb train -h: rl_zoo3's option names plus
          --variant, --unsafe-eval); --checkpoint-freq N checkpoints, --resume RUN_FOLDER continues; --optimize searches
  enjoy   play a run folder's model and print each episode's success and every agent's return (loads a pickle)
  sweep   run a grid of settings x seeds as trials of an Optuna study, shared by any number of workers
  plot    learning curves, collisions, the beta x k table and heatmap, the SimHash grouping figure
"""


# top-level modules of the packages that the ``zoo`` extra installs (pyproject.toml)
ZOO_EXTRA_MODULES = frozenset(
    {"rl_zoo3", "sb3_contrib", "optuna", "yaml", "matplotlib", "pandas", "tqdm", "rich", "sqlalchemy"}
)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(USAGE)
        return 0 if argv else 2
    try:
        return _run(argv[0], argv[1:])
    except ModuleNotFoundError as exc:  # a command used without the extra it needs: say which to install
        if (exc.name or "").split(".")[0] not in ZOO_EXTRA_MODULES:
            raise
        print(
            f"sb3-macb {argv[0]}: error: this command needs the 'zoo' extra (no module named '{exc.name}'): "
            "pip install 'sb3_macb[zoo]'",
            file=sys.stderr,
        )
        return 2


def _run(command: str, rest: list[str]) -> int:
    if command == "train":
        from sb3_macb.common.atomic import AtomicWriteError
        from sb3_macb.zoo.experiment import ExperimentError
        from sb3_macb.zoo.train import train

        debug = "--debug" in rest
        try:
            train([a for a in rest if a != "--debug"])
        except (ExperimentError, AtomicWriteError) as exc:  # a user's mistake, a full disk: one line (--debug: traceback)
            if debug:
                raise
            print(f"sb3-macb train: error: {exc}", file=sys.stderr)
            return 2
    elif command == "enjoy":
        from sb3_macb.zoo.enjoy import main as enjoy
        from sb3_macb.zoo.experiment import ExperimentError

        try:
            return enjoy(rest)
        except ExperimentError as exc:  # no such folder, no model, a config.yml that names no env: one line
            print(f"sb3-macb enjoy: error: {exc}", file=sys.stderr)
            return 2
    elif command == "sweep":
        from sb3_macb.zoo.sweep import main as sweep

        try:
            return sweep(rest)
        except (ValueError, ConnectionError) as exc:  # bad config, unreachable storage: one line
            print(f"sb3-macb sweep: error: {exc}", file=sys.stderr)
            return 2
    elif command == "plot":
        from sb3_macb.zoo.plots import main as plot

        try:
            plot(rest)
        except FileNotFoundError as exc:  # a group or file that is not there: one line
            print(f"error: {exc}", file=sys.stderr)
            return 2
    else:
        print(f"sb3-macb: unknown command '{command}'\n\n{USAGE}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())

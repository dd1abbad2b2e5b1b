"""
Copy the runs that ``reproduce.py`` filed outside the repository (its ``-o``) into the study's ``results/``, the way
the sessions commit them:

- a run's ``evaluations.npz`` (and ``config.yml``) replaces the committed one only when it reaches further (more
  evaluation rows); a shorter or equal one is left out, so a restarted run never shortens what is committed;
- a complete run (``run.json`` says ``complete``) brings its ``run.json`` and its final ``model.zip``, re-packed with
  deflate compression (the same members, byte for byte; SB3 writes them stored);
- a committed complete run is never replaced.

It does not know machines: a run on another CPU does not repeat the committed one step for step, so before
publishing a run that restarted on another machine, move the committed files to a folder labelled by their machine
(as ``CommunicativeNavigation-sparse-4e4-1e6-amd-partial/``).

    python scripts/publish_runs.py /work/runres results            # copy
    python scripts/publish_runs.py /work/runres results --dry-run  # only say what would be copied

Runs are the folders ``<experiment>/<variant>/seed_<s>/`` under SRC that hold an ``evaluations.npz``. Each is reported
in one line. The model zips are pickles: this script copies their bytes and loads nothing.
"""

import argparse
import json
import os
import shutil
import sys
import zipfile

import numpy as np


def _rows(path: str) -> int:
    """Evaluation rows of an ``evaluations.npz`` (0 if it cannot be read)."""
    try:
        with np.load(path) as data:
            return int(len(data["timesteps"]))
    except (OSError, KeyError, ValueError):
        return 0


def _complete(folder: str) -> bool:
    try:
        with open(os.path.join(folder, "run.json")) as f:
            return bool(json.load(f).get("complete"))
    except (OSError, ValueError, AttributeError):
        return False


def deflate_zip(source: str, target: str) -> None:
    """Write ``source``'s members into ``target`` with deflate compression (written beside it, then renamed)."""
    partial = target + ".partial"
    with zipfile.ZipFile(source) as zin, zipfile.ZipFile(partial, "w", compression=zipfile.ZIP_DEFLATED) as zout:
        for info in zin.infolist():
            zout.writestr(info.filename, zin.read(info.filename), compress_type=zipfile.ZIP_DEFLATED)
    os.replace(partial, target)


def publish(src: str, dst: str, dry_run: bool = False) -> list[str]:
    """Copy the runs under ``src`` into ``dst`` by the rules above; one line of report per run."""
    report = []
    for root, _, files in sorted(os.walk(src)):
        if "evaluations.npz" not in files:
            continue
        rel = os.path.relpath(root, src)
        target = os.path.join(dst, rel)
        new_rows, old_rows = _rows(os.path.join(root, "evaluations.npz")), _rows(os.path.join(target, "evaluations.npz"))
        complete = _complete(root)
        if _complete(target):
            report.append(f"{rel}: kept (the committed run is complete)")
            continue
        if new_rows <= old_rows and not complete:
            report.append(f"{rel}: kept (committed {old_rows} evaluations, this one {new_rows})")
            continue
        if complete and not os.path.isfile(os.path.join(root, "model.zip")):
            report.append(f"{rel}: kept (complete but without model.zip)")
            continue
        names = ["evaluations.npz", "config.yml"] + (["run.json"] if complete else [])
        report.append(f"{rel}: {'complete' if complete else 'partial'}, {new_rows} evaluations (committed {old_rows})")
        if dry_run:
            continue
        os.makedirs(target, exist_ok=True)
        for name in names:
            if os.path.isfile(os.path.join(root, name)):
                shutil.copyfile(os.path.join(root, name), os.path.join(target, name))
        if complete:
            deflate_zip(os.path.join(root, "model.zip"), os.path.join(target, "model.zip"))
    return report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("src", help="the runs' folder (reproduce.py's -o)")
    parser.add_argument("dst", help="the study's results/")
    parser.add_argument("--dry-run", action="store_true", help="only say what would be copied")
    args = parser.parse_args()
    for name, path in (("src", args.src), ("dst", args.dst)):
        if not os.path.isdir(path):
            parser.error(f"{name}: {path} is not a folder")
    if os.path.realpath(args.src) == os.path.realpath(args.dst):
        parser.error("src and dst are the same folder")
    lines = publish(args.src, args.dst, args.dry_run)
    print("\n".join(lines) if lines else f"no runs (folders with an evaluations.npz) under {args.src}")
    sys.exit(0)


if __name__ == "__main__":
    main()

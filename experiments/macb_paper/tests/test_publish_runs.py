"""scripts/publish_runs.py: what a session copies from reproduce.py's output into results/."""

import json
import zipfile
from pathlib import Path

import numpy as np
from test_study import load_script


def _run(folder: Path, rows: int, complete: bool = False) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    np.savez(folder / "evaluations.npz", timesteps=np.arange(rows) * 20, successes=np.zeros((rows, 10)))
    (folder / "config.yml").write_text(f"rows: {rows}\n")
    if complete:
        (folder / "run.json").write_text(json.dumps({"complete": True}))
        with zipfile.ZipFile(folder / "model.zip", "w", compression=zipfile.ZIP_STORED) as z:
            z.writestr("data", b"x" * 5000)
            z.writestr("policy.pth", bytes(range(256)) * 20)


def test_publish_replaces_only_what_reaches_further_and_deflates_complete_models(tmp_path):
    publish = load_script("publish_runs").publish
    src, dst = tmp_path / "runres", tmp_path / "results"
    run = Path("Task-4e4/maddpg/seed_4")
    _run(dst / run, 300)  # committed partial
    _run(src / run, 200)  # a restarted run, not as far yet
    assert "kept" in publish(str(src), str(dst))[0]
    assert len(np.load(dst / run / "evaluations.npz")["timesteps"]) == 300

    _run(src / run, 400)
    assert publish(str(src), str(dst), dry_run=True)[0].endswith("partial, 400 evaluations (committed 300)")
    assert len(np.load(dst / run / "evaluations.npz")["timesteps"]) == 300  # (a dry run copies nothing)
    publish(str(src), str(dst))
    assert len(np.load(dst / run / "evaluations.npz")["timesteps"]) == 400
    assert not (dst / run / "run.json").exists()

    _run(src / run, 500, complete=True)
    publish(str(src), str(dst))
    assert json.loads((dst / run / "run.json").read_text())["complete"]
    with zipfile.ZipFile(src / run / "model.zip") as a, zipfile.ZipFile(dst / run / "model.zip") as b:
        assert [i.compress_type for i in b.infolist()] == [zipfile.ZIP_DEFLATED] * 2
        assert {n: a.read(n) for n in a.namelist()} == {n: b.read(n) for n in b.namelist()}
    assert (dst / run / "model.zip").stat().st_size < (src / run / "model.zip").stat().st_size

    _run(src / run, 600)  # nothing replaces a complete run
    assert "complete" in publish(str(src), str(dst))[0] and "kept" in publish(str(src), str(dst))[0]
    assert len(np.load(dst / run / "evaluations.npz")["timesteps"]) == 500

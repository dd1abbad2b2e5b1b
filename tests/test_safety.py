"""What strangers' files and a user's mistakes cannot do: run code, write outside the run, print tracebacks."""

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
import yaml

from sb3_macb.cli import main as cli
from sb3_macb.zoo.experiment import (
    Experiment,
    ExperimentConfig,
    ExperimentError,
    RunConfig,
    load_experiment,
    load_hyperparams,
    make_callbacks,
)

COMM = "sb3_macb/CommunicativeNavigation-v0"
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FAST = ["--env", COMM, "--variant", "maddpg,fast", "--no-progress", "--verbose", "0", "-tb", ""]


def marker_code(marker) -> str:
    """A Python expression that creates ``marker`` when it is evaluated."""
    return f"__import__('pathlib').Path({str(marker)!r}).touch()"


def one_line_error(capsys, argv, *expected):
    """Run the command line; assert exit 2 and a single stderr line that names ``expected``, without a traceback."""
    assert cli(argv) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    for word in expected:
        assert word in lines[0], (word, lines[0])
    return lines[0]


MISTAKES = [
    (["-params", "exploration.beta:-1"], ["exploration", "beta"]),
    (["-params", "exploration.scope:'everything'"], ["exploration", "scope"]),
    (["-params", "exploration.nope:1"], ["exploration", "nope"]),
    (["-params", "batch_size:0"], ["batch_size", ">= 1"]),
    (["-params", "policy_kwargs:\"dict(net_arch='wide')\""], ["net_arch"]),
    (["-params", "train_freq:0"], ["train_freq"]),
    (["-params", "share_parameters:\"[['nobody']]\""], ["share_parameters", "nobody"]),
    (["-params", "policy:'CnnPolicy'"], ["policy", "MlpPolicy"]),
    (["-params", "noise_std:'big'"], ["noise_std"]),
    (["-params", "gamma:2"], ["gamma", "(0, 1]"]),
    (["-params", "n_envs:0"], ["n_envs"]),
    (["-params", "learning_starts:-1"], ["learning_starts"]),
    (["-params", "buffer_size:-5"], ["buffer_size"]),
    (["--env-kwargs", "reward:'bogus'"], ["reward"]),
    (["--env-kwargs", "colour:1"], ["colour"]),
    (["--device", "tpu"], ["--device"]),
    (["--num-threads", "0"], ["--num-threads"]),
    (["-n", "0"], ["-n"]),
    (["-n", "-5"], ["-n"]),
    (["-i", "logs/maddpg/x/model.zip"], ["-i/--trained-agent", "--resume"]),
    (["-params", "exploration.beta:'lin_fast'"], ["exploration.beta", "lin_<number>"]),
    (["-params", "exploration.normalize:'mean'"], ["exploration", "normalize"]),
    (["-params", "intrinsic_gamma:2"], ["intrinsic_gamma"]),
    (["-params", "exploration.estimator:'icm'"], ["exploration", "estimator"]),
    (["-params", "gamma:-'a'"], ["gamma", "not allowed"]),  # only numbers take a minus sign
    (["-params", "gamma:-True"], ["gamma", "not allowed"]),
    (["--save-freq", "0"], ["--save-freq", ">= 1"]),
    (["--save-freq", "50", "--checkpoint-freq", "40"], ["--save-freq", "--checkpoint-freq"]),
]


@pytest.mark.parametrize("extra,expected", MISTAKES, ids=[" ".join(m[0]) for m in MISTAKES])
def test_a_mistake_is_one_line_naming_the_key_and_leaves_no_run_folder(tmp_path, capsys, monkeypatch, extra, expected):
    monkeypatch.chdir(tmp_path)
    one_line_error(capsys, ["train", *FAST, "-n", "40", "-f", str(tmp_path / "logs"), *extra], *expected)
    assert not (tmp_path / "logs" / "maddpg").exists() or not os.listdir(tmp_path / "logs" / "maddpg")


def small_hyperparams(**extra):
    hp = load_hyperparams(COMM, variants=["maddpg", "fast"])
    hp.update(policy_kwargs="dict(net_arch=[16])", batch_size=8, **extra)
    return hp


def single_run(folder, steps=150, **extra) -> ExperimentConfig:
    """The train command's layout: the run's files and its checkpoints in one folder."""
    return ExperimentConfig(
        COMM, [RunConfig(seed=0, folder=str(folder), hyperparams=small_hyperparams(**extra))], n_timesteps=steps
    )


@pytest.fixture(scope="module")
def checkpointed(tmp_path_factory):
    """A run folder as a kill after its checkpoint at step 100 leaves it (and the finished run's files, to compare)."""
    root = tmp_path_factory.mktemp("checkpointed")
    whole = root / "whole"
    Experiment(single_run(whole), str(whole), verbose=0).run()
    cut = root / "cut"
    experiment = Experiment(single_run(cut), str(cut), checkpoint_freq=50, keep_checkpoint=True, verbose=0)
    experiment.run()
    assert sorted(os.listdir(cut / "checkpoint")) == ["LATEST", "step_100"]
    experiment._write_experiment_file(done=False)
    for name in ("model.zip", "run.json", "config.yml", "best_model.zip"):
        (cut / name).unlink(missing_ok=True)
    return root


def copy_of(checkpointed, tmp_path, name="copy"):
    target = tmp_path / name
    shutil.copytree(checkpointed / "cut", target)
    return target


def test_resume_of_a_moved_folder_writes_only_there_whatever_the_working_directory(checkpointed, tmp_path, monkeypatch):
    original = checkpointed / "cut"
    before = {p: p.read_bytes() for p in original.rglob("*") if p.is_file()}
    moved = copy_of(checkpointed, tmp_path)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert subprocess.run([sys.executable, "-m", "sb3_macb.zoo.experiment", "--resume", os.path.relpath(moved)],
                          cwd=elsewhere, capture_output=True, timeout=300).returncode == 0  # fmt: skip
    assert {p: p.read_bytes() for p in original.rglob("*") if p.is_file()} == before  # the original is untouched
    assert not os.listdir(elsewhere)
    assert json.loads((moved / "run.json").read_text())["complete"] and (moved / "model.zip").exists()
    a, b = np.load(moved / "evaluations.npz"), np.load(checkpointed / "whole" / "evaluations.npz")
    assert all(np.array_equal(a[name], b[name]) for name in b.files)
    # the train command's resume of a moved folder: the same, and its path is not a setting that must match
    again = copy_of(checkpointed, tmp_path, "again")
    Experiment(single_run(again), str(again), verbose=0).run(resume=True)
    assert np.array_equal(np.load(again / "evaluations.npz")["results"], b["results"])


def test_a_moved_pack_whose_runs_lie_outside_its_folder_is_refused(tmp_path):
    runs = [RunConfig(seed=s, folder=str(tmp_path / "out" / f"run_{s}"), hyperparams=small_hyperparams()) for s in (0, 1)]
    work = tmp_path / "work"
    Experiment(ExperimentConfig(COMM, runs, n_timesteps=60), str(work), verbose=0)._write_experiment_file(done=False)
    saved = json.loads((work / "experiment.json").read_text())
    assert [r["folder"] for r in saved["config"]["runs"]] == [
        os.path.join("..", "out", "run_0"),
        os.path.join("..", "out", "run_1"),
    ]
    assert len(load_experiment(str(work), verbose=0).config.runs) == 2  # in place: its runs are where they were
    shutil.copytree(work, tmp_path / "copy")
    with pytest.raises(ExperimentError, match="moved or copied .* lies outside it"):
        load_experiment(str(tmp_path / "copy"))


def test_unsafe_eval_is_never_taken_from_a_run_folder(checkpointed, tmp_path):
    folder = copy_of(checkpointed, tmp_path)
    marker = tmp_path / "MARKER"
    saved = json.loads((folder / "experiment.json").read_text())
    saved["config"]["unsafe_eval"] = True
    saved["config"]["runs"][0]["hyperparams"]["policy_kwargs"] = f"dict(net_arch=[16], x={marker_code(marker)})"
    (folder / "experiment.json").write_text(json.dumps(saved))
    with pytest.raises(ExperimentError, match="started with --unsafe-eval"):
        load_experiment(str(folder))
    done = subprocess.run([sys.executable, "-m", "sb3_macb.zoo.experiment", "--resume", str(folder)], capture_output=True,
                          text=True, timeout=120)  # fmt: skip
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1 and "--unsafe-eval" in done.stderr
    saved["config"]["unsafe_eval"] = False  # and without the flag in the file, the string is parsed, not run
    (folder / "experiment.json").write_text(json.dumps(saved))
    with pytest.raises(ExperimentError, match="not allowed in a hyperparameter string"):
        load_experiment(str(folder))
    assert not marker.exists()


def test_damaged_checkpoint_metadata_is_named_in_one_line(checkpointed, tmp_path, capsys):
    def resume(folder):
        from sb3_macb.zoo.experiment import main

        assert main(["--resume", str(folder)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1, err
        return err[0]

    for content, expected in ((b"\xff\xfe", "LATEST is damaged"), (b"", "LATEST is damaged"), (b"step_99", "names step_99")):
        folder = copy_of(checkpointed, tmp_path, f"latest{len(content)}{content[:2].hex()}")
        (folder / "checkpoint" / "LATEST").write_bytes(content)
        assert expected in resume(folder)
    folder = copy_of(checkpointed, tmp_path, "truncated")
    (folder / "experiment.json").write_bytes((folder / "experiment.json").read_bytes()[:40])
    assert "experiment.json is not a readable experiment file" in resume(folder)
    folder = copy_of(checkpointed, tmp_path, "notadict")
    import pickle

    (folder / "checkpoint" / "step_100" / "state.pkl").write_bytes(pickle.dumps([1, 2]))
    assert "state.pkl is damaged" in resume(folder)
    for drop, cut in (("agent_rewards", False), ("observations", True)):
        folder = copy_of(checkpointed, tmp_path, f"buffer_{drop}")
        path = folder / "checkpoint" / "step_100" / "buffer.npz"
        with np.load(path) as data:
            arrays = {name: data[name] for name in data.files}
        if cut:
            arrays[drop] = arrays[drop][:10]
        else:
            del arrays[drop]
        np.savez(path, **arrays)
        line = resume(folder)
        assert "buffer.npz is missing or damaged" in line and f"'{drop}'" in line


def test_a_complete_checkpoint_without_latest_is_found(checkpointed, tmp_path):
    folder = copy_of(checkpointed, tmp_path)
    (folder / "checkpoint" / "LATEST").unlink()
    (folder / "checkpoint" / ".step_150.tmp").mkdir()  # a checkpoint a kill left half written
    (folder / ".evaluations.npz.abc.tmp").write_bytes(b"half")
    load_experiment(str(folder), verbose=0).run(resume=True)
    a, b = np.load(folder / "evaluations.npz"), np.load(checkpointed / "whole" / "evaluations.npz")
    assert np.array_equal(a["results"], b["results"])
    assert not list(folder.rglob("*.tmp"))  # leftovers of the kill are removed


def test_result_files_keep_the_umask_mode(tmp_path):
    old = os.umask(0o022)
    try:
        Experiment(single_run(tmp_path / "run", steps=40), str(tmp_path / "run"), verbose=0).run()
    finally:
        os.umask(old)
    for name in ("model.zip", "evaluations.npz", "run.json", "config.yml", "experiment.json"):
        assert os.stat(tmp_path / "run" / name).st_mode & 0o777 == 0o644, name
    config = yaml.safe_load((tmp_path / "run" / "config.yml").read_text())
    assert config["buffer_size_per_run"] == json.loads((tmp_path / "run" / "run.json").read_text())["buffer_size_per_run"]


def test_a_full_disk_during_a_checkpoint_is_one_error_naming_the_file(checkpointed, tmp_path, monkeypatch):
    import errno

    folder = copy_of(checkpointed, tmp_path)
    real_savez = np.savez

    def full(file, **arrays):
        if "hash_keys" in arrays or "agent_rewards" in arrays:  # the replay buffer's file
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_savez(file, **arrays)

    monkeypatch.setattr(np, "savez", full)
    experiment = load_experiment(str(folder), checkpoint_freq=25, verbose=0)
    with pytest.raises(ExperimentError, match=r"checkpoint at step 125 failed \(.*buffer\.npz: No space left on device\)"):
        experiment.run(resume=True)
    assert (folder / "checkpoint" / "LATEST").read_text() == "step_100"
    assert not list(folder.rglob("*.tmp")) and sorted(os.listdir(folder / "checkpoint")) == ["LATEST", "step_100"]


def test_callbacks_only_from_the_allow_list_and_writing_only_inside_the_run(tmp_path):
    for name in ("sb3_macb.__main__.Anything", "sb3_macb.callbacks.MultiAgentEvalCallback", "os.system"):
        with pytest.raises(ExperimentError, match="not one of the allowed callbacks"):
            make_callbacks({"callback": name})
    checkpoint = "stable_baselines3.common.callbacks.CheckpointCallback"
    for path in ("/tmp/elsewhere", "../up", "a/../../up"):
        with pytest.raises(ExperimentError, match="relative path inside the run's folder"):
            make_callbacks({"callback": {checkpoint: {"save_freq": 10, "save_path": path}}}, folder=str(tmp_path))
    [callback] = make_callbacks({"callback": {checkpoint: {"save_freq": 10, "save_path": "zips"}}}, folder=str(tmp_path))
    assert callback.save_path == os.path.join(str(tmp_path), "zips")


def test_eval_env_strings_are_only_registered_ids(tmp_path, monkeypatch):
    from sb3_macb.callbacks import MultiAgentEvalCallback

    marker = tmp_path / "MARKER"
    (tmp_path / "strangermod.py").write_text(f"{marker_code(marker)}\nclass Env: pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    for env_id in ("strangermod:Env", "NoSuchEnv-v0"):
        with pytest.raises(ValueError, match="not a registered gymnasium env id"):
            MultiAgentEvalCallback(env_id)
    assert not marker.exists() and "strangermod" not in sys.modules


@pytest.mark.parametrize("key", ["normalize", "monitor_kwargs", "env_wrapper", "vec_env_wrapper"])
def test_optimize_refuses_what_rl_zoo3_would_evaluate_or_import(tmp_path, capsys, monkeypatch, key):
    marker = tmp_path / "MARKER"
    value = {"normalize": marker_code(marker), "monitor_kwargs": f"dict(x={marker_code(marker)})",
             "env_wrapper": {"subprocess.getoutput": {"cmd": f"touch {marker}"}},
             "vec_env_wrapper": [{"subprocess.getoutput": {"cmd": f"touch {marker}"}}]}[key]  # fmt: skip
    conf = tmp_path / "conf.yml"
    entry = load_hyperparams(COMM, variants=["maddpg", "fast"])
    conf.write_text(yaml.safe_dump({COMM: {**entry, key: value}}))
    monkeypatch.chdir(tmp_path)
    one_line_error(capsys, ["train", "--env", COMM, "--optimize", "--n-trials", "1", "-n", "40", "-conf", str(conf),
                            "-f", str(tmp_path / "logs"), "-tb", ""], key)  # fmt: skip
    assert not marker.exists()


def test_files_that_are_not_what_they_claim(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    bad = tmp_path / "bad.yml"
    bad.write_text(f"{COMM}: [unclosed\n")
    one_line_error(capsys, ["train", "--env", COMM, "-n", "40", "-conf", str(bad)], "not valid YAML")
    listing = tmp_path / "list.yml"
    listing.write_text("- 1\n- 2\n")
    one_line_error(capsys, ["train", "--env", COMM, "-n", "40", "-conf", str(listing)], "not a YAML mapping")
    one_line_error(capsys, ["sweep", "--config", str(tmp_path / "missing.yml"), "--study-name", "s", "-f", str(tmp_path)],
                   "missing.yml")  # fmt: skip
    sweep = tmp_path / "sweep.yml"
    for conf_file, expected in (("/etc/passwd", ".yml/.yaml"), (str(listing), "not a YAML mapping")):
        sweep.write_text(
            yaml.safe_dump({"env": COMM, "grid": {"exploration.beta": [0.1]}, "seeds": [0], "conf_file": conf_file})
        )
        line = one_line_error(capsys, ["sweep", "--config", str(sweep), "--study-name", "s", "-f", str(tmp_path)], expected)
        assert "root:" not in line
    assert cli(["plot", "curves", str(tmp_path / "nothing")]) == 2
    assert "nothing does not exist" in capsys.readouterr().err


def test_an_unwritable_log_folder_is_one_line(tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    one_line_error(capsys, ["train", *FAST, "-n", "40", "-f", str(blocker / "logs")], "-f/--log-folder", "a_file")

"""The package as a wheel installs it: every subpackage and the zoo's YAML files, found without the checkout."""

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import tomllib

ROOT = Path(__file__).parent.parent


def test_the_package_list_names_every_package_and_zoo_holds_only_yaml():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    on_disk = {str(p.parent.relative_to(ROOT)).replace(os.sep, ".") for p in (ROOT / "sb3_macb").rglob("__init__.py")}
    mapped = set(config["package-dir"])
    assert on_disk | mapped == set(config["packages"]), "pyproject.toml's [tool.setuptools] packages must list every package"
    assert not (ROOT / "zoo").is_symlink()
    assert {p.suffix for p in (ROOT / "zoo").rglob("*") if p.is_file()} == {".yml"}  # nothing importable as zoo.*


def test_a_wheel_ships_the_zoo_yaml_and_the_cli_finds_its_defaults(tmp_path):
    source = tmp_path / "source"
    source.mkdir()
    for name in ("pyproject.toml", "setup.cfg", "README.md"):
        shutil.copy(ROOT / name, source)
    for name in ("sb3_macb", "zoo"):
        shutil.copytree(ROOT / name, source / name, ignore=shutil.ignore_patterns("__pycache__"))
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run([*pip, "wheel", "--no-deps", "--no-build-isolation", "-w", str(tmp_path / "dist"), str(source)],
                   check=True, capture_output=True, timeout=300)  # fmt: skip
    (wheel,) = (tmp_path / "dist").glob("sb3_macb-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {"sb3_macb/zoo/hyperparams/maddpg.yml", "sb3_macb/zoo/sweeps/table1.yml"} <= names
    site = tmp_path / "site"
    subprocess.run(
        [*pip, "install", "--no-deps", "--target", str(site), str(wheel)], check=True, capture_output=True, timeout=300
    )
    check = (
        "import os, sb3_macb\n"
        "from sb3_macb.zoo.experiment import DEFAULT_CONFIG, load_hyperparams\n"
        "assert DEFAULT_CONFIG.startswith(os.path.dirname(sb3_macb.__file__)), DEFAULT_CONFIG\n"
        "print(sorted(load_hyperparams('sb3_macb/CommunicativeNavigation-v0', variants=['fast'])))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(site)}
    done = subprocess.run([sys.executable, "-c", check], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "'policy_kwargs'" in done.stdout and "'n_timesteps'" in done.stdout


@pytest.mark.parametrize(
    "args, module", [(["train", "--help"], "yaml"), (["sweep", "--help"], "optuna"), (["plot", "simhash"], "matplotlib")]
)
def test_a_command_without_its_extra_names_the_extra_to_install(args, module, tmp_path):
    code = (
        f"import sys; sys.modules[{module!r}] = None\n"  # as if the package were not installed
        "from sb3_macb.cli import main\n"
        f"sys.exit(main({args!r}))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert done.returncode == 2, done.stderr
    assert f"no module named '{module}'" in done.stderr and "pip install 'sb3_macb[zoo]'" in done.stderr
    assert "Traceback" not in done.stderr and not list(tmp_path.iterdir())

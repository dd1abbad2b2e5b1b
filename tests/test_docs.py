"""The documentation builds without a warning (Sphinx -W), the API pages from the docstrings included."""

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).parent.parent


def test_the_docs_build_without_warnings(tmp_path):
    done = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html", str(ROOT / "docs"),
                           str(tmp_path)], capture_output=True, text=True, timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    api = (tmp_path / "api.html").read_text()
    assert "predict_agents" in api and "make_task_vec_env" in api and "fused_adam_" in api  # autodoc ran
    for page in ("envs", "maddpg", "exploration", "evaluation", "runs", "zoo", "study", "benchmarks", "performance"):
        assert (tmp_path / f"{page}.html").exists(), page
    # the study page includes the summary at the top of the study's README (one text, between two markers)
    readme = (ROOT / "experiments" / "macb_paper" / "README.md").read_text()
    summary = readme.split("<!-- summary -->\n")[1].split("<!-- /summary -->")[0]
    first_point = re.search(r"\*\*(.+?)\*\*", summary).group(1)
    assert first_point in (tmp_path / "study.html").read_text()

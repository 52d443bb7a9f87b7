"""The documentation's examples run as written: every ```python block of README.md and docs/*.md, and every
```bash line of a block marked `<!-- tested -->`, in a scratch folder that sees the repo's maps/ and models/."""
import glob
import os
import re
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PAGES = [os.path.join(ROOT, "README.md")] + sorted(glob.glob(os.path.join(ROOT, "docs", "*.md")))


def blocks(kind: str, marked: bool = False):
    for page in PAGES:
        text = open(page).read()
        pattern = (r"<!-- tested -->\s*\n" if marked else "") + rf"```{kind}\n(.*?)```"
        for i, m in enumerate(re.finditer(pattern, text, re.S)):
            yield pytest.param(m.group(1), id=f"{os.path.basename(page)}-{i}")


def scratch(tmp_path):
    for name in ("maps", "models", "results"):
        os.symlink(os.path.join(ROOT, name), tmp_path / name)
    return {**os.environ, "PYTHONPATH": ROOT, "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg"}


def test_the_docs_link_only_to_files_in_the_repo():
    for page in PAGES:
        text = open(page).read()
        assert "../shared" not in text, page
        for target in re.findall(r"\]\(([^)#:]+)\)", text):
            assert os.path.exists(os.path.join(os.path.dirname(page), target)), f"{page}: broken link {target}"


def test_the_readme_headline_is_what_the_results_say():
    import report

    text = open(os.path.join(ROOT, "README.md")).read()
    shown = re.search(r"<!-- headline[^>]*-->\n(.*?)\n<!-- /headline -->", text, re.S)
    assert shown, "README.md: no headline block"
    assert shown.group(1) == "\n".join(report.headline(report.load_results(os.path.join(ROOT, "results"))))


def test_the_readme_stays_a_front_page():
    text = open(os.path.join(ROOT, "README.md")).read()
    assert len(text.splitlines()) <= 200
    assert "Carvalho" in text and "Deep Reinforcement Learning Methods for Cooperative Robotic Navigation" in text


@pytest.mark.parametrize("code", list(blocks("python")))
def test_python_examples_run(code, tmp_path):
    env = scratch(tmp_path)
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr


@pytest.mark.parametrize("script", list(blocks("bash", marked=True)))
def test_marked_shell_examples_run(script, tmp_path):
    env = scratch(tmp_path)
    for name in glob.glob(os.path.join(ROOT, "*.py")):
        os.symlink(name, tmp_path / os.path.basename(name))
    env["PATH"] = os.path.dirname(sys.executable) + os.pathsep + env["PATH"]
    done = subprocess.run(["bash", "-euo", "pipefail", "-c", script], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]

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


def test_the_docs_link_only_to_sections_that_exist():
    """A `page.md#section` link names a heading of that page, as GitHub spells its anchor."""
    def anchor(heading):
        return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")

    for page in PAGES:
        for target, section in re.findall(r"\]\(([^)#:]*)#([^)]+)\)", open(page).read()):
            linked = os.path.join(os.path.dirname(page), target) if target else page
            headings = [anchor(h) for h in re.findall(r"^#+ (.*)$", open(linked).read(), re.M)]
            assert section in headings, f"{page}: no section #{section} in {target or 'this page'}"


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


# ----------------------------------------------------------------------------- generated or absent
EXPERIMENTS = os.path.join(ROOT, "docs", "experiments.md")  # a record of past measurements, each at a named commit
BLOCK = re.compile(r"<!-- ([\w-]+): report\.(\w+)[^>]*-->\n(.*?)\n<!-- /\1 -->", re.S)
# dissertation references, and the Python version the README states: not measured figures
REFERENCE = re.compile(r"(?:\bTables?|\bFigs?\.|\beqs?\.|§|\bAlgorithms?|\bchapters?|Python ≥)\s*\d+(?:\.\d+)*"
                       r"(?:\s*[–-]\s*\d+(?:\.\d+)*)?", re.I)
FLAG_VALUE = re.compile(r"--[\w-]+[ =][^\s,;)]+")
FIGURE = re.compile(
    r"\d+\.\d+"                                                       # a decimal: 0.038, 1.28×, 23.6 min
    r"|\d\s*%"                                                        # a percentage: 62.9%, 100%
    r"|\d[\d,]*\s*[kKM]?\s+(?:[A-Za-z-]+\s+)?[A-Za-z-]*/s\b"          # a rate: 933 env steps/s, 46k agent-steps/s
    r"|\d[\d,]*\s*[kKM]?[A-Za-z-]*/s\b"
    r"|\d[\d,]*\s*(?:ms|µs|s|sec|min|minutes|h|hours|CPU-hours|MB|GB|GiB|MiB|KB)\b"  # a time or a size: 45 s, 2 h
    r"|\d×(?!\d)")                                                  # a factor: 8× faster (not a 5×5 map)
RETIRED = ("departures.py", "label_symmetry.py", "rollout_agreement.py", "rollout_labels.py", "tie_features.py",
           "team_overlap.py")  # diagnostics retired with issue 45; their code stays at commit ce6bf6e
MEASURED_IN_CODE = re.compile(r"\d\s*%|\b(?:overlap|time-save|t_sf|steps/s|labels/s)\W+\d")


def prose(text: str) -> list[tuple[int, str]]:
    """The page's lines as a reader reads them: without code blocks, generated blocks, comments, link targets, code
    spans that are code (flags, settings, calls), flag values and dissertation references."""
    def blank(m):  # keep the line numbers
        return "\n" * m.group(0).count("\n")

    text = re.sub(r"```.*?```", blank, text, flags=re.S)
    text = BLOCK.sub(blank, text)
    text = re.sub(r"<!--.*?-->", blank, text, flags=re.S)
    text = re.sub(r"\]\([^)]*\)", "]", text)
    text = re.sub(r"`([^`\n]*)`", lambda m: m.group(1) if MEASURED_IN_CODE.search(m.group(1))
                  or not re.search(r"[A-Za-z_]", m.group(1)) else "", text)
    text = REFERENCE.sub("", FLAG_VALUE.sub("", text))
    return list(enumerate(text.splitlines(), 1))


def hand_typed(text: str) -> list[str]:
    return [f"{n}: {m.group(0)!r} in {line.strip()[:120]!r}" for n, line in prose(text) for m in FIGURE.finditer(line)]


def test_the_figure_check_catches_what_it_should():
    for typed in ("overlap 0.038 on cpp_eval", "completion 62.9% alone", "it runs 933 env steps/s",
                  "about 46k agent-steps/s", "2,113 labels/s", "45 s an episode", "in 23 min", "5–8× faster",
                  "a 0.55 MB file", "the agent `overlap 0.109` line"):
        assert hand_typed(typed), typed
    for fine in ("Table 6.1's 5e-5", "Figs. 6.17–6.22 and eq. 6.21", "§6.4.2.4 (p as `--imitation 0.9`)",
                 "Python ≥ 3.11", "`--learning-rate 5e-4`", "5×5 maps, sizes 5–30", "Tables 6.2–6.3",
                 "```bash\npython x.py --steps 2000  # 5 min\n```", "[RESULTS.md](../results/RESULTS.md#a-62-b)",
                 "<!-- x: report.f -->\n| 0.039 |\n<!-- /x -->"):
        assert not hand_typed(fine), fine


@pytest.mark.parametrize("page", [p for p in PAGES if p != EXPERIMENTS], ids=os.path.basename)
def test_no_figure_is_typed_by_hand(page):
    """Every measured number (overlap, %, steps/s, times, sizes) sits in a block report.py renders from results/ (the
    test below checks it) or is not on the page: a page links the section of results/RESULTS.md instead. The
    experiments log, a record of measurements at named commits, is exempt."""
    found = hand_typed(open(page).read())
    assert not found, f"{os.path.relpath(page, ROOT)}: figures typed by hand:\n" + "\n".join(found)


def test_every_rendered_block_is_what_the_results_say():
    """`<!-- name: report.function ... -->` ... `<!-- /name -->`: the lines between are report.function(results)."""
    import report

    results = report.load_results(os.path.join(ROOT, "results"))
    seen = 0
    for page in PAGES:
        for name, function, shown in BLOCK.findall(open(page).read()):
            seen += 1
            expected = "\n".join(getattr(report, function)(results))
            assert shown == expected, f"{os.path.basename(page)}: block {name} is stale; it should read:\n{expected}"
    assert seen >= 3


@pytest.mark.parametrize("page", PAGES, ids=os.path.basename)
def test_every_page_is_short(page):
    assert len(open(page).read().splitlines()) <= (200 if page.endswith("README.md") else 300), page


def test_the_docs_name_every_benchmark_and_only_the_ones_here():
    """Each script in benchmarks/ is named where its figure is discussed; a retired one is named only in the
    experiments log (its code stays at the commit the log gives)."""
    text = {page: open(page).read() for page in PAGES}
    for script in glob.glob(os.path.join(ROOT, "benchmarks", "*.py")):
        name = f"benchmarks/{os.path.basename(script)}"
        assert any(name in t for t in text.values()), f"no page names {name}"
    for page, t in text.items():
        if page != EXPERIMENTS:
            for name in re.findall(r"benchmarks/\w+\.py", t):
                assert os.path.exists(os.path.join(ROOT, name)) and os.path.basename(name) not in RETIRED, \
                    f"{os.path.basename(page)} names {name}, retired"
    for name in RETIRED:
        assert f"benchmarks/{name}" in text[EXPERIMENTS], name

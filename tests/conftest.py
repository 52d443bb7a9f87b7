"""Fixtures shared by several test files."""
import signal

import numpy as np
import pytest

import classical_cpp as cc
import gridworld as gw


def from_rows(rows: list[str]) -> gw.Scenario:
    """A map drawn in text: '.' free, '@' obstacle, 'x' pre-covered, digits = agent starts in index order (covered)."""
    chars = np.array([list(r) for r in rows])
    digits = np.char.isdigit(chars)
    starts = np.argwhere(digits)[np.argsort(chars[digits].astype(int))]
    return cc.with_starts(gw.Scenario(chars == "@", starts, chars == "x"))


@pytest.fixture
def heuristic_ties(monkeypatch) -> list:
    """The (dead_ends_first, far_first) arguments of every gridworld.heuristic_actions call, in order."""
    seen = []
    original = gw.heuristic_actions

    def recording(core, random_ties=True, dead_ends_first=False, far_first=False):
        seen.append((dead_ends_first, far_first))
        return original(core, random_ties, dead_ends_first, far_first)

    monkeypatch.setattr(gw, "heuristic_actions", recording)
    return seen


@pytest.fixture
def restore_sigint():
    """The trainers catch Ctrl-C and SIGTERM while they run; a test that fails inside one leaves the handlers as they
    were."""
    old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    yield
    for s, handler in old.items():
        signal.signal(s, handler)


@pytest.fixture
def small_report_maps(monkeypatch):
    """A function cutting the planner report's map subsets to a few small maps (cpp_eval sizes up to `max_size` in
    two bands, two external episodes on empty-8-8, `layouts` marl_eval layouts, at most `structured` structured_eval
    maps per family, of size 10, and the first `structured` structured_eval maps for the team rollout), so that a
    report runs in seconds."""
    cpp, ext, marl, structured_subset = cc.cpp_eval_subset, cc.external_episodes, cc.marl_eval_subset, \
        cc.structured_eval_subset
    team = cc.structured_team_subset

    def shrink(max_size: int, layouts: int, structured: int = 1) -> None:
        monkeypatch.setattr(cc, "STRUCTURED_BANDS", ((10, 10),))
        monkeypatch.setattr(cc, "structured_eval_subset", lambda per_band: structured_subset(min(per_band, structured)))
        def cpp_subset(per_size):
            scenarios, sizes = cpp(per_size)
            keep = np.flatnonzero(sizes <= max_size)
            return [scenarios[i] for i in keep], sizes[keep]

        monkeypatch.setattr(cc, "cpp_eval_subset", cpp_subset)
        monkeypatch.setattr(cc, "REPORT_BANDS", ((5, 6), (7, max_size)))
        monkeypatch.setattr(cc, "external_episodes", lambda: [e for e in ext() if e[0] == "empty-8-8.map"][:2])
        monkeypatch.setattr(cc, "marl_eval_subset", lambda agents, every=cc.MARL_EVERY: tuple(
            x[:layouts] for x in marl(agents, every)))
        monkeypatch.setattr(cc, "structured_team_subset", lambda agents, every: tuple(
            x[:structured] for x in team(agents, 1)))

    return shrink


def one_line_error(result, *words) -> str:
    """A failed CLI run's stderr: one `error: ...` line, no traceback, naming every word given."""
    assert result.returncode != 0
    assert "Traceback" not in result.stderr
    err = result.stderr.strip()
    assert err.startswith("error: ") and "\n" not in err, err
    for w in words:
        assert w in err, err
    return err


def tiny_trainer_args(t, **kw):
    """A trainer's Args (rainbow_cpp or rainbow_marl module `t`) for a run of a few dozen steps of a tiny compact
    network in runs/t, on the CPU, writing nothing but its run folder."""
    base = dict(run_name="t", total_steps=32, num_envs=2, learning_starts=16, buffer_size=2000, hidden=16,
                eval_every=0, save_every=0, quiet=True, cuda=False, network="compact", conv_width=8)
    if t.SCRIPT == "rainbow_marl":
        base["init_from"] = ""
    return t.Args(**{**base, **kw})

"""Fixtures shared by the trainers' tests."""
import signal

import pytest

import gridworld as gw


@pytest.fixture
def heuristic_ties(monkeypatch) -> list:
    """The dead_ends_first argument of every GridWorldCore.heuristic_actions call, in order."""
    seen = []
    original = gw.GridWorldCore.heuristic_actions

    def recording(self, random_ties=True, dead_ends_first=False):
        seen.append(dead_ends_first)
        return original(self, random_ties, dead_ends_first)

    monkeypatch.setattr(gw.GridWorldCore, "heuristic_actions", recording)
    return seen


@pytest.fixture
def restore_sigint():
    """The trainers catch Ctrl-C while they run; a test that fails inside one leaves the handler as it was."""
    old = signal.getsignal(signal.SIGINT)
    yield
    signal.signal(signal.SIGINT, old)

"""Tests for the multiagent rollout: gridworld.team_rollout_actions (Bertsekas 2020: agents choose in index order,
each try finished by greedy-dead-ends with claims) and the rollout planner with several agents (classical_cpp).

team_rollout_actions: with one agent it is rollout_actions; on a corridor where the claims send both agents into the
same half it sends agent 0 the other way (hand-computed); legal moves only; WAIT for frozen and absent agents and the
heuristic's moves in finished worlds; max_steps keeps the heuristic's moves; the core and its random stream are left
as they were. The planner: never a longer makespan than its base on small random maps, legal and complete
(classical_cpp.replay); the command line plans for several agents and rejects a bad option in one line.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from conftest import from_rows  # noqa: E402

import classical_cpp as cc  # noqa: E402
import gridworld as gw  # noqa: E402


def random_maps(n: int, agents: int, seed: int) -> list[gw.Scenario]:
    """n connected random maps of 4x4 to 7x7 with 0-10 obstacles and `agents` starts."""
    rng = np.random.default_rng(seed)
    maps = []
    for _ in range(n):
        (s,) = gw.generate_scenarios(1, seed=int(rng.integers(1 << 30)), size=int(rng.integers(4, 8)),
                                     number_agents=agents, number_obstacles=int(rng.integers(0, 11)),
                                     obstacles_random=True)
        maps.append(cc.with_starts(gw.Scenario(s.obstacles, s.starts)))
    return maps


def core_of(maps: list[gw.Scenario], **config) -> gw.GridWorldCore:
    n = max(len(s.starts) for s in maps)
    core = gw.GridWorldCore(gw.EnvConfig(load_state=True, load_random=False, battery_factor=1e6, number_agents=n,
                                         **config), len(maps))
    core.configure(scenarios=maps)
    core.reset()
    return core


def mid_episode(maps: list[gw.Scenario], steps: int, seed: int) -> gw.GridWorldCore:
    """A core some random moves into its episodes (some coverage and history)."""
    core = core_of(maps)
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        core.step(rng.integers(0, 5, (core.B, core.N)))
    return core


def makespan(scenarios, paths) -> np.ndarray:
    return np.array([cc.replay(s, p)["steps"] for s, p in zip(scenarios, paths)])


# ----------------------------------------------------------------------------- team_rollout_actions
def test_one_agent_is_rollout_actions():
    core = mid_episode(random_maps(24, 1, seed=4), steps=3, seed=1)
    core.freeze([5], 0)
    want = gw.rollout_actions(core)
    got = gw.team_rollout_actions(core)
    assert got.shape == (24, 1) and got[:, 0].tolist() == want.tolist()
    pick = np.arange(23, -1, -4)
    assert gw.team_rollout_actions(core, pick)[:, 0].tolist() == want[pick].tolist()  # any subset, in its order
    mask = np.arange(24) % 3 == 0
    assert gw.team_rollout_actions(core, mask)[:, 0].tolist() == want[mask].tolist()
    assert gw.team_rollout_actions(core, max_steps=2)[:, 0].tolist() == gw.rollout_actions(core, max_steps=2).tolist()


# A corridor of 7 cells, agent 1 at the West end, agent 0 three cells East of it: 5 points of interest. The claims
# (nearest agent-target pair first, the lower index and then row-major order on ties) give agent 0 the cell West of it,
# so both agents work the West part, agent 1 is blocked behind agent 0 once, and agent 0 walks back East to the two
# cells left there: 6 steps. The team rollout tries agent 0's moves with agent 1 on its heuristic move: East covers the
# East end while agent 1 sweeps the West part, 3 steps, the lower bound ceil(5 / 2).
CORRIDOR = ["1...0.."]


def test_team_rollout_splits_the_corridor_the_claims_do_not():
    s = from_rows(CORRIDOR)
    (base,) = cc.plan("greedy-dead-ends", [s])
    assert [p[:, 1].tolist() for p in base] == [[4, 3, 2, 3, 4, 5, 6], [0, 1, 1, 2, 3, 4, 4]]
    core = core_of([s])
    assert gw.heuristic_actions(core, False, True).tolist() == [[gw.WEST, gw.EAST]]
    assert gw.team_rollout_actions(core).tolist() == [[gw.EAST, gw.EAST]]
    assert gw.team_rollout_actions(core, max_steps=1).tolist() == [[gw.WEST, gw.EAST]]  # no try finishes in one step
    (paths,) = cc.plan("rollout", [s])
    assert [p[:, 1].tolist() for p in paths] == [[4, 5, 6, 6], [0, 1, 2, 3]]
    b, r = cc.replay(s, base), cc.replay(s, paths)
    assert (b["steps"], b["revisits"], r["steps"], r["revisits"]) == (6, 5, 3, 0)
    assert r["steps"] == cc.lower_bound(s)


def test_moves_are_legal_and_idle_agents_wait():
    maps = random_maps(10, 3, seed=7)
    maps[3] = gw.Scenario(maps[3].obstacles, maps[3].starts[:2], maps[3].covered)  # its agent 2 is absent
    core = mid_episode(maps, steps=2, seed=3)
    core.freeze([1, 6], 1)
    out = gw.team_rollout_actions(core)
    assert out.shape == (10, 3) and out.min() >= 0 and out.max() <= gw.WAIT
    target = core.pos + core.delta[out]
    assert not (core.views["obstacle"][target] & (out != gw.WAIT)).any()  # never into an obstacle
    assert out[3, 2] == gw.WAIT and out[1, 1] == gw.WAIT and out[6, 1] == gw.WAIT
    finished = core_of([from_rows(["0.1"])])  # one point of interest, covered by the first step
    finished.step(np.array([[gw.EAST, gw.WAIT]]))
    assert finished.remaining[0] == 0
    assert gw.team_rollout_actions(finished).tolist() == gw.heuristic_actions(finished, False, True).tolist()


def test_the_core_is_left_as_it_was():
    core = mid_episode(random_maps(6, 2, seed=9), steps=3, seed=2)
    before = {k: getattr(core, k).copy() for k in gw.GridWorldCore.WORLD_ARRAYS}
    rng_state = core.rng.bit_generator.state
    gw.team_rollout_actions(core, [0, 2, 5])
    for k, v in before.items():
        assert np.array_equal(getattr(core, k), v), k
    assert core.rng.bit_generator.state == rng_state
    assert gw.team_rollout_actions(core, []).shape == (0, 2)


# ----------------------------------------------------------------------------- the rollout planner, several agents
@pytest.mark.parametrize("agents,seed", [(2, 0), (3, 1)])
def test_team_rollout_never_worse_than_its_base(agents, seed):
    maps = random_maps(12, agents, seed)
    for base in ("greedy-dead-ends", "greedy"):
        want = makespan(maps, cc.plan(base, maps))
        paths = cc.plan("rollout", maps, rollout_base=base)
        got = makespan(maps, paths)  # replay raises unless every path is legal and covers the map
        assert (got <= want).all(), (base, got, want)
    (alone,) = cc.plan("rollout", [maps[5]], rollout_base="greedy")  # maps do not interact in the batch
    for p, q in zip(alone, paths[5]):
        np.testing.assert_array_equal(p, q)


def test_mixed_agent_counts_and_the_one_agent_path():
    one, two = random_maps(3, 1, seed=11), random_maps(3, 2, seed=12)
    mixed = cc.plan("rollout", [two[0], one[0], two[1], one[1], one[2], two[2]])
    for got, want in zip(mixed, [*cc.team_rollout_many([two[0]]), *cc.rollout_many([one[0]]), *cc.team_rollout_many([two[1]]),
                                 *cc.rollout_many(one[1:]), *cc.team_rollout_many([two[2]])]):
        assert len(got) == len(want) and all((p == q).all() for p, q in zip(got, want))
    assert [len(p) for p in cc.rollout(two[0])] == [len(p) for p in mixed[0]]


def test_cli_rollout_several_agents():
    cmd = [sys.executable, "classical_cpp.py", "--planner", "rollout", "--agents", "2", "--maps",
           "maps/external/empty-8-8.map", "--quiet"]
    result = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "rollout: 1 scenario(s), 2 agent(s) each" in result.stdout
    bad = subprocess.run(cmd + ["--rollout-base", "lkh"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert bad.returncode != 0 and "rollout base" in bad.stderr and "Traceback" not in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1

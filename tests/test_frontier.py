"""The frontier baselines of evaluate.py: the navigation heuristic on the agent's known map (`frontier`, dead-ends-first
ties; `frontier-row-major`) and its one-step rollout planned on the known map (`frontier-rollout`,
gw.rollout_actions(GridWorldCore, view="known")).

By hand: a pre-covered corridor sends the agent to its nearest frontier. With the full sensor frontier is the planner
greedy-dead-ends (row-major: greedy) and frontier-rollout the planner rollout, episode by episode; frontier-rollout is
never longer than frontier. Camera and LiDAR coincide at sensor range 1 (§6.5.3.2). With nothing pre-covered and no
sensor failure the heuristic on the known map is the full-information one (range >= 2; row-major: >= 1).
rollout_actions(view="known") is the rollout on the optimistic map (unknown cells free points of interest, those walled
in by known obstacles obstacles). Every episode completes; sensors, --compare and --video work; bad input is one line.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import one_line_error

import classical_cpp as cc
import evaluate
import gridworld as gw

ROOT = Path(__file__).resolve().parent.parent


def random_maps(n: int, seed: int = 0, sizes=(4, 9), obstacles=(0, 13)) -> list[tuple[str, gw.Scenario]]:
    """n connected random maps (name, scenario with its start covered) of sizes in [sizes) with obstacles in [obstacles)."""
    rng = np.random.default_rng(seed)
    maps = []
    for i in range(n):
        (s,) = gw.generate_scenarios(1, seed=int(rng.integers(1 << 30)), size=int(rng.integers(*sizes)),
                                     number_obstacles=int(rng.integers(*obstacles)), obstacles_random=True)
        maps.append((f"map{i}", cc.with_starts(gw.Scenario(s.obstacles, s.starts))))
    return maps


def run(policy: str, episodes, **kw) -> list[dict]:
    return evaluate.run_frontier(evaluate.Args(policy=policy, quiet=True, **kw), episodes)


def steps(rows: list[dict]) -> list[int]:
    return [r["steps"] for r in rows]


# ----------------------------------------------------------------------------- by hand
@pytest.mark.parametrize("sensor, sensor_range", [("camera", 1), ("camera", 3), ("lidar", 1), ("lidar", 3)])
def test_pre_covered_corridor_sends_the_agent_to_its_nearest_frontier(tmp_path, sensor, sensor_range):
    """1x9 corridor, agent at column 4, everything covered but column 8 (the agent cannot know it). Known cells are all
    covered, so the targets are the two frontier cells, equally near (columns 4 -+ K, next to the unseen): row-major
    order (and equal dead-end degrees, 0) takes WEST; the agent walks west until column 0 is known (at column K),
    then east until column 8 is known (at column 8 - K) and on to it: 4 - K + 8 - K = 12 - 2K steps, one new cell.
    The full-information heuristic walks 4 steps east."""
    path = tmp_path / "corridor.txt"
    path.write_text("xxxx0xxx.\n")
    args = dict(maps=(str(path),), out=str(tmp_path / "out"), quiet=True, overwrite=True)  # one folder, three runs
    for policy in ("frontier", "frontier-row-major"):
        evaluate.main(evaluate.Args(policy=policy, sensor=sensor, sensor_range=sensor_range, compare="greedy-dead-ends",
                                    **args))
        table = json.loads((tmp_path / "out" / "compare.json").read_text())["all"]
        want = 12 - 2 * sensor_range
        assert table[policy] == dict(episodes=1, overlap=want - 1, time_save=want, completion_rate=1.0)
        assert table["greedy-dead-ends"]["time_save"] == 4.0
    evaluate.main(evaluate.Args(policy="frontier", **args))  # full sensor: the heuristic with full information
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["all"]["steps"]["mean"] == 4.0


@pytest.mark.parametrize("policy", ["frontier", "frontier-row-major", "frontier-far-first"])
def test_a_point_of_interest_seen_through_a_wall_does_not_stop_the_agent(tmp_path, policy):
    """5x5, agent at (0, 1), camera K=2 (through walls): it knows rows 0-2, columns 0-3. The only known point of
    interest, (2, 3), is walled in on its known sides; its way in, (2, 4) or (3, 3), is unseen. Waiting for a path to
    it would wait until truncation: the heuristic heads for the frontier instead. The nearest frontier cells are (0, 3)
    and (2, 1), two steps away; (0, 3) has no target neighbour and comes first in row-major order: EAST. Then the
    agent finds the way in and covers both points of interest."""
    path = tmp_path / "pocket.txt"
    path.write_text("x0xxx\nxx##x\nxx#..\nxxx#x\nxxxxx\n")
    paths = {0: None}
    scenario = gw.load_map(str(path))
    rows = evaluate.run_frontier(evaluate.Args(policy=policy, sensor="camera", sensor_range=2, quiet=True),
                                 [("pocket", scenario)], paths)
    assert paths[0][1, 0].tolist() == [0, 2]
    assert rows[0]["completed"] and not rows[0]["truncated"]
    core = gw.GridWorldCore(gw.EnvConfig(sensor="camera", sensor_range=2), 1)  # the same world, one heuristic call
    core.reset(scenarios=[scenario])
    assert gw.heuristic_actions(core, False, policy != "frontier-row-major", policy == "frontier-far-first")[0, 0] == gw.EAST


def test_at_range_1_dead_ends_first_counts_only_known_neighbours():
    """2x6 room, agent at (0, 0), camera K=1: it knows columns 0-1. The nearest points of interest (0, 1) and (1, 0)
    have one known target neighbour each ((1, 1); (0, 2) is unseen), so row-major order takes (0, 1): EAST, and so on
    along row 0 (at (0, c) the cell ahead has one target neighbour, (1, c) two), then back along row 1: 11 steps.
    With full information (0, 1) has two target neighbours and (1, 0) one: greedy-dead-ends goes SOUTH first."""
    episodes = [("room", cc.with_starts(gw.Scenario(np.zeros((2, 6), bool), np.array([[0, 0]]))))]
    paths = {0: None}
    rows = evaluate.run_frontier(evaluate.Args(policy="frontier", sensor="camera", sensor_range=1, quiet=True),
                                 episodes, paths)
    assert paths[0][:, 0].tolist() == [[0, c] for c in range(6)] + [[1, c] for c in range(5, -1, -1)]
    assert rows[0]["steps"] == 11 and rows[0]["overlap"] == 0 and rows[0]["completed"]
    assert cc.plan("greedy-dead-ends", [episodes[0][1]])[0][0][1].tolist() == [1, 0]


# ----------------------------------------------------------------------------- against the planners
def test_with_the_full_sensor_frontier_is_greedy_dead_ends_and_frontier_rollout_is_rollout():
    episodes = random_maps(12, seed=1)
    for policy, planner in (("frontier", "greedy-dead-ends"), ("frontier-row-major", "greedy"),
                            ("frontier-far-first", "greedy-far-first"), ("frontier-rollout", "rollout")):
        mine, theirs = run(policy, episodes), evaluate.run_planner(planner, episodes)
        assert [(r["steps"], r["overlap"]) for r in mine] == [(r["steps"], r["overlap"]) for r in theirs], policy


def test_frontier_rollout_is_never_longer_than_frontier_with_the_full_sensor():
    """The rollout of a deterministic policy with full information is never worse than the policy (Bertsekas)."""
    episodes = random_maps(10, seed=2, sizes=(5, 9))
    base, rollout = steps(run("frontier", episodes)), steps(run("frontier-rollout", episodes))
    assert all(r <= b for r, b in zip(rollout, base))
    assert np.mean(rollout) < np.mean(base)


@pytest.mark.parametrize("policy", list(evaluate.FRONTIER))
def test_camera_and_lidar_coincide_at_sensor_range_1(policy):
    """At K=1 the LiDAR's lines of sight have no cell between the agent and its 8 neighbours (§6.5.3.2)."""
    episodes = random_maps(8, seed=3, obstacles=(4, 13))
    camera, lidar = (run(policy, episodes, sensor=s, sensor_range=1) for s in ("camera", "lidar"))
    assert camera == lidar
    assert all(r["completed"] for r in camera)


@pytest.mark.parametrize("policy, planner, least", [("frontier", "greedy-dead-ends", 2), ("frontier-row-major", "greedy", 1)])
@pytest.mark.parametrize("sensor", ["camera", "lidar"])
def test_the_known_map_holds_what_the_heuristic_needs(policy, planner, least, sensor):
    """With nothing pre-covered and no sensor failure, every cell nearer than the nearest point of interest has been
    walked, so that point is next to the walked path and seen; dead-ends-first also counts its neighbours, 2 cells
    from the path: from range 2 the heuristic on the known map is the one with full information, episode by episode
    (at range 1 dead-ends-first does miss some)."""
    episodes = random_maps(24, seed=4, obstacles=(4, 13))
    want = steps(evaluate.run_planner(planner, episodes))
    assert steps(run(policy, episodes, sensor=sensor, sensor_range=least)) == want
    if least == 2:
        assert steps(run(policy, episodes, sensor=sensor, sensor_range=1)) != want


@pytest.mark.parametrize("sensor, sensor_range, failure", [("camera", 1, 0.0), ("lidar", 2, 0.0), ("camera", 2, 0.5)])
def test_every_episode_completes_under_a_sensor(sensor, sensor_range, failure):
    episodes = random_maps(8, seed=5, obstacles=(4, 13))
    for policy in evaluate.FRONTIER:
        rows = run(policy, episodes, sensor=sensor, sensor_range=sensor_range, sensor_failure=failure)
        assert all(r["completed"] and not r["truncated"] for r in rows), policy
        if failure:  # the failures are drawn from --seed
            assert rows == run(policy, episodes, sensor=sensor, sensor_range=sensor_range, sensor_failure=failure)


def test_rainbow_under_sensor_failures_is_repeatable_and_follows_the_seed():
    """The failures are drawn from --seed for the agent as for the baselines: the same seed, the same episodes."""
    episodes = random_maps(8, seed=5, obstacles=(4, 13))

    def rainbow(seed):
        args = evaluate.Args(policy="rainbow", sensor="camera", sensor_range=2, sensor_failure=0.5, seed=seed, quiet=True)
        return [(r["steps"], r["revisits"]) for r in evaluate.run_rainbow(args, episodes)]

    assert rainbow(0) == rainbow(0) != rainbow(1)


# ----------------------------------------------------------------------------- rollout_actions(view="known")
def optimistic(core: gw.GridWorldCore, b: int) -> tuple[gw.Scenario, int]:
    """World b as the agent knows it: unknown cells free and uncovered where the agent can reach them, else obstacles;
    and how many unknown cells are walled in."""
    c, (h, w) = core.c, core.hw[b]
    inner = (b, slice(c, c + h), slice(c, c + w))
    seen, obstacle, covered = core.seen[inner], core.obstacle[inner], core.covered[inner]
    open_ = ~obstacle | ~seen
    reach = np.zeros_like(open_)
    reach[tuple(core.agent_cells()[b, 0])] = True
    for _ in range(h * w):  # grow the reached cells one step at a time through the open ones
        grown = reach.copy()
        grown[1:] |= reach[:-1]
        grown[:-1] |= reach[1:]
        grown[:, 1:] |= reach[:, :-1]
        grown[:, :-1] |= reach[:, 1:]
        grown &= open_
        if (grown == reach).all():
            break
        reach = grown
    return gw.Scenario(~reach, core.agent_cells()[b], covered & seen), int((~seen & ~reach).sum())


@pytest.mark.parametrize("sensor, sensor_range", [("camera", 1), ("lidar", 3)])
def test_known_view_is_the_full_rollout_on_the_optimistic_map(sensor, sensor_range):
    """Mid-episode worlds under a short sensor: rollout_actions(view="known") is, world by world, rollout_actions() on a
    full-sensor world of the optimistic map. Some LiDAR worlds hide a cell behind known obstacles only: had it counted
    as a point of interest, no imagined world would finish."""
    maps = [s for _, s in random_maps(24, seed=6, sizes=(6, 7), obstacles=(8, 16))]
    core = gw.GridWorldCore(gw.EnvConfig(load_state=True, load_random=False, sensor=sensor, sensor_range=sensor_range),
                            len(maps))
    core.configure(scenarios=maps)
    core.reset()
    for _ in range(8):
        core.step(gw.heuristic_actions(core, False, True))
    live = np.flatnonzero(core.remaining > 0)
    known = gw.rollout_actions(core, live, view="known")
    worlds, walled_in = zip(*(optimistic(core, b) for b in live))
    full = gw.GridWorldCore(gw.EnvConfig(load_state=True, load_random=False), len(worlds))
    full.configure(scenarios=list(worlds))
    full.reset()
    assert known.tolist() == gw.rollout_actions(full).tolist()
    if sensor == "lidar":
        assert any(walled_in)


def test_known_view_with_the_full_sensor_is_the_full_view_and_bad_views_are_refused():
    maps = [s for _, s in random_maps(6, seed=7)]
    core = gw.GridWorldCore(gw.EnvConfig(load_state=True, load_random=False), len(maps))
    core.configure(scenarios=maps)
    core.reset()
    assert gw.rollout_actions(core, view="known").tolist() == gw.rollout_actions(core).tolist()
    with pytest.raises(ValueError, match="view must be 'full' or 'known'"):
        gw.rollout_actions(core, view="seen")


# ----------------------------------------------------------------------------- evaluate.py
def test_compare_with_rainbow_under_a_sensor_runs_the_same_episodes_and_films(tmp_path):
    path = tmp_path / "room.txt"
    path.write_text("......\n.@@...\n......\n...@..\n")
    starts = tmp_path / "starts.json"
    starts.write_text(json.dumps({"room.txt": [[0, 0], [3, 5]]}))
    out, video = tmp_path / "out", tmp_path / "video"
    evaluate.main(evaluate.Args(policy="rainbow", maps=(str(path),), starts=str(starts), sensor="camera", sensor_range=3,
                                compare="frontier,frontier-rollout", video=str(video), out=str(out), quiet=True))
    table = json.loads((out / "compare.json").read_text())
    assert table["policies"] == ["rainbow", "frontier", "frontier-rollout"] and table["episodes"] == 2
    assert all(table["all"][p]["completion_rate"] == 1.0 for p in table["policies"])
    assert (out / "compare.png").exists()
    evaluate.main(evaluate.Args(policy="frontier-rollout", maps=(str(path),), starts=str(starts), sensor="lidar",
                                sensor_range=2, video=str(tmp_path / "v2"), out=str(tmp_path / "o2"), quiet=True))
    assert sorted(p.name for p in (tmp_path / "v2").iterdir()) == ["000-room-txt.mp4", "000-room-txt.png"]


@pytest.mark.parametrize("flags, words", [
    (["--policy", "frontier", "--agents", "2"], ["frontier is single-agent", "--agents 1"]),
    (["--policy", "partition", "--agents", "2", "--compare", "frontier-rollout"], ["frontier-rollout is single-agent"]),
    (["--policy", "frontier-row-major", "--action-loss", "0.1"], ["--action-loss"]),
    (["--policy", "frontier", "--sensor", "sonar"], ["--sensor must be one of"]),
    (["--policy", "frontier", "--sensor-range", "0"], ["--sensor-range must be >= 1"]),
])
def test_bad_input_is_a_one_line_error(tmp_path, flags, words):
    (tmp_path / "room.txt").write_text("....\n.@..\n....\n")
    result = subprocess.run([sys.executable, "evaluate.py", "--maps", str(tmp_path / "room.txt"), "--out",
                             str(tmp_path / "out"), *flags], cwd=ROOT, capture_output=True, text=True)
    one_line_error(result, *words)
    assert not (tmp_path / "out").exists()


"""The multiscale observation (EnvConfig.observation = "multiscale", GitHub issue 16 item 2).

Specification checked here against a slow reference written with explicit loops:

- "map" (B, N, scales * 5, v, v) uint8, v = scale_view, scale-major; channels per scale [points of interest,
  covered, obstacle, agents, frontier].
- Scale s has blocks of b x b map cells, b = scale_factor**s; block [i, j] covers map rows
  y - b//2 + (i - v//2) * b ... + b - 1 and cols x - b//2 + (j - v//2) * b ... + b - 1 around the agent's
  cell [y, x] (odd b: the agent's cell is the centre of the centre block; even b: it is the cell below and
  right of the centre).
- POI, covered, obstacle and agents are round-half-up(255 * cells / b**2); a cell outside the map is an
  obstacle; an unseen cell is none of them. Frontier is 255 if any cell of the block is a seen free map cell
  with an unseen 4-neighbour inside the map, else 0.
- "out_of_bounds" (eq. 6.5) counts, per direction N, S, W, E, the map rows/cols and known points of interest
  beyond the coarsest scale's blocks (not beyond the deep window's core); "last_action" and "battery" are
  those of the deep observation.
"""
from __future__ import annotations

import math
from fractions import Fraction

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import gridworld as gw
from gridworld import EnvConfig, GridWorldCore, GridWorldParallelEnv, GridWorldVectorEnv, Scenario

POI, COV, OBS, AG, FR = range(5)


# ----------------------------------------------------------------------------- the slow reference
def cell_table(core: GridWorldCore, b: int) -> np.ndarray:
    """(h, w, 5) int: the five channels (0/1) of every map cell of world b, one cell at a time."""
    c = core.c
    h, w = (int(v) for v in core.hw[b])
    seen = core.seen[b, c:c + h, c:c + w]
    obst = core.obstacle[b, c:c + h, c:c + w]
    cov = core.covered[b, c:c + h, c:c + w]
    occ = core.occupied[b, c:c + h, c:c + w]
    out = np.zeros((h, w, 5), np.int64)
    for y in range(h):
        for x in range(w):
            if not seen[y, x]:
                continue  # unseen: nothing
            if obst[y, x]:
                out[y, x, OBS] = 1
            else:
                out[y, x, COV if cov[y, x] else POI] = 1
                out[y, x, FR] = any(0 <= y + dy < h and 0 <= x + dx < w and not seen[y + dy, x + dx]
                                    for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1)))
            out[y, x, AG] = occ[y, x]
    return out


def round_half_up(n: int, area: int) -> int:
    return math.floor(Fraction(255 * n, area) + Fraction(1, 2))


def reference(core: GridWorldCore) -> np.ndarray:
    cfg = core.config
    S, f, v = cfg.scales, cfg.scale_factor, cfg.scale_view
    pad = v * f ** (S - 1)  # more than any block reaches past the agent
    out = np.zeros((core.B, core.N, S * 5, v, v), np.uint8)
    cells = core.agent_cells()
    for b in range(core.B):
        table = cell_table(core, b)
        h, w = table.shape[:2]
        padded = np.zeros((h + 2 * pad, w + 2 * pad, 5), np.int64)
        padded[..., OBS] = 1  # out of the map: obstacle
        padded[pad:pad + h, pad:pad + w] = table
        for n in range(core.N):
            y, x = (int(v) for v in cells[b, n])
            if not (0 <= y < h and 0 <= x < w):  # an absent agent: parked off the map
                y, x = -core.c, -core.c
            for s in range(S):
                side = f ** s
                for i in range(v):
                    for j in range(v):
                        top = y - side // 2 + (i - v // 2) * side + pad
                        left = x - side // 2 + (j - v // 2) * side + pad
                        top, left = max(top, 0), max(left, 0)  # only an absent agent reaches past the padding
                        block = padded[top:top + side, left:left + side]
                        counts = block.sum((0, 1))
                        area = side * side
                        for ch in (POI, COV, OBS, AG):
                            out[b, n, s * 5 + ch, i, j] = round_half_up(int(counts[ch]), area)
                        out[b, n, s * 5 + FR, i, j] = 255 if counts[FR] > 0 else 0
    return out


def reference_out_of_bounds(core: GridWorldCore) -> np.ndarray:
    """(B, N, 4, 2): [rows/cols, known points of interest] past the coarsest blocks' first and last map row/col."""
    cfg = core.config
    side, half = cfg.scale_factor ** (cfg.scales - 1), cfg.scale_view // 2
    up = side // 2 + half * side  # the first block row starts at y - side//2 - half * side
    down = half * side + side - 1 - side // 2  # the last one ends at y - side//2 + half * side + side - 1
    out = np.zeros((core.B, core.N, 4, 2), np.float32)
    cells = core.agent_cells()
    for b in range(core.B):
        poi = cell_table(core, b)[..., POI]
        h, w = poi.shape
        for n in range(core.N):
            if not core.active[b, n]:
                continue
            y, x = (int(v) for v in cells[b, n])
            out[b, n, 0] = max(y - up, 0), poi[:max(y - up, 0)].sum()
            out[b, n, 1] = max(h - 1 - y - down, 0), poi[y + down + 1:].sum()
            out[b, n, 2] = max(x - up, 0), poi[:, :max(x - up, 0)].sum()
            out[b, n, 3] = max(w - 1 - x - down, 0), poi[:, x + down + 1:].sum()
    return out


# ----------------------------------------------------------------------------- helpers
def parse(rows: list[str]) -> Scenario:
    """'.' free, '@' obstacle, 'x' covered, digits = agent starts (in order)."""
    a = np.array([list(r) for r in rows])
    digits = np.char.isdigit(a)
    starts = np.argwhere(digits)[np.argsort(a[digits].astype(int))]
    return Scenario(a == "@", starts, a == "x")


def make(scenarios: list[Scenario], size: int = 3, seed: int = 0, **kw) -> GridWorldCore:
    """One world per scenario (in order), its stored starts and coverage; the canvas is max(size, map sides)."""
    n = max(len(s.starts) for s in scenarios)
    cfg = EnvConfig(size=size, number_agents=n, load_state=True, load_random=False,
                    **{"observation": "multiscale", **kw})
    core = GridWorldCore(cfg, num_worlds=len(scenarios), seed=seed)
    core.configure(scenarios=scenarios)
    core.reset()
    return core


def check(core: GridWorldCore) -> np.ndarray:
    obs = core.observe()
    cfg = core.config
    assert obs["map"].shape == (core.B, core.N, cfg.scales * 5, cfg.scale_view, cfg.scale_view)
    assert obs["map"].dtype == np.uint8
    np.testing.assert_array_equal(obs["map"], reference(core))
    np.testing.assert_array_equal(obs["out_of_bounds"], reference_out_of_bounds(core))
    return obs["map"]


def walk(core: GridWorldCore, steps: int, seed: int = 0, twin: GridWorldCore | None = None) -> None:
    """Random steps, checking every observation (and, with a deep twin, the frame features)."""
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        a = rng.integers(0, 5, (core.B, core.N))
        ev = core.step(a)
        if twin is not None:
            twin.step(a)
        done = ev["terminated"] | ev["truncated"]
        if done.any():
            core.reset(done)
            if twin is not None:
                twin.reset(done)
        check(core)
        if twin is not None:
            ms, deep = core.observe(), twin.observe()
            for k in ("last_action", "battery"):
                np.testing.assert_array_equal(ms[k], deep[k])


def random_map(rng, h: int, w: int, n: int, density: float = 0.15, covered: float = 0.3, near=None) -> Scenario:
    """Random obstacles, pockets cut off from the largest free region filled; n starts at random or at the free
    cells nearest to `near`."""
    obst = rng.random((h, w)) < density
    seed = np.zeros((h, w), bool)
    seed[tuple(np.argwhere(~obst)[rng.integers((~obst).sum())])] = True
    obst |= ~gw.flood(~obst[None], seed[None])[0]
    free = np.argwhere(~obst)
    if near is None:
        starts = free[rng.choice(len(free), n, replace=False)]
    else:
        starts = np.array([free[np.abs(free - p).sum(1).argmin()] for p in near])
    return Scenario(obst, starts, (rng.random((h, w)) < covered) & ~obst)


# ----------------------------------------------------------------------------- worked examples
def test_worked_example_odd_factor():
    core = make([parse(["0.@",
                        "x..",
                        "..."])], scales=2, scale_factor=3, scale_view=3)
    m = check(core)[0, 0]
    fine, coarse = m[:5], m[5:]
    np.testing.assert_array_equal(fine[:, 1, 1], [0, 255, 0, 255, 0])  # the agent's own cell, covered
    np.testing.assert_array_equal(fine[:, 1, 2], [255, 0, 0, 0, 0])  # east: free
    np.testing.assert_array_equal(fine[:, 2, 1], [0, 255, 0, 0, 0])  # south: covered
    assert (fine[OBS, 0, :] == 255).all() and (fine[OBS, :, 0] == 255).all()  # north and west: off the map
    # the centre 3x3 block is map rows -1..1, cols -1..1: 5 cells off the map, 2 POI, 2 covered, 1 agent
    np.testing.assert_array_equal(coarse[:, 1, 1], [57, 57, 142, 28, 0])
    np.testing.assert_array_equal(coarse[:, 1, 2], [28, 0, 227, 0, 0])  # cols 2..4: (1, 2) free, (0, 2) + 7 off the map
    np.testing.assert_array_equal(coarse[:, 2, 1], [57, 0, 198, 0, 0])  # rows 2..4: (2, 0), (2, 1) free
    assert (coarse[:, 0, :][OBS] == 255).all() and (coarse[OBS, :, 0] == 255).all()


def test_worked_example_even_factor_centres_below_right_and_rounds_half_up():
    core = make([parse(["0...", "....", "....", "...."])], scales=2, scale_factor=2, scale_view=3)
    coarse = check(core)[0, 0, 5:]
    # the centre 2x2 block is map rows -1..0, cols -1..0: 3 cells off the map and the agent's covered cell
    np.testing.assert_array_equal(coarse[:, 1, 1], [0, 64, 191, 64, 0])
    np.testing.assert_array_equal(coarse[:, 1, 2], [128, 0, 128, 0, 0])  # 2 of 4 cells: 127.5 rounds up
    np.testing.assert_array_equal(coarse[:, 2, 2], [255, 0, 0, 0, 0])  # rows 1..2, cols 1..2


def test_worked_example_camera_frontier():
    rows = ["........."] * 9
    rows[4] = "....0...."
    core = make([parse(rows)], scales=2, scale_factor=3, scale_view=3, sensor="camera", sensor_range=1)
    m = check(core)[0, 0]
    fine, coarse = m[:5], m[5:]
    ring = np.ones((3, 3), bool)
    ring[1, 1] = False
    np.testing.assert_array_equal(fine[FR] == 255, ring)  # every seen cell but the agent's borders unseen ones
    np.testing.assert_array_equal(coarse[:, 1, 1], [227, 28, 0, 28, 255])  # the seen 3x3: 8 POI, 1 agent
    assert not coarse[:, [0, 2]].any() and not coarse[:, :, [0, 2]].any()  # all around unseen: nothing, no frontier


# ----------------------------------------------------------------------------- against the reference
def test_small_maps_several_agents_corners_and_coverage():
    core = make([parse(["0.@..",
                        ".x@.1",
                        "..x..",
                        "@...x",
                        "2..@3"])])
    check(core)
    walk(core, 6)


def test_map_larger_than_the_coarsest_window_non_square_canvas():
    rng = np.random.default_rng(1)
    s = random_map(rng, 120, 40, 4, near=[[0, 0], [119, 39], [60, 20], [3, 38]])  # corners, middle, an edge
    core = make([s], seed=1)
    assert (core.H, core.W) == (120, 40)
    check(core)
    deep = make([s], seed=1, observation="deep")
    walk(core, 4, twin=deep)
    assert core.observe()["out_of_bounds"].any()  # the map is larger than the deep window


def test_out_of_bounds_worked_example_one_scale():
    """One scale of 3x3 single cells reaches one cell each way. Agent at the top-left corner of a 3x6 map with
    one covered cell: one row beyond to the south (6 points of interest), four cols beyond to the east
    (12 cells less the covered one)."""
    core = make([parse(["0.x...", "......", "......"])], scales=1, scale_factor=2, scale_view=3)
    np.testing.assert_array_equal(core.observe()["out_of_bounds"][0, 0], [[0, 0], [1, 6], [0, 0], [4, 11]])


@pytest.mark.parametrize("side, beyond", [(50, 0), (51, 1)])
def test_out_of_bounds_default_scales_zero_up_to_50(side, beyond):
    """The default coarsest window (11 blocks of 9x9) shows 49 cells each way: nothing lies beyond it from any
    corner of a 50x50 map, one row/col does on 51x51."""
    corners = [[0, 0], [0, side - 1], [side - 1, 0], [side - 1, side - 1]]
    core = make([Scenario(np.zeros((side, side), bool), np.array(corners))])
    oob = core.observe()["out_of_bounds"][0]
    np.testing.assert_array_equal(np.sort(oob[:, :, 0], 1), [[0, 0, beyond, beyond]] * 4)
    assert (oob[:, :, 1] > 0).sum() == 8 * beyond
    check(core)


@pytest.mark.parametrize("factor, sensor", [(9, "camera"), (257, "full")])
def test_a_map_of_65536_cells_or_more(factor, sensor):
    """Block counts are packed in 16-bit lanes unless a block can hold 65536 cells of one kind (here factor 257:
    the centre block holds nearly the whole map of uncovered free cells)."""
    rng = np.random.default_rng(7)
    core = make([random_map(rng, 257, 256, 2, density=0.0, covered=0.0, near=[[128, 128], [200, 100]])], seed=7,
                sensor=sensor, scales=2, scale_factor=factor, scale_view=3)
    assert core.H * core.W >= 1 << 16
    m = check(core)
    if factor == 257:
        assert m[0, 0, 5 + POI, 1, 1] >= 250  # more than 65535 points of interest in the block
    walk(core, 1, seed=7)


def test_worlds_of_different_sizes_and_shapes():
    rng = np.random.default_rng(2)
    scenarios = [random_map(rng, 7, 13, 2), random_map(rng, 13, 7, 2), random_map(rng, 30, 4, 1),
                 random_map(rng, 5, 5, 2)]
    core = make(scenarios, seed=2)
    assert (core.H, core.W) == (30, 13)  # smaller maps sit in a larger canvas: cells beyond are off the map
    check(core)
    assert not core.active.all()  # the one-agent world's second agent is absent (parked off the map)
    deep = make(scenarios, seed=2, observation="deep")
    walk(core, 8, twin=deep)


@pytest.mark.parametrize("sensor", ["camera", "lidar"])
def test_sensor_tasks_unseen_cells_and_frontier(sensor):
    rng = np.random.default_rng(3)
    scenarios = [random_map(rng, 16, 22, 2, density=0.25, covered=0.1), random_map(rng, 9, 9, 1, covered=0.0)]
    core = make(scenarios, seed=3, sensor=sensor, sensor_range=2)
    m = check(core)
    assert (m[:, :, FR::5] == 255).any()  # some frontier is visible
    walk(core, 10, seed=3)


@pytest.mark.parametrize("settings", [dict(scales=2, scale_factor=2, scale_view=5), dict(scales=4, scale_factor=2, scale_view=3),
                                      dict(scales=1, scale_factor=3, scale_view=7), dict(scales=3, scale_factor=4, scale_view=5)])
def test_other_scale_settings(settings):
    rng = np.random.default_rng(4)
    core = make([random_map(rng, 11, 17, 3), random_map(rng, 6, 4, 2)], seed=4, sensor="camera", **settings)
    check(core)
    walk(core, 4, seed=4)


def test_the_finest_scale_is_the_centre_of_the_deep_window():
    rng = np.random.default_rng(5)
    s = random_map(rng, 12, 9, 3)
    ms, deep = make([s], seed=5, sensor="lidar"), make([s], seed=5, sensor="lidar", observation="deep")
    for _ in range(5):
        c = gw.VIEW_SIZE // 2
        np.testing.assert_array_equal(ms.observe()["map"][:, :, :4], deep.observe()["map"][:, :, :, c - 5:c + 6, c - 5:c + 6])
        a = rng.integers(0, 4, (1, 3))
        ms.step(a)
        deep.step(a)


def test_generated_maps_in_a_vector_of_worlds():
    core = GridWorldCore(EnvConfig(size=14, random_size=True, min_size=6, number_obstacles=20, number_agents=2,
                                   sensor="camera", observation="multiscale"), num_worlds=3, seed=6)
    core.reset()
    check(core)
    walk(core, 5, seed=6)


# ----------------------------------------------------------------------------- faces and settings
def test_default_is_still_the_deep_observation():
    assert EnvConfig().observation == "deep"
    assert gw.agent_observation_space(EnvConfig())["map"].shape == (4, gw.VIEW_SIZE, gw.VIEW_SIZE)


def test_gymnasium_env_checker_and_spaces():
    env = gym.make("GridWorld-v0", size=8, number_obstacles=5, observation="multiscale", sensor="camera")
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=0)
    assert obs["map"].shape == (15, 11, 11) and env.observation_space.contains(obs)
    space = gw.agent_observation_space(EnvConfig(observation="multiscale", scales=2, scale_view=5))
    assert space["map"].shape == (10, 5, 5) and set(space) == {"map", "out_of_bounds", "last_action", "battery"}


@pytest.mark.parametrize("agents", [1, 3])
def test_vector_env_shapes_match_the_space(agents):
    env = GridWorldVectorEnv(4, size=10, number_agents=agents, observation="multiscale", scales=2, scale_factor=3,
                             scale_view=7)
    obs, _ = env.reset(seed=0)
    assert env.single_observation_space["map"].shape == ((10, 7, 7) if agents == 1 else (agents, 10, 7, 7))
    assert env.observation_space.contains(obs)
    obs, *_ = env.step(np.zeros((4, agents), np.int64) if agents > 1 else np.zeros(4, np.int64))
    assert env.observation_space.contains(obs)


def test_parallel_env_shapes_match_the_space():
    env = GridWorldParallelEnv(size=9, number_agents=2, observation="multiscale", sensor="lidar")
    obs, _ = env.reset(seed=0)
    for agent, o in obs.items():
        assert env.observation_space(agent).contains(o) and o["map"].shape == (15, 11, 11)
    obs, *_ = env.step({a: 1 for a in env.agents})
    assert all(env.observation_space(a).contains(o) for a, o in obs.items())


@pytest.mark.parametrize("bad, match", [
    (dict(scale_view=10), "odd scale_view"), (dict(scale_view=1), "odd scale_view"), (dict(scales=0), "scales >= 1"),
    (dict(scale_factor=1), "scale_factor >= 2"), (dict(scales=9, scale_factor=3), "at most 4096"),
    (dict(scales=10 ** 9), "at most 4096"), (dict(scale_view=11.0), "scale_view must be an int"),
    (dict(observation="multi"), "observation must be one of"),
])
def test_bad_settings_raise_one_line_value_errors(bad, match):
    with pytest.raises(ValueError, match=match) as info:
        GridWorldCore(EnvConfig(observation="multiscale").replace(**bad))
    assert "\n" not in str(info.value)


def test_scales_are_fixed_once_an_env_is_made():
    env = GridWorldVectorEnv(2, size=8, observation="multiscale")
    with pytest.raises(ValueError, match="fixed once an env is made"):
        env.configure(scales=2)
    env.configure(size=9)  # other settings may change

"""The structured map families of gridworld (EnvConfig.map_family, FamilyParams): connectivity, starts, determinism,
each family's structural signature, mixed draws, every path that takes settings, bad settings, structured_eval."""
import dataclasses
import importlib.util
import sys
from collections import Counter, deque
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import gridworld as gw
from gridworld import STRUCTURED_FAMILIES, EnvConfig, FamilyParams

MAPS = Path(__file__).resolve().parent.parent / "maps"


def maps(map_family, size, n=24, seed=0, **config):
    """n scenarios of one map family and size through generate_scenarios."""
    return gw.generate_scenarios(n, seed=seed, size=size, map_family=map_family, **config)


def raw(family, sizes, seed=0, params=None, pad=3, k=24):
    """The generator itself, for sides generate_scenarios does not draw (non-square, mixed in one batch)."""
    hw = np.array([s for s in sizes for _ in range(k)])
    H, W = hw.max(0) + pad
    return hw, gw.structured_obstacles(family, np.random.default_rng(seed), hw, int(H), int(W), params)


def components(mask: np.ndarray, diagonal: bool = False) -> list[np.ndarray]:
    """Cell lists (n, 2) of the 4- (or 8-) connected components of a 2-D bool array (plain BFS)."""
    seen = np.zeros_like(mask)
    steps = [(-1, 0), (1, 0), (0, -1), (0, 1)] + ([(-1, -1), (-1, 1), (1, -1), (1, 1)] if diagonal else [])
    out = []
    for y0, x0 in zip(*np.nonzero(mask)):
        if seen[y0, x0]:
            continue
        seen[y0, x0] = True
        q, cells = deque([(y0, x0)]), []
        while q:
            y, x = q.popleft()
            cells.append((y, x))
            for dy, dx in steps:
                yy, xx = y + dy, x + dx
                if 0 <= yy < mask.shape[0] and 0 <= xx < mask.shape[1] and mask[yy, xx] and not seen[yy, xx]:
                    seen[yy, xx] = True
                    q.append((yy, xx))
        out.append(np.array(cells))
    return out


def free_edges(free: np.ndarray) -> int:
    return int((free[1:] & free[:-1]).sum() + (free[:, 1:] & free[:, :-1]).sum())


def cycles(free: np.ndarray) -> int:
    """Cyclomatic number of the free cells' grid graph (one region): 0 = a tree, no loops."""
    return free_edges(free) - int(free.sum()) + 1


def free_neighbours(free: np.ndarray) -> np.ndarray:
    p = np.pad(free, 1)
    return p[:-2, 1:-1].astype(int) + p[2:, 1:-1] + p[1:-1, :-2] + p[1:-1, 2:]


def squares(mask: np.ndarray, s: int) -> np.ndarray:
    """(h-s+1, w-s+1) bool: the s x s windows of `mask` that are all True."""
    h, w = mask.shape
    out = np.ones((h - s + 1, w - s + 1), bool)
    for dy in range(s):
        for dx in range(s):
            out &= mask[dy:dy + h - s + 1, dx:dx + w - s + 1]
    return out


def covered_by_squares(free: np.ndarray, s: int) -> bool:
    """Every free cell lies in a free s x s square (passages at least s wide)."""
    sq = squares(free, s)
    cover = np.zeros_like(free)
    for dy in range(s):
        for dx in range(s):
            cover[dy:dy + sq.shape[0], dx:dx + sq.shape[1]] |= sq
    return bool((cover == free).all())


def one_line_error(fn, *args, match="", **kwargs):
    with pytest.raises(ValueError, match=match) as e:
        fn(*args, **kwargs)
    assert "\n" not in str(e.value)


# ----------------------------------------------------------------------------- every family
@pytest.mark.parametrize("family", [*STRUCTURED_FAMILIES, "mixed"])
def test_connected_with_starts_on_free_cells(family):
    """After Algorithm 10 the free cells are one region holding the distinct starts, only they covered."""
    scenarios = maps(family, 30, n=64, seed=1, number_agents=3, random_size=True, min_size=3)
    assert len({s.obstacles.shape for s in scenarios}) > 15
    gw.check_scenarios(scenarios)  # gridworld's own check (flood fill), then an independent BFS
    for s in scenarios:
        free = ~s.obstacles
        assert s.obstacles.shape[0] == s.obstacles.shape[1] and len(components(free)) == 1
        assert len({tuple(p) for p in s.starts.tolist()}) == 3 and free[s.starts[:, 0], s.starts[:, 1]].all()
        starts = np.zeros_like(free)
        starts[s.starts[:, 0], s.starts[:, 1]] = True
        assert (s.covered == starts).all()


@pytest.mark.parametrize("family", [*STRUCTURED_FAMILIES, "mixed"])
def test_deterministic_under_a_seed(family):
    a, b, c = (maps(family, 20, n=16, seed=seed, number_agents=3) for seed in (7, 7, 8))
    same = [(x.obstacles == y.obstacles).all() and (x.starts == y.starts).all() for x, y in zip(a, b)]
    assert all(same) and any((x.obstacles != y.obstacles).any() for x, y in zip(a, c))


@pytest.mark.parametrize("family", STRUCTURED_FAMILIES)
def test_structured_not_open_and_varied(family):
    scenarios = maps(family, 20, n=32)
    frac = np.array([s.obstacles.mean() for s in scenarios])
    assert (frac > 0.05).all() and (frac < 0.85).all()  # corridors: thick rock between passages
    assert len({s.obstacles.tobytes() for s in scenarios}) == len(scenarios)


@pytest.mark.parametrize("family", STRUCTURED_FAMILIES)
def test_number_obstacles_is_ignored(family):
    """Documented: the structure sets the obstacles; number_obstacles/obstacles_random only shape "random" maps."""
    a = maps(family, 15, n=8, seed=3)
    b = maps(family, 15, n=8, seed=3, number_obstacles=40, obstacles_random=True)
    assert all((x.obstacles == y.obstacles).all() for x, y in zip(a, b))


@pytest.mark.parametrize("family", STRUCTURED_FAMILIES)
def test_generator_non_square_and_mixed_sides(family):
    """The generator draws any sides (the config draws square maps), each map in its corner, connected."""
    rng = np.random.default_rng(5)
    hw = rng.integers(2, 33, (48, 2))
    obs = gw.structured_obstacles(family, rng, hw, 32, 34)
    for (h, w), o in zip(hw, obs):
        free = ~o[:h, :w]
        assert o[h:].all() and o[:, w:].all() and free.sum() >= 2 and len(components(free)) == 1


# ----------------------------------------------------------------------------- structural signatures
def test_rooms_signature():
    """Long straight 1-cell walls (>= 60% of a side) with door gaps; walls are never thicker than one cell."""
    for s in maps("rooms", 20) + maps("rooms", 27, seed=1):
        m = s.obstacles
        lines = list(m) + list(m.T)
        assert any(line.mean() >= 0.6 and not line.all() for line in lines)
        assert not squares(m, 2).any()


def test_rooms_room_sizes():
    """Every room (free region with the doors closed) keeps its sides in room_size; small maps are open."""
    family = FamilyParams(room_size=(3, 6), door_width=(1, 1))
    for s in maps("rooms", 20, family=family) + maps("rooms", 23, family=family):
        m = s.obstacles
        p_ = np.pad(m, 1, constant_values=True)
        door = ~m & ((p_[:-2, 1:-1] & p_[2:, 1:-1]) | (p_[1:-1, :-2] & p_[1:-1, 2:]))  # a free cell between two walls
        for cells in components(~m & ~door):
            sides = cells.max(0) - cells.min(0) + 1
            assert len(cells) == sides.prod() and (sides >= 3).all() and (sides <= 6).all()
    assert not any(s.obstacles.any() for s in maps("rooms", 8))


def test_corridors_signature():
    """Width-1 passages: most free cells have <= 2 free neighbours; loop_fraction 0 makes a tree, 0.5 loops."""
    family = FamilyParams(passage_width=(1, 1))
    for s in maps("corridors", 20, family=family) + maps("corridors", 27, family=family):
        free = ~s.obstacles
        assert (free_neighbours(free)[free] <= 2).mean() >= 0.7
    tree, loops = (dataclasses.replace(family, loop_fraction=f) for f in (0.0, 0.5))
    assert all(cycles(~s.obstacles) == 0 for s in maps("corridors", 25, family=tree))
    assert np.mean([cycles(~s.obstacles) for s in maps("corridors", 30, family=loops)]) > 1


@pytest.mark.parametrize("width", [1, 2, 3])
def test_corridors_width(width):
    """Passages exactly `width` wide: every free cell in a free width x width square, none wider."""
    for s in maps("corridors", 24, n=8, family=FamilyParams(passage_width=(width, width))):
        free = ~s.obstacles
        assert covered_by_squares(free, width) and not squares(free, width + 1).any()


def test_clutter_signature():
    """Every obstacle component (even 8-connected) is a rectangle with sides in block_size; count follows area."""
    for s in maps("clutter", 20) + maps("clutter", 13):
        for cells in components(s.obstacles, diagonal=True):
            sides = cells.max(0) - cells.min(0) + 1
            assert len(cells) == sides.prod() and (sides <= 4).all()
    dense = maps("clutter", 30, n=8, family=FamilyParams(block_count=(5, 5), block_size=(1, 1)))
    sparse = maps("clutter", 30, n=8, family=FamilyParams(block_count=(2, 2), block_size=(1, 1)))
    assert {int(s.obstacles.sum()) for s in dense} == {45} and {int(s.obstacles.sum()) for s in sparse} == {18}


@pytest.mark.parametrize("width", [1, 2])
def test_maze_signature(width):
    """Corridors exactly maze_width wide; width 1: a perfect maze (braid 0) is a tree with dead ends, a braided
    one has loops (wider corridors hold grid cycles of their own, so the count says nothing there)."""
    family = FamilyParams(maze_width=(width, width))
    for s in maps("maze", 20, family=family) + maps("maze", 27, family=family):
        free = ~s.obstacles
        assert covered_by_squares(free, width) and not squares(free, width + 1).any()
        assert width > 1 or cycles(free) > 0
    if width == 1:
        for s in maps("maze", 21, family=dataclasses.replace(family, braid=0.0)):
            free = ~s.obstacles
            assert cycles(free) == 0 and (free_neighbours(free)[free] == 1).sum() >= 2


# ----------------------------------------------------------------------------- mixed
def test_mixed_draws_every_family(monkeypatch):
    calls = Counter()
    draw = gw.structured_obstacles

    def counting(family, rng, hw, *args):
        calls[family] += len(hw)
        return draw(family, rng, hw, *args)

    monkeypatch.setattr(gw, "structured_obstacles", counting)
    scenarios = maps("mixed", 12, n=500)  # number_obstacles 0: the "random" maps are the open ones
    calls["random"] = sum(not s.obstacles.any() for s in scenarios)
    assert set(calls) == {"random", *STRUCTURED_FAMILIES} and min(calls.values()) > 60, calls
    calls.clear()
    scenarios = maps("mixed", 12, n=400, map_family_weights={"rooms": 1, "maze": 3})
    assert set(calls) == {"rooms", "maze"} and 2 < calls["maze"] / calls["rooms"] < 4.5, calls
    assert all(s.obstacles.any() for s in scenarios)


# ----------------------------------------------------------------------------- starts
def test_fixed_start_on_a_wall_is_cleared():
    """A fixed starting_position is a free cell of every map (cleared if the family put a wall there), connected."""
    for family in STRUCTURED_FAMILIES:
        scenarios = maps(family, 15, n=16, starting_position=[[1, 1], [7, 8]], starting_position_random=False,
                         number_agents=2)
        gw.check_scenarios(scenarios)
        assert all(s.starts.tolist() == [[1, 1], [7, 8]] and len(components(~s.obstacles)) == 1 for s in scenarios)


def test_no_usable_map_is_a_one_line_error():
    one_line_error(maps, "maze", 5, number_agents=24, match="no usable map in 20 draws")  # the centre is a wall


# ----------------------------------------------------------------------------- the paths that take settings
def test_yaml_stage_with_map_family(tmp_path):
    """Stage files reach the trainers through load_config: families, weights and nested family parameters."""
    path = tmp_path / "stages.yaml"
    path.write_text("rooms_stage:\n  size: 16\n  map_family: rooms\n  family: {room_size: [3, 5], door_width: [2, 2]}\n"
                    "mixed_stage:\n  size: 12\n  map_family: mixed\n  map_family_weights: {maze: 2, clutter: 1}\n")
    configs = gw.load_config(str(path))
    rooms, mixed = configs["rooms_stage"], configs["mixed_stage"]
    assert rooms.map_family == "rooms" and rooms.family.room_size == (3, 5) and rooms.family.door_width == (2, 2)
    assert rooms.family.passage_width == FamilyParams().passage_width  # unspecified parameters keep defaults
    assert mixed.map_family_weights == {"maze": 2, "clutter": 1}
    for cfg in configs.values():
        core = gw.GridWorldCore(cfg, 4, seed=0)
        core.reset()
        assert core.obstacle.any()
    assert rooms.replace(size=18).family == rooms.family  # replace keeps the nested parameters
    assert EnvConfig.from_dict(dataclasses.asdict(rooms)) == rooms  # the dict form (JSON, checkpoints) round-trips


def test_gym_make_with_map_family():
    env = gym.make("GridWorld-v0", map_family="maze", size=12, family={"maze_width": [1, 1]})
    obs, _ = env.reset(seed=0)
    core = env.unwrapped.core
    assert core.config.map_family == "maze" and core.config.family.maze_width == (1, 1)
    assert env.observation_space.contains(obs) and core.obstacle[0, core.c:core.c + 12, core.c:core.c + 12].any()
    env.step(0)
    vec = gw.GridWorldVectorEnv(3, map_family="clutter", size=10)
    vec.reset(seed=0)
    vec.configure(map_family="corridors")  # picked up at the next reset
    assert vec.core.config.map_family == "corridors"
    env.close()


@pytest.mark.parametrize("settings,problem", [
    (dict(map_family="hallways"), "map_family must be one of"),
    (dict(map_family=3), "map_family must be a str"),
    (dict(map_family_weights={"rooms": 1}), "map_family_weights needs map_family 'mixed'"),
    (dict(map_family="mixed", map_family_weights={"hallways": 1}), "map_family_weights must map some of"),
    (dict(map_family="mixed", map_family_weights=[1, 2]), "map_family_weights must map some of"),
    (dict(map_family="mixed", map_family_weights={"rooms": -1}), "finite weights >= 0"),
    (dict(map_family="mixed", map_family_weights={"rooms": 0}), "not all 0"),
    (dict(map_family="mixed", map_family_weights={"rooms": "1"}), "finite weights >= 0"),
    (dict(family="rooms"), "family must be a mapping"),
    (dict(family={"room_sise": [4, 8]}), "unknown map family setting"),
    (dict(family={"room_size": [8, 4]}), "room_size needs 1 <= min <= max"),
    (dict(family={"door_width": [0, 2]}), "door_width needs 1 <= min"),
    (dict(family={"passage_width": [1]}), "passage_width must be a \\(min, max\\) pair"),
    (dict(family={"passage_gap": [0, 2]}), "passage_gap needs 1 <= min"),
    (dict(family={"loop_fraction": 1.5}), "loop_fraction must be a number in \\[0, 1\\]"),
    (dict(family={"braid": "0.5"}), "braid must be a number in \\[0, 1\\]"),
    (dict(family={"block_count": [-1, 3]}), "block_count needs 0 <= min"),
    (dict(family={"block_size": [1.5, 3]}), "block_size must hold whole cell counts"),
    (dict(family={"maze_width": "2"}), "maze_width must be a \\(min, max\\) pair"),
    (dict(family={"maze_width": [True, 2]}), "maze_width must be a \\(min, max\\) pair"),
])
def test_bad_settings_are_one_line_value_errors(settings, problem, tmp_path):
    one_line_error(lambda: EnvConfig.from_dict(settings).validate(), match=problem)
    one_line_error(gw.generate_scenarios, 2, **settings, match=problem)
    path = tmp_path / "stage.yaml"
    path.write_text(__import__("yaml").safe_dump({"stage": settings}))
    one_line_error(gw.load_config, str(path), match="stage: .*" + problem)


def test_bad_generator_calls():
    rng = np.random.default_rng(0)
    for family, hw, problem in (("random", [[10, 10]], "unknown structured map family"),
                                ("rooms", [[1, 10]], "map sides must be >= 2"), ("rooms", [[12, 10]], "fit the 10x10")):
        one_line_error(gw.structured_obstacles, family, rng, np.array(hw), 10, 10, match=problem)
    assert gw.structured_obstacles("rooms", rng, np.zeros((0, 2), int), 4, 4).shape == (0, 4, 4)


# ----------------------------------------------------------------------------- structured_eval
def test_structured_eval_protocol():
    with np.load(MAPS / "structured_eval.npz") as data:
        family, size, covered = data["family"], data["size"], data["covered"]
    scenarios = gw.load_dataset(str(MAPS / "structured_eval.npz"))  # validates every scenario
    assert Counter(zip(family.tolist(), size.tolist())) == {(f, s): 20 for f in STRUCTURED_FAMILIES for s in range(10, 31)}
    assert not covered.any()  # no pre-coverage: the first N starts make a clean N-agent scenario
    for s, n in zip(scenarios, size):
        assert s.obstacles.shape == (n, n) and s.covered is None and len({tuple(p) for p in s.starts.tolist()}) == 15
    core = gw.GridWorldCore(EnvConfig(dataset_path=str(MAPS / "structured_eval.npz"), load_state=True,
                                      load_random=False, number_agents=15), 2)
    core.reset()
    assert core.active.all() and (core.agent_cells()[0] == scenarios[0].starts).all()


def test_pictures(tmp_path):
    spec = importlib.util.spec_from_file_location("make_datasets", MAPS / "make_datasets.py")
    make_datasets = importlib.util.module_from_spec(spec)
    sys.modules["make_datasets"] = make_datasets  # dataclasses look their module up here
    spec.loader.exec_module(make_datasets)
    path = make_datasets.pictures(make_datasets.Args(), str(tmp_path / "families.png"))
    assert Path(path).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

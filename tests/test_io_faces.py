"""Input/output and interface tests for gridworld.py: map files, datasets, YAML configs, the
Gymnasium Env / VectorEnv faces, the PettingZoo ParallelEnv and rendering."""
import os

os.environ["SDL_VIDEODRIVER"] = "dummy"  # before pygame is imported anywhere
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

import glob
import re
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gymnasium as gym  # noqa: E402
from gymnasium.utils.env_checker import check_env  # noqa: E402

import gridworld  # noqa: E402
from gridworld import (  # noqa: E402
    EnvConfig,
    GridWorldCore,
    GridWorldVectorEnv,
    Scenario,
    check_scenario,
    load_config,
    load_dataset,
    load_map,
    save_dataset,
    save_map,
)

MAPS_DIR = Path(__file__).resolve().parent.parent / "maps" / "external"
MOVINGAI_MAPS = sorted(glob.glob(str(MAPS_DIR / "*.map")))
DATA = Path(__file__).resolve().parent / "data"

POI, COVERED, OBSTACLE, AGENT = gridworld.POI, gridworld.COVERED, gridworld.OBSTACLE, gridworld.AGENT
BLACK, WHITE, RED, BLUE = (0, 0, 0), (255, 255, 255), (220, 50, 50), (40, 90, 220)


# ----------------------------------------------------------------------------- helpers
def write(tmp_path, name, text) -> str:
    p = tmp_path / name
    p.write_text(text)
    return str(p)


def raises_one_line(exc_type, match):
    """pytest.raises that also checks the message is one line (use as a context manager)."""

    class _Ctx:
        def __enter__(self):
            self.cm = pytest.raises(exc_type, match=match)
            self.info = self.cm.__enter__()
            return self.info

        def __exit__(self, *exc):
            out = self.cm.__exit__(*exc)
            if out:
                msg = str(self.info.value)
                assert "\n" not in msg, f"error message is not a single line: {msg!r}"
            return out

    return _Ctx()


def inner(core, arr, b=0):
    """Map-coordinate slice of a canvas-coordinate array of world b."""
    c = core.c
    h, w = core.hw[b]
    return arr[b, c:c + h, c:c + w]


def movingai_counts(path):
    lines = Path(path).read_text().splitlines()
    h = int(lines[1].split()[1])
    w = int(lines[2].split()[1])
    rows = [ln for ln in lines[4:] if ln.strip()]
    blocked = sum(sum(ch in "@OTW" for ch in r) for r in rows)
    return h, w, blocked


def obs_equal(a, b):
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for k in a:
            np.testing.assert_array_equal(np.asarray(a[k]), np.asarray(b[k]), err_msg=k)
    else:
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def obs_at(obs, i):
    return {k: v[i] for k, v in obs.items()} if isinstance(obs, dict) else obs[i]


SMALL_MAP = (  # one start, some covered cells, one 4-connected free component
    "....@.\n"
    ".@@.@.\n"
    ".@0x..\n"
    ".@@@@.\n"
    "..x...\n"
)


# ============================================================================= 1. map files
@pytest.mark.skipif(not MOVINGAI_MAPS, reason="no MovingAI maps in maps/external")
@pytest.mark.parametrize("path", MOVINGAI_MAPS, ids=lambda p: Path(p).name)
def test_load_movingai_map(path):
    h, w, blocked = movingai_counts(path)
    s = load_map(path)
    assert s.obstacles.shape == (h, w)
    assert s.obstacles.dtype == bool
    assert int(s.obstacles.sum()) == blocked
    assert s.starts is None and s.covered is None
    check_scenario(s, path)  # every shipped map is one free component


def test_movingai_all_characters(tmp_path):
    p = write(tmp_path, "chars.map", "type octile\nheight 3\nwidth 5\nmap\n.GS@O\n..T..\nW....\n")
    s = load_map(p)
    expected = np.array([[0, 0, 0, 1, 1], [0, 0, 1, 0, 0], [1, 0, 0, 0, 0]], bool)
    np.testing.assert_array_equal(s.obstacles, expected)


def test_ascii_roundtrip(tmp_path):
    obstacles = np.zeros((5, 7), bool)
    obstacles[1, 1:4] = True
    obstacles[3, 4:6] = True
    starts = np.array([[0, 0], [4, 6], [2, 3]])
    covered = np.zeros((5, 7), bool)
    covered[0, 1:5] = True
    covered[4, 0] = True
    covered[1, 2] = True  # covered obstacle: saved as an obstacle
    covered[4, 6] = True  # covered start: saved as the start digit
    s = Scenario(obstacles, starts, covered)
    p = str(tmp_path / "round.txt")
    save_map(p, s)
    text = Path(p).read_text().splitlines()
    assert text[0] == "0xxxx.."
    assert text[1] == ".@@@..."
    assert text[2] == "...2..."
    assert text[4] == "x.....1"
    t = load_map(p)
    np.testing.assert_array_equal(t.obstacles, obstacles)
    np.testing.assert_array_equal(t.starts, starts)
    start_mask = np.zeros_like(covered)
    start_mask[starts[:, 0], starts[:, 1]] = True
    np.testing.assert_array_equal(t.covered, covered & ~obstacles & ~start_mask)
    # a second round trip is the identity
    save_map(p, t)
    u = load_map(p)
    np.testing.assert_array_equal(u.obstacles, t.obstacles)
    np.testing.assert_array_equal(u.starts, t.starts)
    np.testing.assert_array_equal(u.covered, t.covered)


def test_ascii_hash_obstacles_and_no_starts(tmp_path):
    p = write(tmp_path, "hash.txt", "#..\n.@.\n...\n")
    s = load_map(p)
    np.testing.assert_array_equal(s.obstacles, [[1, 0, 0], [0, 1, 0], [0, 0, 0]])
    assert s.starts is None and s.covered is None


def test_ascii_starts_in_digit_order(tmp_path):
    p = write(tmp_path, "digits.txt", "2..\n.0.\n..1\n")
    s = load_map(p)
    np.testing.assert_array_equal(s.starts, [[1, 1], [2, 2], [0, 0]])


@pytest.mark.parametrize("name,text,problem", [
    ("hdr.map", "type octile\nheight 3\nwidht 3\nmap\n...\n...\n...\n", "bad MovingAI header"),
    ("hdr2.map", "type octile\nheight three\nwidth 3\nmap\n...\n...\n...\n",
     r"bad MovingAI header \(height/width not integers\)"),
    ("hdr3.map", "height 3\nwidth 3\nmap\n...\n...\n...\n", "bad MovingAI header"),
    ("short.map", "type octile\nheight 4\nwidth 3\nmap\n...\n...\n...\n",
     "header says 4x3 but the rows do not match"),
    ("wide.map", "type octile\nheight 3\nwidth 3\nmap\n...\n....\n...\n",
     "header says 3x3 but the rows do not match"),
    ("ragged.txt", "...\n..\n...\n", r"ragged rows \(lengths \[2, 3\]\)"),
    ("unknown.txt", "...\n..z\n...\n", "unknown character .*'z'.* at line 2, column 3"),
    ("unknown.map", "type octile\nheight 2\nwidth 3\nmap\n...\n.?.\n",
     r"unknown character .*'\?'.* at line 6, column 2"),
    ("nofree.txt", "@@@\n#@#\n", "no free cell"),
    ("dup.txt", "0..\n.0.\n...\n", r"agent starts must be the digits 0\.\.1, once each"),
    ("gap.txt", "0..\n.2.\n...\n", r"agent starts must be the digits 0\.\.1, once each"),
    ("split.txt", "..@..\n..@..\n..@..\n", "not one 4-connected component"),
    ("split.map", "type octile\nheight 3\nwidth 3\nmap\n.@.\n@@@\n...\n", "not one 4-connected"),
])
def test_load_map_errors(tmp_path, name, text, problem):
    p = write(tmp_path, name, text)
    with raises_one_line(ValueError, re.escape(p) + ": (.*)" + problem):
        load_map(p)


def test_unknown_character_message_is_plain(tmp_path):
    p = write(tmp_path, "plain.txt", "...\n..z\n")
    with raises_one_line(ValueError, re.escape(p) + ": unknown character 'z' at line 2, column 3"):
        load_map(p)


def test_load_map_missing_file(tmp_path):
    p = str(tmp_path / "nope.map")
    with raises_one_line(ValueError, re.escape(p) + r": cannot read map"):
        load_map(p)
    with raises_one_line(ValueError, re.escape(str(tmp_path)) + r": cannot read map"):
        load_map(str(tmp_path))  # a directory


@pytest.mark.parametrize("name", ["binary.map", "binary.txt"])
def test_load_map_binary_file_names_file(tmp_path, name):
    p = tmp_path / name
    p.write_bytes(b"\xff\xfe\x00\x81garbage\n")
    with raises_one_line(ValueError, re.escape(str(p))):
        load_map(str(p))


@pytest.mark.parametrize("starts,problem", [
    ([[3, 0]], r"start \[3, 0\] is out of bounds \(3x4\)"),
    ([[0, 4]], r"start \[0, 4\] is out of bounds \(3x4\)"),
    ([[0, 0], [-1, 2]], r"start \[-1, 2\] is out of bounds \(3x4\)"),
    ([[1, 1]], r"start \[1, 1\] is on an obstacle"),
    ([[0, 0], [2, 3], [0, 0]], "duplicate starts"),
    ([1, 2], r"starts must be a list of \[row, col\]"),
])
def test_check_scenario_start_errors(starts, problem):
    obstacles = np.zeros((3, 4), bool)
    obstacles[1, 1] = True
    with raises_one_line(ValueError, "my/scenario.txt: " + problem):
        check_scenario(Scenario(obstacles, np.array(starts)), "my/scenario.txt")


def test_more_agents_than_free_cells(tmp_path):
    p = write(tmp_path, "tiny.txt", "01\n2@\n")  # 3 free cells, all of them starts
    assert len(load_map(p).starts) == 3  # loadable as a map ...
    with raises_one_line(ValueError, "3 agent\\(s\\) leave no free cell to cover"):
        GridWorldCore(EnvConfig(map_configuration=p, load_state=True))  # ... but not coverable
    q = write(tmp_path, "tiny2.txt", "..\n.@\n")
    with raises_one_line(ValueError, "leave no free cell to cover"):
        GridWorldCore(EnvConfig(map_configuration=q, number_agents=3))
    with raises_one_line(ValueError, "do not fit a 2x2 map"):
        EnvConfig(size=2, number_agents=4).validate()


def test_more_agents_than_free_cells_names_file(tmp_path):
    p = write(tmp_path, "tiny3.txt", "..\n.@\n")
    with raises_one_line(ValueError, re.escape(p)):
        GridWorldCore(EnvConfig(map_configuration=p, number_agents=3))


def test_load_state_needs_starts(tmp_path):
    p = write(tmp_path, "nostarts.txt", "...\n...\n")
    with pytest.raises(ValueError, match="load_state needs scenarios with agent starts"):
        GridWorldCore(EnvConfig(map_configuration=p, load_state=True))


def test_save_map_more_than_ten_agents(tmp_path):
    st = np.array([[0, i] for i in range(11)])
    s = Scenario(np.zeros((2, 11), bool), st)
    p = str(tmp_path / "eleven.txt")
    try:
        save_map(p, s)
    except ValueError:
        return  # refusing to write an unrepresentable map is acceptable
    np.testing.assert_array_equal(load_map(p).starts, st)


@pytest.mark.parametrize("cfg,problem", [
    (dict(sensor="sonar"), "sensor must be one of"),
    (dict(observation="pixels"), "observation must be one of"),
    (dict(size=4, number_obstacles=15), "15 obstacles and 1 agent\\(s\\) do not fit a 4x4 map"),
    (dict(size=6, random_size=True, min_size=3, number_obstacles=35), "do not fit a 6x6 map"),
    (dict(size=6, random_size=True, min_size=3, number_agents=9), "9 agent\\(s\\) do not fit a 3x3 map"),
    (dict(view_size=10), "view_size must be odd"),
    (dict(sensor_range=0), "sensor_range must be >= 1"),
    (dict(starting_position_random=False), "no starting_position is given"),
])
def test_envconfig_validate_errors(cfg, problem):
    with raises_one_line(ValueError, "invalid environment configuration: (.*)" + problem):
        EnvConfig(**cfg).validate()
    with pytest.raises(ValueError, match=problem):
        GridWorldCore(EnvConfig(**cfg))


def test_envconfig_from_dict_and_range_errors():
    with raises_one_line(ValueError, r"unknown environment setting\(s\): \['colour'\]"):
        EnvConfig.from_dict({"size": 5, "colour": "red"})
    with raises_one_line(ValueError, r"unknown reward setting\(s\): \['bonus'\]"):
        EnvConfig.from_dict({"reward": {"gain": 0.1, "bonus": 1}})
    with raises_one_line(ValueError, "sensor_range 25 exceeds the view radius 20"):
        GridWorldCore(EnvConfig(sensor="camera", sensor_range=25))
    with raises_one_line(ValueError, "sensor_range 6 exceeds the view radius 5"):
        GridWorldCore(EnvConfig(sensor="lidar", sensor_range=6, view_size=11))
    with pytest.raises(ValueError, match="sensor must be one of"):
        gym.make("GridWorld-v0", sensor="sonar")
    with pytest.raises(ValueError, match="unknown environment setting"):
        gym.make("GridWorld-v0", colour="red")
    with pytest.raises(ValueError, match="starting_position must give 1"):
        GridWorldCore(EnvConfig(starting_position=[[0, 0], [1, 1]], starting_position_random=False))


# ============================================================================= 2. datasets
SCENARIO_TEXTS = [
    "0..@.\n.@...\n.@.x1\n...@.\nxx...\n",  # 5x5, 2 starts, covered
    "......\n.@@@@.\n......\n0.@...\n......\n.@....\n.x....\n",  # 7x6, 1 start, covered
    "1..\n.@.\n..0\n...\n",  # 4x3, 2 starts, nothing covered
]


def _scenarios(tmp_path):
    return [load_map(write(tmp_path, f"s{i}.txt", t)) for i, t in enumerate(SCENARIO_TEXTS)]


def test_dataset_roundtrip(tmp_path):
    scen = _scenarios(tmp_path)
    scen.append(Scenario(np.zeros((3, 8), bool)))  # no starts, no coverage
    p = str(tmp_path / "set.npz")
    save_dataset(p, scen)
    back = load_dataset(p)
    assert len(back) == len(scen)
    for s, t in zip(scen, back):
        np.testing.assert_array_equal(t.obstacles, s.obstacles)
        if s.starts is None:
            assert t.starts is None
        else:
            np.testing.assert_array_equal(t.starts, s.starts)
        if s.covered is None:
            assert t.covered is None
        else:
            np.testing.assert_array_equal(t.covered, s.covered)


def test_dataset_errors(tmp_path):
    scen = _scenarios(tmp_path)
    good = str(tmp_path / "good.npz")
    save_dataset(good, scen)
    with raises_one_line(ValueError, "no scenarios to save"):
        save_dataset(str(tmp_path / "empty.npz"), [])
    missing = str(tmp_path / "missing.npz")
    with raises_one_line(ValueError, re.escape(missing) + ": not a gridworld dataset"):
        load_dataset(missing)
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"this is not a numpy archive at all")
    with raises_one_line(ValueError, re.escape(str(garbage)) + ": not a gridworld dataset"):
        load_dataset(str(garbage))
    with np.load(good) as d:
        arrays = dict(d)
    for key in ("obstacles", "sizes", "starts"):
        part = {k: v for k, v in arrays.items() if k != key}
        q = str(tmp_path / f"no_{key}.npz")
        np.savez(q, **part)
        with raises_one_line(ValueError, re.escape(q) + ": not a gridworld dataset.*" + key):
            load_dataset(q)
    # "covered" is optional
    q = str(tmp_path / "no_covered.npz")
    np.savez(q, **{k: v for k, v in arrays.items() if k != "covered"})
    assert all(s.covered is None for s in load_dataset(q))
    # an invalid scenario inside is reported with its index
    bad = dict(arrays)
    bad["obstacles"] = arrays["obstacles"].copy()
    bad["obstacles"][1, 2, :] = True  # wall across scenario 1 -> two components
    q = str(tmp_path / "split.npz")
    np.savez(q, **bad)
    with raises_one_line(ValueError, re.escape(q) + r"\[1\]: free cells are not one 4-connected"):
        load_dataset(q)


@pytest.mark.parametrize("how", ["truncated", "bitflip"])
def test_dataset_corrupt_npz(tmp_path, how):
    good = tmp_path / "good.npz"
    save_dataset(str(good), _scenarios(tmp_path))
    raw = bytearray(good.read_bytes())
    if how == "truncated":
        raw = raw[:len(raw) // 2]
    else:  # damage the compressed data of the first member (header is 30 + name bytes)
        raw[60:80] = bytes(20)
    bad = tmp_path / f"{how}.npz"
    bad.write_bytes(bytes(raw))
    with raises_one_line(ValueError, re.escape(str(bad)) + ": not a gridworld dataset"):
        load_dataset(str(bad))


def _check_world(core, b, s):
    h, w = s.obstacles.shape
    assert tuple(core.hw[b]) == (h, w)
    np.testing.assert_array_equal(inner(core, core.obstacle, b), s.obstacles)
    c = core.c
    assert core.obstacle[b, c:c + core.H, c:c + core.W][h:, :].all()  # rest of canvas: obstacle
    assert core.obstacle[b, c:c + core.H, c:c + core.W][:, w:].all()
    n = len(s.starts)
    np.testing.assert_array_equal(core.agent_cells()[b, :n], s.starts)
    assert core.active[b].tolist() == [True] * n + [False] * (core.N - n)
    expected = np.zeros((h, w), bool) if s.covered is None else s.covered.copy()
    expected[s.starts[:, 0], s.starts[:, 1]] = True
    np.testing.assert_array_equal(inner(core, core.covered, b), expected)
    occ = np.zeros((h, w), bool)
    occ[s.starts[:, 0], s.starts[:, 1]] = True
    np.testing.assert_array_equal(inner(core, core.occupied, b), occ)


def test_core_loads_dataset_in_order(tmp_path):
    scen = _scenarios(tmp_path)
    p = str(tmp_path / "set.npz")
    save_dataset(p, scen)
    cfg = EnvConfig(dataset_path=p, load_state=True, load_random=False)
    core = GridWorldCore(cfg, num_worlds=1, seed=0)
    assert core.N == 2 and (core.H, core.W) == (7, 6)
    for k in range(2 * len(scen)):
        core.reset()
        _check_world(core, 0, scen[k % len(scen)])
        core.step(np.full((1, 2), gridworld.EAST))  # disturb the state between resets
    core3 = GridWorldCore(cfg, num_worlds=3, seed=0)
    core3.reset()
    for b in range(3):
        _check_world(core3, b, scen[b])
    core3.reset([1])  # the next scenario in order goes to world 1
    _check_world(core3, 1, scen[0])
    # load_random=True: every reset picks one of the scenarios, whole
    rnd = GridWorldCore(cfg.replace(load_random=True), num_worlds=4, seed=1)
    for _ in range(3):
        rnd.reset()
        for b in range(4):
            hw = tuple(rnd.hw[b])
            match = [s for s in scen if s.obstacles.shape == hw]
            assert len(match) == 1
            _check_world(rnd, b, match[0])


def test_fixture_dataset_loads(tmp_path):
    """tests/data/scenarios.npz (written by save_dataset from SCENARIO_TEXTS) still loads: the
    on-disk format stays readable."""
    f = DATA / "scenarios.npz"
    back = load_dataset(str(f))
    scen = _scenarios(tmp_path)
    assert len(back) == len(scen)
    for s, t in zip(scen, back):
        np.testing.assert_array_equal(t.obstacles, s.obstacles)
        np.testing.assert_array_equal(t.starts, s.starts)
        assert (t.covered is None) == (s.covered is None)
        if s.covered is not None:
            np.testing.assert_array_equal(t.covered, s.covered)
    core = GridWorldCore(EnvConfig(dataset_path=str(f), load_state=True, load_random=False), 3, seed=0)
    core.reset()
    for b in range(3):
        _check_world(core, b, scen[b])


# ============================================================================= 3. YAML configs
CURRICULUM_MAPPING = """
stage1:
  size: 6
stage2:
  size: 10
  number_obstacles: 8
  sensor: camera
  sensor_range: 2
stage3:
  size: 14
  random_size: true
  min_size: 12
  reward:
    gain: 0.5
    blocked: -2.0
"""

CURRICULUM_LIST = """
- name: small
  size: 5
- name: large
  size: 9
  number_agents: 1
  sensor: lidar
- size: 7
"""


def test_load_config_mapping(tmp_path):
    p = write(tmp_path, "cur.yaml", CURRICULUM_MAPPING)
    cfgs = load_config(p)
    assert list(cfgs) == ["stage1", "stage2", "stage3"]
    assert all(isinstance(c, EnvConfig) for c in cfgs.values())
    assert [c.name for c in cfgs.values()] == ["stage1", "stage2", "stage3"]
    assert [c.size for c in cfgs.values()] == [6, 10, 14]
    assert cfgs["stage2"].sensor == "camera" and cfgs["stage2"].number_obstacles == 8
    assert cfgs["stage3"].reward.gain == 0.5 and cfgs["stage3"].reward.blocked == -2.0
    assert cfgs["stage3"].reward.time_step == -1.0  # unspecified reward fields keep defaults
    assert cfgs["stage1"].sensor == "full"


def test_load_config_list(tmp_path):
    p = write(tmp_path, "cur.yml", CURRICULUM_LIST)
    cfgs = load_config(p)
    assert list(cfgs) == ["small", "large", "env3"]
    assert [c.size for c in cfgs.values()] == [5, 9, 7]
    assert cfgs["large"].sensor == "lidar" and cfgs["env3"].name == "env3"


@pytest.mark.parametrize("text,problem", [
    ("a: {size: 5\n", r"not valid YAML \("),
    ("a:\n  size: 5\n   bad: indent\n", "not valid YAML"),
    ("a:\n  size: 5\n  colour: red\n", r"unknown environment setting\(s\): \['colour'\]"),
    ("a:\n  reward: {bonus: 1}\n", r"unknown reward setting\(s\): \['bonus'\]"),
    ("a:\n  sensor: sonar\n", "sensor must be one of"),
    ("a:\n  size: 3\n  number_obstacles: 20\n", "do not fit"),
    ("a:\n  size: abc\n", ""),
    ("", "expected a mapping of environment names to settings"),
    ("42\n", "expected a mapping"),
    ("a: [1, 2]\n", "expected a mapping"),
    ("- size: 5\n  colour: red\n", "unknown environment setting"),
])
def test_load_config_errors(tmp_path, text, problem):
    p = write(tmp_path, "bad.yaml", text)
    with raises_one_line(ValueError, re.escape(p) + ": (.*)" + problem):
        load_config(p)


def test_load_config_missing_file(tmp_path):
    p = str(tmp_path / "none.yaml")
    with raises_one_line(ValueError, re.escape(p) + ": cannot read config"):
        load_config(p)


def test_load_config_list_of_scalars(tmp_path):
    p = write(tmp_path, "scalars.yaml", "- 1\n- 2\n")
    with raises_one_line(ValueError, re.escape(p)):
        load_config(p)


def test_load_config_reward_not_mapping(tmp_path):
    p = write(tmp_path, "reward.yaml", "a:\n  reward: 5\n")
    with raises_one_line(ValueError, re.escape(p)):
        load_config(p)


def test_configure_switches_stages_between_resets(tmp_path):
    cfgs = load_config(write(tmp_path, "cur.yaml", CURRICULUM_MAPPING))
    core = GridWorldCore(cfgs["stage1"], num_worlds=2, seed=0)
    core.reset()
    assert (core.hw == 6).all() and (core.H, core.W) == (6, 6)
    for _ in range(3):
        core.step(gridworld.heuristic_actions(core))
    cells, covered = core.agent_cells().copy(), [inner(core, core.covered, b).copy() for b in range(2)]
    steps = core.steps.copy()

    core.configure(cfgs["stage2"])  # grows the canvas, keeps the worlds in progress
    assert (core.H, core.W) == (10, 10)
    assert (core.hw == 6).all()
    np.testing.assert_array_equal(core.agent_cells(), cells)
    np.testing.assert_array_equal(core.steps, steps)
    for b in range(2):
        np.testing.assert_array_equal(inner(core, core.covered, b), covered[b])
    core.step(gridworld.heuristic_actions(core))  # still steppable

    core.reset()
    assert (core.hw == 10).all()
    assert core.config.sensor == "camera"
    assert not inner(core, core.seen, 0).all()  # camera: unseen cells exist on a 10x10 map
    assert inner(core, core.obstacle, 0).sum() >= 1

    core.configure(cfgs["stage3"])
    core.reset()
    assert (core.H, core.W) == (14, 14)
    assert ((core.hw >= 12) & (core.hw <= 14)).all()
    assert core.config.reward.gain == 0.5
    assert core.observe()["map"].shape == (2, 1, 4, 41, 41)

    core.configure(cfgs["stage1"])  # back to a smaller map: canvas is kept, map is 6x6
    core.reset()
    assert (core.hw == 6).all() and (core.H, core.W) == (14, 14)
    c = core.c
    assert core.obstacle[:, c + 6:c + 14, c:c + 14].all() and core.obstacle[:, c:c + 14, c + 6:c + 14].all()

    env = gym.make("GridWorld-v0", config=cfgs["stage1"])
    env.reset(seed=0)
    env.unwrapped.configure(cfgs["stage2"])
    env.reset()
    assert tuple(env.unwrapped.core.hw[0]) == (10, 10)
    with pytest.raises(ValueError, match="changing number_agents needs a new environment"):
        core.configure(cfgs["stage1"].replace(number_agents=2))


# ============================================================================= 4. Gymnasium
@pytest.mark.filterwarnings("ignore::UserWarning")
@pytest.mark.parametrize("kwargs", [
    dict(size=8),
    dict(size=8, sensor="camera"),
    dict(size=8, sensor="lidar", number_obstacles=10),
    dict(size=25, number_obstacles=60),  # larger than V//2 = 20: compressed observation
    dict(size=30, sensor="camera", random_size=True, min_size=21),
    dict(map_configuration=str(MAPS_DIR / "maze-32-32-2.map"), sensor="lidar"),
    dict(size=8, observation="tabular"),
    dict(size=12, observation="tabular", sensor="lidar", number_obstacles=20),
    dict(size=6, view_size=7, sensor="camera", sensor_range=3),
], ids=lambda k: "-".join(f"{a}={Path(str(b)).name}" for a, b in k.items()))
def test_check_env(kwargs):
    if "map_configuration" in kwargs and not Path(kwargs["map_configuration"]).exists():
        pytest.skip("maze map not available")
    env = gym.make("GridWorld-v0", **kwargs)
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    for _ in range(20):
        obs, r, term, trunc, info = env.step(env.unwrapped.heuristic_action() % 4)
        assert env.observation_space.contains(obs)
        assert isinstance(r, float)
        if term or trunc:
            obs, _ = env.reset()


def test_compressed_observation_large_map():
    env = gym.make("GridWorld-v0", size=30, starting_position=[[0, 0]], starting_position_random=False)
    obs, _ = env.reset(seed=0)
    oob = obs["out_of_bounds"]
    # agent at [0, 0] on a 30x30 map, R = 19: 10 rows beyond to the South and 10 cols to the East
    np.testing.assert_array_equal(oob[:, 0], [0, 10, 0, 10])
    # known points of interest beyond: 10 rows x 30 (South), 30 rows x 10 cols (East)
    np.testing.assert_array_equal(oob[:, 1], [0, 300, 0, 300])
    m = obs["map"]
    assert m.shape == (4, 41, 41) and m.dtype == np.uint8
    assert (m[OBSTACLE, 0, :] == 255).all() and (m[OBSTACLE, :, -1] == 255).all()


def test_make_vec_shapes_and_spaces():
    v = gym.make_vec("GridWorld-v0", num_envs=4, vectorization_mode="vector_entry_point", size=8)
    assert isinstance(v, GridWorldVectorEnv)
    assert v.num_envs == 4
    assert v.metadata["autoreset_mode"] == gym.vector.AutoresetMode.SAME_STEP
    obs, info = v.reset(seed=0)
    assert obs["map"].shape == (4, 4, 41, 41) and obs["map"].dtype == np.uint8
    assert obs["out_of_bounds"].shape == (4, 4, 2)
    assert obs["last_action"].shape == (4, 5)
    assert obs["battery"].shape == (4, 1)
    assert v.observation_space.contains(obs)
    assert info["active"].shape == (4, 1)
    a = v.action_space.sample()
    assert a.shape == (4,)
    obs, r, term, trunc, info = v.step(a)
    assert v.observation_space.contains(obs)
    assert r.shape == (4,) and r.dtype == np.float32
    assert term.shape == trunc.shape == (4,) and term.dtype == bool
    assert info["new"].shape == (4, 1)
    t = gym.make_vec("GridWorld-v0", num_envs=3, vectorization_mode="vector_entry_point", size=8,
                     observation="tabular")
    o, _ = t.reset(seed=0)
    assert o.shape == (3, 8) and o.dtype == np.int8 and t.observation_space.contains(o)


def _run_until_done(v, policy, max_steps=200):
    """Step v until some world finishes; returns (actions, obs, r, term, trunc, info)."""
    for _ in range(max_steps):
        a = policy()
        out = v.step(a.copy())  # a copy: see test_step_does_not_alias_caller_actions
        if (out[2] | out[3]).any():
            return (a,) + out
    raise AssertionError("no episode ended")


def test_vector_autoreset_same_step():
    v = GridWorldVectorEnv(num_envs=4, size=4, battery_factor=2.0)
    v.reset(seed=3)
    budget = v.core.budget.copy()
    assert (budget == 32).all()

    def policy():  # worlds 0-2 follow the heuristic (terminate), world 3 bumps North (truncates)
        h = v.heuristic_actions().copy()
        h[3] = gridworld.NORTH if v.core.agent_cells()[3, 0, 0] == 0 else h[3]
        return h

    seen_term = seen_trunc = False
    for _ in range(30):
        acts, obs, r, term, trunc, info = _run_until_done(v, policy)
        done = term | trunc
        assert "final_obs" in info and "final_info" in info
        np.testing.assert_array_equal(info["_final_obs"], done)
        np.testing.assert_array_equal(info["_final_info"], done)
        fo, fi = info["final_obs"], info["final_info"]
        for w in np.flatnonzero(done):
            # the returned obs is the first of a new episode
            assert obs["battery"][w, 0] == 1.0
            np.testing.assert_array_equal(obs["last_action"][w], np.eye(5)[gridworld.WAIT])
            assert v.core.steps[w] == 0
            # final_obs / final_info describe the end of the old one
            assert fi["steps"][w] > 0
            np.testing.assert_array_equal(fo["last_action"][w], np.eye(5)[acts[w]])
            if term[w]:
                seen_term = True
                assert fi["completed"][w]
                assert (fo["map"][w][POI] == 0).all()  # nothing left to cover
                assert fo["battery"][w, 0] > 0
            else:
                seen_trunc = True
                assert fo["battery"][w, 0] == 0.0
                assert not fi["completed"][w]
        for w in np.flatnonzero(~done):  # unfinished worlds: final_obs entries equal obs
            obs_equal(obs_at(fo, w), obs_at(obs, w))
        if seen_term and seen_trunc:
            break
    assert seen_term and seen_trunc


def test_vector_autoreset_top_level_info_is_reset_info():
    # all worlds truncate together after 8 WAIT steps; number_agent_random changes who is active
    v = GridWorldVectorEnv(num_envs=6, size=4, number_agents=3, number_agent_random=True,
                           battery_factor=0.5)
    v.reset(seed=0)
    for _ in range(8):
        obs, r, term, trunc, info = v.step(np.full((6, 3), gridworld.WAIT))
    assert trunc.all()
    old_active = info["final_info"]["active"]
    new_active = v.core.active
    assert (old_active != new_active).any()  # precondition of this check
    # the returned obs is the new episode's; the top-level info must describe it too
    np.testing.assert_array_equal(info["active"], new_active)
    if "steps" in info:
        np.testing.assert_array_equal(info["steps"], 0)


def test_step_does_not_alias_caller_actions():
    v = GridWorldVectorEnv(num_envs=1, size=3, battery_factor=0.5)  # 5 steps of battery
    v.reset(seed=0)
    a = np.array([gridworld.NORTH])
    for _ in range(5):
        *_, trunc, _ = v.step(a)
    assert trunc[0]  # autoreset happened
    assert a[0] == gridworld.NORTH, "the caller's action array was overwritten with WAIT"
    w = GridWorldVectorEnv(num_envs=1, size=6)
    w.reset(seed=0)
    buf = np.array([gridworld.EAST])
    w.step(buf)
    buf[:] = gridworld.WEST  # a trainer refilling its action buffer in place
    *_, info = w.step(buf)
    assert not info["repeated_action"][0, 0]


def test_vector_reset_mask():
    v = GridWorldVectorEnv(num_envs=4, size=8, number_obstacles=6)
    v.reset(seed=5)
    rng = np.random.default_rng(0)
    for _ in range(5):
        obs, *_ = v.step(rng.integers(0, 4, 4))
    cells = v.core.agent_cells().copy()
    obstacle = v.core.obstacle.copy()
    covered = v.core.covered.copy()
    battery = v.core.battery.copy()
    mask = np.array([True, False, True, False])
    new_obs, info = v.reset(options={"reset_mask": mask})
    np.testing.assert_array_equal(v.core.steps, [0, 5, 0, 5])
    np.testing.assert_array_equal(info["steps"], [0, 5, 0, 5])
    for w in (1, 3):
        np.testing.assert_array_equal(v.core.agent_cells()[w], cells[w])
        np.testing.assert_array_equal(v.core.obstacle[w], obstacle[w])
        np.testing.assert_array_equal(v.core.covered[w], covered[w])
        assert v.core.battery[w] == battery[w]
        obs_equal(obs_at(new_obs, w), obs_at(obs, w))
    for w in (0, 2):
        assert v.core.battery[w] == v.core.budget[w]
        assert new_obs["battery"][w, 0] == 1.0
    # index form works too (core.reset accepts indices)
    v.core.reset([1])
    np.testing.assert_array_equal(v.core.steps, [0, 0, 0, 5])


# ============================================================================= 5. vector == single
def test_vector_matches_single_env_same_seed():
    kw = dict(size=8, number_obstacles=6, sensor="camera", sensor_range=2, battery_factor=1.5)
    env = gym.make("GridWorld-v0", **kw)
    venv = GridWorldVectorEnv(num_envs=1, **kw)
    o1, i1 = env.reset(seed=7)
    o2, i2 = venv.reset(seed=7)
    obs_equal(o1, obs_at(o2, 0))
    rng = np.random.default_rng(1)
    episodes, steps = 0, 0
    while episodes < 2:
        h1 = env.unwrapped.heuristic_action()
        h2 = venv.heuristic_actions()
        assert h1 == int(h2[0])
        a = h1 if steps % 4 else int(rng.integers(0, 4))  # heuristic mostly, random sometimes
        o1, r1, t1, u1, i1 = env.step(a)
        o2, r2, t2, u2, i2 = venv.step(np.array([a]))
        steps += 1
        assert r1 == float(r2[0]) and t1 == bool(t2[0]) and u1 == bool(u2[0])
        for k in ("new", "blocked", "revisit"):
            assert bool(i1[k][0]) == bool(i2[k][0, 0])
        if t1 or u1:
            obs_equal(o1, obs_at(i2["final_obs"], 0))
            o1, _ = env.reset()  # same rng state: the same new episode
            episodes += 1
        obs_equal(o1, obs_at(o2, 0))
    assert steps > 20


def test_vector_matches_single_env_fixed_map(tmp_path):
    p = write(tmp_path, "fixed.txt", SMALL_MAP)
    kw = dict(map_configuration=p, load_state=True, sensor="lidar", sensor_range=2, battery_factor=1.0)
    env = gym.make("GridWorld-v0", **kw)
    venv = GridWorldVectorEnv(num_envs=3, **kw)
    o1, _ = env.reset(seed=0)
    o2, _ = venv.reset(seed=123)  # different seed: the loaded state does not depend on it
    for w in range(3):
        obs_equal(o1, obs_at(o2, w))
    assert tuple(env.unwrapped.core.agent_cells()[0, 0]) == (2, 2)
    rng = np.random.default_rng(2)
    resets = 0
    for t in range(120):
        a = env.unwrapped.heuristic_action() if t % 3 == 0 else int(rng.integers(0, 4))
        o1, r1, t1, u1, _ = env.step(a)
        o2, r2, t2, u2, i2 = venv.step(np.full(3, a))
        np.testing.assert_array_equal(r2, np.full(3, r1, np.float32))
        np.testing.assert_array_equal(t2, [t1] * 3)
        np.testing.assert_array_equal(u2, [u1] * 3)
        if t1 or u1:
            for w in range(3):
                obs_equal(o1, obs_at(i2["final_obs"], w))
            o1, _ = env.reset()
            resets += 1
        for w in range(3):
            obs_equal(o1, obs_at(o2, w))
    assert resets >= 2


# ============================================================================= 6. PettingZoo
@pytest.mark.parametrize("kwargs", [
    dict(size=8, number_agents=3),
    dict(size=8, number_agents=3, number_agent_random=True),
    dict(size=8, number_agents=3, sensor="camera"),
    dict(size=8, number_agents=2, observation="tabular"),
])
def test_parallel_api(kwargs):
    from pettingzoo.test import parallel_api_test
    parallel_api_test(gridworld.parallel_env(**kwargs), num_cycles=100)


def test_parallel_env_is_a_module_level_class_that_pickles_and_keeps_stepping():
    import pickle

    from pettingzoo import ParallelEnv
    env = gridworld.parallel_env(size=8, number_agents=3, number_obstacles=6, sensor="lidar")
    assert type(env) is gridworld.GridWorldParallelEnv and isinstance(env, ParallelEnv)
    env.reset(seed=2)
    env.step(env.heuristic_actions())
    copy = pickle.loads(pickle.dumps(env))
    assert copy.agents == env.agents
    for _ in range(40):  # same actions, same worlds: the copy's views and windows follow its own arrays
        if not env.agents:
            break
        actions = env.heuristic_actions()
        a, b = env.step(actions), copy.step(actions)
        assert a[1] == b[1] and a[2] == b[2] and a[3] == b[3]
        for agent in a[0]:
            for key in ("map", "out_of_bounds", "last_action", "battery"):
                np.testing.assert_array_equal(a[0][agent][key], b[0][agent][key])
    np.testing.assert_array_equal(copy.core.covered, env.core.covered)
    assert not np.shares_memory(copy.core.canvas, env.core.canvas)
    assert np.shares_memory(copy.core.windows, copy.core.canvas)
    copy.configure(size=6)  # the copy can still be reconfigured like any face
    copy.reset(seed=0)
    assert copy.core.hw[0].tolist() == [6, 6]


def test_vector_reset_seeds_np_random_as_gymnasium_does():
    env = GridWorldVectorEnv(2, size=5)
    env.reset(seed=7)
    assert env.np_random_seed == 7
    assert env.np_random.random() == np.random.default_rng(7).random()
    other = GridWorldVectorEnv(2, size=5)
    other.reset(seed=7)
    first = other.np_random.random()
    other.reset()  # no seed: the generator carries on
    assert other.np_random_seed == 7 and other.np_random.random() != first


def test_parallel_number_agent_random_agents_list():
    env = gridworld.parallel_env(size=8, number_agents=4, number_agent_random=True)
    counts = set()
    for seed in range(12):
        obs, infos = env.reset(seed=seed)
        counts.add(len(env.agents))
        assert env.agents == env.possible_agents[:len(env.agents)]
        assert set(obs) == set(infos) == set(env.agents)
    assert len(counts) > 1 and max(counts) <= 4 and min(counts) >= 1


def test_parallel_missing_agent_waits():
    env = gridworld.parallel_env(size=8, number_agents=3)
    obs, infos = env.reset(seed=0)
    core = env.core
    before = core.agent_cells()[0].copy()
    steps = 0
    moved = False
    while steps < 10:
        h = env.heuristic_actions()
        acts = {a: h[a] if h[a] != gridworld.WAIT else gridworld.NORTH for a in ("agent_0", "agent_2")}
        obs, rew, term, trunc, infos = env.step(acts)
        steps += 1
        after = core.agent_cells()[0]
        np.testing.assert_array_equal(after[1], before[1])
        assert infos["agent_1"]["waited"]
        assert not infos["agent_0"]["waited"]
        np.testing.assert_array_equal(obs["agent_1"]["last_action"], np.eye(5)[gridworld.WAIT])
        moved |= (after[0] != before[0]).any() or (after[2] != before[2]).any()
        if any(term.values()) or any(trunc.values()):
            break
    assert moved
    assert set(rew) == {"agent_0", "agent_1", "agent_2"} or not env.agents


def test_multi_agent_vector_env_shapes():
    v = GridWorldVectorEnv(num_envs=4, size=10, number_agents=3)
    obs, info = v.reset(seed=0)
    assert obs["map"].shape == (4, 3, 4, 41, 41)
    assert obs["out_of_bounds"].shape == (4, 3, 4, 2)
    assert obs["last_action"].shape == (4, 3, 5)
    assert obs["battery"].shape == (4, 3, 1)
    assert v.observation_space.contains(obs)
    assert v.single_action_space.shape == (3,)
    a = v.action_space.sample()
    assert a.shape == (4, 3)
    obs, r, term, trunc, info = v.step(a)
    assert v.observation_space.contains(obs)
    assert r.shape == (4, 3) and r.dtype == np.float32
    assert term.shape == (4,) and trunc.shape == (4,)
    assert info["active"].shape == (4, 3) and info["active"].all()
    assert v.heuristic_actions().shape == (4, 3)

    vr = GridWorldVectorEnv(num_envs=6, size=10, number_agents=3, number_agent_random=True)
    obs, info = vr.reset(seed=4)
    assert info["active"].shape == (6, 3)
    assert not info["active"].all()
    assert (info["active"].sum(1) >= 1).all()
    obs, r, term, trunc, info = vr.step(vr.action_space.sample())
    assert (r[~info["active"]] == 0).all()

    vt = GridWorldVectorEnv(num_envs=2, size=10, number_agents=3, observation="tabular")
    o, _ = vt.reset(seed=0)
    assert o.shape == (2, 3, 8) and vt.observation_space.contains(o)


# ============================================================================= 7. rendering
def _cell_colours(img, cell=16):
    """Colour of each cell's top-left pixel (outside the agent disk)."""
    return img[::cell, ::cell]


def test_render_rgb_array_colours(tmp_path):
    env = gym.make("GridWorld-v0", size=8, number_obstacles=10, render_mode="rgb_array")
    env.reset(seed=3)
    for _ in range(6):
        env.step(env.unwrapped.heuristic_action() % 4)
    img = env.render()
    assert isinstance(img, np.ndarray) and img.dtype == np.uint8 and img.shape == (128, 128, 3)
    core = env.unwrapped.core
    obst, cov = inner(core, core.obstacle), inner(core, core.covered)
    colours = _cell_colours(img)
    assert (colours[obst] == BLACK).all()
    assert (colours[~obst & cov] == RED).all()
    assert (colours[~obst & ~cov] == WHITE).all()
    assert obst.any() and (~obst & ~cov).any()
    y, x = core.agent_cells()[0, 0]
    centre = img[y * 16 + 8, x * 16 + 8]
    assert tuple(centre) not in (BLACK, WHITE, RED)  # the agent is drawn over its cell

    # non-square map from a file: (h*16, w*16)
    p = write(tmp_path, "rect.txt", "0....@...\n.........\n..@......\n.........\n....x....\n")
    env2 = gym.make("GridWorld-v0", map_configuration=p, load_state=True, render_mode="rgb_array")
    env2.reset(seed=0)
    img2 = env2.render()
    assert img2.shape == (5 * 16, 9 * 16, 3)
    col2 = _cell_colours(img2)
    assert tuple(col2[0, 5]) == BLACK and tuple(col2[2, 2]) == BLACK
    assert tuple(col2[4, 4]) == RED and tuple(col2[0, 0]) == RED and tuple(col2[1, 1]) == WHITE


def test_render_camera_unseen_blue():
    env = gym.make("GridWorld-v0", size=12, number_obstacles=15, sensor="camera", sensor_range=2,
                   render_mode="rgb_array")
    env.reset(seed=1)
    env.step(0)
    core = env.unwrapped.core
    img = env.render()
    assert img.shape == (192, 192, 3)
    colours = _cell_colours(img)
    seen, obst, cov = inner(core, core.seen), inner(core, core.obstacle), inner(core, core.covered)
    assert (~seen).any() and seen.any()
    assert (colours[~seen] == BLUE).all()
    b = colours[~seen].astype(int)
    assert (b[:, 2] > b[:, 0]).all() and (b[:, 2] > b[:, 1]).all()  # blue-ish
    assert (colours[seen & obst] == BLACK).all()
    assert (colours[seen & ~obst & cov] == RED).all()
    assert (colours[seen & ~obst & ~cov] == WHITE).all()
    # unseen obstacles are not revealed
    assert not (colours[~seen & obst] == BLACK).all(-1).any()


def test_vector_render():
    v = GridWorldVectorEnv(num_envs=2, size=6, render_mode="rgb_array")
    v.reset(seed=0)
    img = v.render()
    assert img.shape == (96, 96, 3) and img.dtype == np.uint8
    assert GridWorldVectorEnv(num_envs=1, size=6).render() is None


def test_render_human_dummy_driver():
    import pygame
    env = gym.make("GridWorld-v0", size=6, render_mode="human")
    env.reset(seed=0)  # renders
    assert pygame.display.get_init()
    surf = pygame.display.get_surface()
    assert surf.get_size() == (96, 96)
    for _ in range(3):
        env.step(env.unwrapped.heuristic_action() % 4)
    assert env.render() is None
    env.close()
    assert not pygame.display.get_init()

    penv = gridworld.parallel_env(size=5, number_agents=2, render_mode="human")
    penv.reset(seed=0)
    assert penv.render() is None
    assert pygame.display.get_surface().get_size() == (80, 80)
    penv.step({a: 0 for a in penv.agents})
    penv.close()
    with pytest.raises(ValueError, match="render_mode"):
        gym.make("GridWorld-v0", size=6, render_mode="ansi")


def test_record_video(tmp_path):
    pytest.importorskip("moviepy")
    from gymnasium.wrappers import RecordVideo
    env = RecordVideo(gym.make("GridWorld-v0", size=5, render_mode="rgb_array"),
                      video_folder=str(tmp_path / "video"), episode_trigger=lambda e: True,
                      disable_logger=True)
    env.reset(seed=0)
    for _ in range(200):
        _, _, term, trunc, _ = env.step(env.unwrapped.heuristic_action() % 4)
        if term or trunc:
            break
    env.close()
    assert list((tmp_path / "video").glob("*.mp4"))


def test_face_configure_keeps_spaces():
    env = gym.make("GridWorld-v0", size=8)
    env.unwrapped.configure(size=12, number_obstacles=5)  # a new stage: fine
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    for bad in (dict(view_size=31), dict(observation="tabular")):
        with pytest.raises(ValueError, match="fixed once an env is made"):
            env.unwrapped.configure(**bad)
    assert env.unwrapped.core.config.size == 12

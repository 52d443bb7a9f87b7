"""The committed datasets in maps/: regenerable, well formed, drawn as documented."""
import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

import gridworld as gw

MAPS = Path(__file__).resolve().parent.parent / "maps"
spec = importlib.util.spec_from_file_location("make_datasets", MAPS / "make_datasets.py")
make_datasets = importlib.util.module_from_spec(spec)
sys.modules["make_datasets"] = make_datasets  # dataclasses look their module up here
spec.loader.exec_module(make_datasets)


@pytest.mark.parametrize("size", [5, 30])
def test_cpp_eval_subsets_regenerate_exactly(size):
    data = np.load(MAPS / "cpp_eval.npz")
    rows = np.flatnonzero(data["size"] == size)
    fresh = make_datasets.subset(make_datasets.Args(), 1, size, 0.10, len(rows))
    for i, s in zip(rows, fresh):
        assert (data["obstacles"][i, :size, :size] == s.obstacles).all()
        assert (data["starts"][i, :1] == s.starts).all()


@pytest.mark.parametrize("name,agents", [("cpp_eval", 1), ("marl_eval", 15), ("p2p_eval", 1)])
def test_datasets_follow_their_protocol(name, agents):
    data = np.load(MAPS / f"{name}.npz")
    scenarios = gw.load_dataset(str(MAPS / f"{name}.npz"))  # validates every scenario
    sizes = data["size"]
    assert sorted(set(sizes.tolist())) == list(range(5, 31))
    limit = 0.15 if name == "marl_eval" else 0.10
    for s, size in zip(scenarios, sizes):
        assert s.obstacles.shape == (size, size) and len(s.starts) == agents
        if name == "p2p_eval":
            assert (~s.obstacles & ~s.covered).sum() == 1
        elif name == "marl_eval":
            assert s.covered is None  # the N-agent episode covers its own N starts at reset, no others
        else:
            assert (~s.obstacles & ~s.covered).sum() == (~s.obstacles).sum() - agents
    # obstacles uniform in [0, limit] of the cells (plus rare pockets filled by Algorithm 10)
    fraction = np.mean([s.obstacles.mean() for s in scenarios])
    assert 0.4 * limit < fraction < 0.6 * limit
    if name == "cpp_eval":
        assert np.bincount(sizes)[5:].tolist() == [100] * 26


def test_marl_eval_agent_prefixes_are_distinct_free_cells():
    for s in gw.load_dataset(str(MAPS / "marl_eval.npz"))[::50]:
        st = [tuple(p) for p in s.starts.tolist()]
        assert len(set(st)) == 15 and not s.obstacles[s.starts[:, 0], s.starts[:, 1]].any()


def test_ch5_sets():
    data = np.load(MAPS / "ch5_6x6.npz")
    corners = {(0, 0), (0, 5), (5, 0), (5, 5)}
    for s, k in zip(gw.load_dataset(str(MAPS / "ch5_6x6.npz")), data["requested_obstacles"]):
        assert s.obstacles.shape == (6, 6) and tuple(s.starts[0]) in corners
        assert s.obstacles.sum() >= k
    data = np.load(MAPS / "ch5_eval.npz")
    assert len(data["size"]) == 42 * 100


def test_main_regenerates_every_committed_dataset_exactly(tmp_path, capsys):
    make_datasets.main(make_datasets.Args(out=str(tmp_path)))
    names = ["cpp_eval", "p2p_eval", "marl_eval", "ch5_6x6", "ch5_eval", "structured_eval"]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(f"{n}.npz" for n in names)
    for name in names:
        with np.load(MAPS / f"{name}.npz") as committed, np.load(tmp_path / f"{name}.npz") as fresh:
            assert sorted(committed.files) == sorted(fresh.files)
            for key in committed.files:
                assert committed[key].dtype == fresh[key].dtype
                np.testing.assert_array_equal(committed[key], fresh[key], err_msg=f"{name}: {key}")
    assert len(capsys.readouterr().out.splitlines()) == len(names)  # one line per file, no bar off a terminal


def test_crops_are_cut_from_their_maps_with_the_unreachable_cells_filled(tmp_path):
    """--crops: each crop is its map's square at (row, col) with only the cells its first start cannot reach added
    as obstacles; every free cell is reachable, the starts are distinct free cells, and the file holds nothing else."""
    paths = [str(MAPS / "external" / "room-32-32-4.map"), str(MAPS / "external" / "random-8-8-20.map")]
    make_datasets.main(make_datasets.Args(out=str(tmp_path), crops=tuple(paths), crops_per_map=3, marl_agents=5))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["crops.npz"]
    data, scenarios = np.load(tmp_path / "crops.npz"), gw.load_dataset(str(tmp_path / "crops.npz"))
    assert list(data["family"]) == ["room-32-32-4"] * 3 + ["random-8-8-20"] * 3
    for s, family, side, y, x in zip(scenarios, data["family"], data["size"], data["row"], data["col"]):
        source = gw.load_map(str(MAPS / "external" / f"{family}.map")).obstacles
        assert side in make_datasets.CROP_SIDES or side == source.shape[0] == 8  # an 8x8 map is cut whole
        square = source[y:y + side, x:x + side]
        assert s.obstacles.shape == square.shape and (s.obstacles >= square).all()
        free = ~s.obstacles
        seed = np.zeros_like(free)
        seed[tuple(s.starts[0])] = True
        assert (gw.flood(free[None], seed[None])[0] == free).all()
        assert 2 * free.sum() >= (~square).sum()  # the start reaches at least half the square's free cells
        assert len(s.starts) == 5 and len({tuple(c) for c in s.starts}) == 5 and free[tuple(s.starts.T)].all()


def test_flood_reaches_four_connected_cells_only():
    free = np.array([[1, 1, 0, 1],
                     [0, 1, 0, 1],
                     [1, 1, 1, 0]], bool)  # (0, 3)-(1, 3) touch the rest only diagonally
    seed = np.zeros_like(free)
    seed[0, 0] = True
    expected = np.array([[1, 1, 0, 0],
                         [0, 1, 0, 0],
                         [1, 1, 1, 0]], bool)
    assert (gw.flood(free[None], seed[None])[0] == expected).all()


def test_one_component_tells_split_maps_from_connected_ones():
    split = np.array([[1, 1, 0, 1],
                      [0, 1, 0, 1],
                      [1, 1, 1, 0]], bool)  # the right column touches the rest only diagonally
    joined = split.copy()
    joined[2, 3] = True  # (1, 3)-(2, 3)-(2, 2) joins them
    walled = np.zeros_like(split)
    walled[1, 1] = True  # a single free cell
    assert gw.one_component(np.stack([split, joined, walled])).tolist() == [False, True, True]
    with pytest.raises(ValueError, match="not one 4-connected component"):
        gw.check_scenario(gw.Scenario(~split, np.array([[0, 0]])))

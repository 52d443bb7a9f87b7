"""Batched grid world for cooperative robotic navigation (dissertation chapter 4).

One numpy core, `GridWorldCore`, simulates B independent worlds with N agents each; every
rule (safety controller, events, rewards, sensors, map generation, observations, heuristic)
is implemented once, vectorised over worlds and agents. Thin faces sit on top:

- `GridWorldEnv`        Gymnasium Env, registered as "GridWorld-v0" (one world, one agent);
- `GridWorldVectorEnv`  native Gymnasium VectorEnv (B worlds; with N > 1 agents every array
                        gets an agent axis, which is the batched multi-agent form for training);
- `GridWorldParallelEnv` PettingZoo ParallelEnv (one world, N agents; picklable), made by
                        PettingZoo's factory `parallel_env(...)`.

Conventions
- Cells are indexed [row, col]; row 0 is North. Actions: 0 North, 1 South, 2 West, 3 East,
  4 WAIT (no action: a lost message or a faulty agent). The learned action space is the four
  moves (§6.3.1); WAIT is accepted everywhere as "the agent gave no action".
- Synchronous moves with the safety controller of §4.2.2.5: a move into an obstacle, the
  border or an agent that stays is blocked. Two agents aiming at one cell: the lower index
  wins. Following is allowed (an agent may enter a cell its occupant leaves in the same step);
  swapping two agents is blocked for both (they would pass through each other).
- Battery = steps left before truncation, starting at `battery_factor * h * w` (5·size², as
  in the author's code); truncation (battery empty) and termination (all covered) are distinct.
- Deep observation (§6.3.2), per agent: "map" uint8 (4, V, V), channels points of interest,
  covered, obstacles, agents, 0/255 (compressed edges hold rounded means); "out_of_bounds"
  float32 (4, 2) rows [N, S, W, E] of [rows/cols beyond the window, known points of interest
  beyond]; "last_action" float32 one-hot (5,) (WAIT included); "battery" float32 (1,) in [0, 1].
  The map is a view of a channels-last buffer (torch reads it as channels_last). Frame
  stacking (3 frames in the dissertation) is left to the trainer's replay buffer, which stores
  each frame once and stacks at sample time; a single Env can use FrameStackObservation.
  Networks read VIEW_SIZE, FRAME_FEATURES (last_action + out_of_bounds / OUT_OF_BOUNDS_SCALE,
  built by `frame_features`) and BATTERY_FEATURES from here rather than hard-coding 41, 13, 100, 1.
- Tabular observation (§5.3.1): 8 range readings r' in the order N, S, E, W, NE, NW, SE, SW.
- Multiscale observation (observation="multiscale", not in the dissertation; after Jonnarth et al., ICML 2024):
  the deep dict with "map" uint8 (scales * 5, scale_view, scale_view), per scale s (scale_factor**s cells a
  block, agent-centred) [POI, covered, obstacle, agent means, frontier any]; see GridWorldCore._multiscale.
  Its "out_of_bounds" counts what lies beyond the coarsest window (zero on maps up to 50x50 by default).
"""
from __future__ import annotations

import contextlib
import dataclasses
import datetime
import fcntl
import functools
import hashlib
import json
import math
import numbers
import os
import pickle
import platform
import resource
import shlex
import signal
import subprocess
import sys
import tempfile
import time
import warnings
import zipfile
import zlib
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
import yaml
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from pettingzoo import ParallelEnv

NORTH, SOUTH, WEST, EAST, WAIT = 0, 1, 2, 3, 4
ACTION_DELTAS = np.array([[-1, 0], [1, 0], [0, -1], [0, 1], [0, 0]], dtype=np.int64)
POI, COVERED, OBSTACLE, AGENT = 0, 1, 2, 3  # channel indices of the deep observation
FRONTIER = 4  # the multiscale observation's fifth channel (known free cells next to unseen ones)
MULTISCALE_CHANNELS = 5  # per scale: POI, COVERED, OBSTACLE, AGENT, FRONTIER
SENSORS = ("full", "camera", "lidar")
STRUCTURES = ("competitive", "cooperative", "size_invariant")
OBSERVATIONS = ("deep", "tabular", "multiscale")
STRUCTURED_FAMILIES = ("rooms", "corridors", "clutter", "maze")  # map families beyond Algorithm 9's random maps
MAP_FAMILIES = ("random", *STRUCTURED_FAMILIES, "mixed")  # "mixed": one family drawn per map
FREE_CHARS, BLOCKED_CHARS = set(".GS"), set("@OTW#")
SETTING_KINDS = {"int": numbers.Integral, "float": numbers.Real, "bool": (bool, np.bool_),
                 "str": (str, os.PathLike)}  # what EnvConfig.validate accepts per annotated type
CODE = np.array([0xFF << (8 * ch) for ch in range(4)], np.uint32)  # channel bytes of a cell (little-endian)
ONE_HOT = np.eye(5, dtype=np.float32)
FIRST_STEP = np.array([[WAIT, NORTH, WAIT], [WEST, WAIT, EAST], [WAIT, SOUTH, WAIT]])  # by [dy+1, dx+1]
VIEW_SIZE = 41  # default side V of the deep observation's window (§6.3.2, Fig. 6.8)
FRAME_FEATURES = 5 + 4 * 2  # per stacked frame beside the map: last_action one-hot + out_of_bounds (§6.3.2.7)
BATTERY_FEATURES = 1  # the battery enters the network once, not per frame
OUT_OF_BOUNDS_SCALE = 100.0  # the networks read out_of_bounds (eq. 6.5 counts of rows and cells) divided by this
MAX_MAP_SIDE = 256  # the longest map side any config, .map file or dataset may have (the repo's maps are <= 48): checked
# before anything is allocated, so a typo (size: 100000) is a one-line error, not a process killed at 22 GB
MAX_DATASET_CELLS = 1 << 28  # cells (maps x rows x columns) of a dataset's padded arrays; maps/ holds at most 9 M
CANVAS_BYTES = 9  # bytes a world holds per canvas cell (5 bool arrays and the 4-byte observation canvas)
MAX_MAP_FILE_BYTES = 16 << 20  # a .map/ASCII map file is read whole; a 256x256 map is ~66 kB


# ----------------------------------------------------------------------------- configuration
@dataclass
class RewardParams:
    """Reward per event (Table 4.2). Defaults: the final single-agent reward of §6.3.3
    (eq. 6.13) and, for several agents, the size-invariant cooperative structure (eq. 7.5)."""

    time_step: float = -1.0
    new_cell: float = 1.0
    blocked: float = -1.0
    revisit: float = 0.0
    repeated_action: float = 0.0
    finished: float = 0.0
    timeout: float = 0.0
    waited: float = 0.0
    finished_line: float = 0.0
    wall_adjacent: float = 0.0
    structure: str = "size_invariant"
    gain: float = 0.25
    scale_by_area: bool = False
    positive_only_if_new: bool = False

    @classmethod
    def chapter5(cls) -> RewardParams:
        """§5.3.4: every term scaled by 1/(h·w); positive terms only when a new cell is covered."""
        return cls(time_step=0.0, new_cell=1.0, blocked=-10.0, revisit=-5.0, repeated_action=1.0,
                   finished_line=1.0, wall_adjacent=1.0, structure="competitive", gain=0.0,
                   scale_by_area=True, positive_only_if_new=True)


@dataclass
class FamilyParams:
    """Shape of the structured map families (EnvConfig.map_family, section "map families"). (min, max) pairs are
    inclusive ranges drawn uniformly; YAML lists become tuples. Maps too small for a family's structure come out open."""

    room_size: tuple[int, int] = (4, 8)
    """rooms: room side in cells; a room longer than max is split by a wall, no part below min (if it fits)."""
    door_width: tuple[int, int] = (1, 3)
    """rooms: width in cells of the one door cut in each wall (at most half the wall)."""
    passage_width: tuple[int, int] = (1, 3)
    """corridors: width in cells of each passage (drawn per passage)."""
    passage_gap: tuple[int, int] = (2, 4)
    """corridors: thickness in cells of the rock between parallel passages."""
    loop_fraction: float = 0.2
    """corridors: fraction of the lattice links left out of the spanning tree opened anyway, closing loops."""
    block_count: tuple[float, float] = (3.0, 10.0)
    """clutter: furniture blocks per 100 map cells (fewer when no more fit)."""
    block_size: tuple[int, int] = (1, 4)
    """clutter: side in cells of each rectangular block (height and width drawn apart)."""
    maze_width: tuple[int, int] = (1, 2)
    """maze: corridor width in cells (one per map; walls are 1 cell thick)."""
    braid: float = 0.5
    """maze: fraction of the perfect maze's dead ends knocked through to a neighbour, closing loops."""

    def __post_init__(self):
        for f in dataclasses.fields(self):  # YAML and JSON give lists: keep pairs hashable and comparable
            if isinstance(getattr(self, f.name), list):
                setattr(self, f.name, tuple(getattr(self, f.name)))

    def validate(self) -> None:
        def bad(msg):
            raise ValueError(f"invalid map family parameters: {msg}")

        def number(v):
            return isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_)) and math.isfinite(v)

        for name, low in (("room_size", 1), ("door_width", 1), ("passage_width", 1), ("passage_gap", 1),
                          ("block_count", 0), ("block_size", 1), ("maze_width", 1)):
            r = getattr(self, name)
            if not (isinstance(r, (tuple, list)) and len(r) == 2 and all(number(v) for v in r)):
                bad(f"{name} must be a (min, max) pair of finite numbers, got {r!r}")
            if name != "block_count" and not all(float(v).is_integer() for v in r):
                bad(f"{name} must hold whole cell counts, got {r!r}")
            if not low <= r[0] <= r[1]:
                bad(f"{name} needs {low} <= min <= max, got {tuple(r)}")
        for name in ("loop_fraction", "braid"):
            if not (number(getattr(self, name)) and 0.0 <= getattr(self, name) <= 1.0):
                bad(f"{name} must be a number in [0, 1], got {getattr(self, name)!r}")


@dataclass
class EnvConfig:
    """Environment configuration; field names follow Table 4.1."""

    size: int = 10
    min_size: int = 5
    random_size: bool = False
    number_obstacles: int = 0
    obstacles_random: bool = False
    number_agents: int = 1
    number_agent_random: bool = False
    sensor: str = "full"
    sensor_range: int = 3
    starting_position: Any = None
    starting_position_random: bool = True
    random_coverage: bool = False
    random_coverage_max: float = 0.7
    random_coverage_prob: float = 1.0
    number_points_of_interest: int = 0
    map_configuration: str | None = None
    dataset_path: str | None = None
    load_state: bool = False
    load_random: bool = True
    battery_factor: float = 5.0
    sensor_failure: float = 0.0
    faulty_agent_step: int | None = None
    faulty_agent: int = -1
    view_size: int = VIEW_SIZE
    edge_compression: bool = True
    observation: str = "deep"
    """"deep" (§6.3.2, the default), "tabular" (§5.3.1) or "multiscale" (scales x 5 channels of scale_view x
    scale_view block means, docs/environment.md; not in the dissertation)."""
    scales: int = 3
    """multiscale only: number of scales; scale s (0 = finest) has cells of scale_factor**s x scale_factor**s."""
    scale_factor: int = 3
    scale_view: int = 11
    """multiscale only: side (odd) of every scale's window, in blocks."""
    reward: RewardParams = field(default_factory=RewardParams)
    name: str = ""
    base_steps: int = 0
    map_family: str = "random"
    """How random maps are drawn (section "map families"): "random" is Algorithm 9 (number_obstacles cells
    scattered, obstacles_random); "rooms", "corridors", "clutter" and "maze" draw structured maps shaped by
    `family` and ignore number_obstacles/obstacles_random (the structure sets the obstacle density); "mixed"
    draws one family per map by map_family_weights, number_obstacles applying to its "random" maps."""
    map_family_weights: dict[str, float] | None = None
    """mixed only: {family: weight >= 0} over random, rooms, corridors, clutter, maze (absent = 0); None = uniform
    over all five."""
    family: FamilyParams = field(default_factory=FamilyParams)
    """Parameters of the structured families (YAML: `family: {room_size: [4, 8], braid: 0.3}`)."""

    @classmethod
    def from_dict(cls, d: dict) -> EnvConfig:
        d = dict(d)
        unknown = set(d) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise ValueError(f"unknown environment setting(s): {sorted(unknown)}")
        for key, kind, label in (("reward", RewardParams, "reward"), ("family", FamilyParams, "map family")):
            if not isinstance(d.get(key, kind()), (dict, kind)):
                raise ValueError(f"{key} must be a mapping of {kind.__name__} fields, got {d[key]!r}")
            if isinstance(d.get(key), dict):
                bad = set(d[key]) - {f.name for f in dataclasses.fields(kind)}
                if bad:
                    raise ValueError(f"unknown {label} setting(s): {sorted(bad)}")
                d[key] = kind(**d[key])
        return cls(**d)

    def replace(self, **changes) -> EnvConfig:
        return EnvConfig.from_dict({**dataclasses.asdict(self), "reward": self.reward, "family": self.family, **changes})

    def validate(self) -> None:
        def bad(msg):
            raise ValueError(f"invalid environment configuration: {msg}")

        if not isinstance(self.reward, RewardParams):
            bad(f"reward must be RewardParams, got {self.reward!r}")
        if not isinstance(self.family, FamilyParams):
            bad(f"family must be FamilyParams, got {self.family!r}")
        for settings in (self, self.reward):
            for f in dataclasses.fields(settings):
                value, kind = getattr(settings, f.name), f.type.removesuffix(" | None")
                if value is None and f.type.endswith(" | None") or kind not in SETTING_KINDS:
                    continue
                if not isinstance(value, SETTING_KINDS[kind]) or (kind in ("int", "float") and isinstance(value, bool)):
                    bad(f"{f.name} must be {'an' if kind == 'int' else 'a'} {kind}, got {value!r}")
                if kind == "float" and not math.isfinite(value):  # nan passes every comparison check below
                    bad(f"{f.name} must be a finite number, got {value!r}")
        if self.sensor not in SENSORS:
            bad(f"sensor must be one of {SENSORS}, got {self.sensor!r}")
        if self.observation not in OBSERVATIONS:
            bad(f"observation must be one of {OBSERVATIONS}, got {self.observation!r}")
        if self.scales < 1 or self.scale_factor < 2 or self.scale_view < 3 or self.scale_view % 2 == 0:
            bad(f"need scales >= 1, scale_factor >= 2 and an odd scale_view >= 3, got scales={self.scales} "
                f"scale_factor={self.scale_factor} scale_view={self.scale_view}")
        if self.scales > 12 or self.scale_view * self.scale_factor ** (self.scales - 1) > 4096:
            bad(f"the coarsest multiscale window, scale_view * scale_factor ** (scales - 1) cells, must span at most "
                f"4096, got scales={self.scales} scale_factor={self.scale_factor} scale_view={self.scale_view}")
        if self.reward.structure not in STRUCTURES:
            bad(f"reward structure must be one of {STRUCTURES}, got {self.reward.structure!r}")
        if self.size > MAX_MAP_SIDE:
            bad(f"size must be at most {MAX_MAP_SIDE} (the largest map side, gridworld.MAX_MAP_SIDE), got {self.size}")
        if self.size < 2 or (self.random_size and not 2 <= self.min_size <= self.size):
            bad(f"need 2 <= min_size <= size, got size={self.size} min_size={self.min_size}")
        if self.number_agents < 1:
            bad(f"number_agents must be >= 1, got {self.number_agents}")
        if self.sensor_range < 1:
            bad(f"sensor_range must be >= 1, got {self.sensor_range}")
        if not 0.0 <= self.random_coverage_prob <= 1.0:
            bad(f"random_coverage_prob must be in [0, 1], got {self.random_coverage_prob}")
        if not 0.0 <= self.random_coverage_max < 1.0:
            bad(f"random_coverage_max must be in [0, 1), got {self.random_coverage_max}")
        if not 0.0 <= self.sensor_failure <= 1.0:
            bad(f"sensor_failure must be in [0, 1], got {self.sensor_failure}")
        if self.view_size < 5 or self.view_size % 2 == 0:
            bad(f"view_size must be odd and >= 5, got {self.view_size}")
        if self.number_points_of_interest < 0 or self.battery_factor <= 0:
            bad("number_points_of_interest must be >= 0 and battery_factor > 0")
        if self.number_obstacles < 0 or self.base_steps < 0:
            bad(f"number_obstacles and base_steps must be >= 0, got {self.number_obstacles} and {self.base_steps}")
        if not -self.number_agents <= self.faulty_agent < self.number_agents:
            bad(f"faulty_agent {self.faulty_agent} is not one of the {self.number_agents} agent(s) (or -1, the last)")
        if self.faulty_agent_step is not None and self.faulty_agent_step < 0:
            bad(f"faulty_agent_step must be >= 0, got {self.faulty_agent_step}")
        if self.map_configuration is None and self.dataset_path is None:
            smallest = self.min_size if self.random_size else self.size
            if self.number_agents > smallest ** 2 - 1:
                bad(f"{self.number_agents} agent(s) do not fit a {smallest}x{smallest} map with a cell to cover")
            if self.number_obstacles > self.size ** 2 - self.number_agents - 1:
                bad(f"{self.number_obstacles} obstacles and {self.number_agents} agent(s) do not fit a "
                    f"{self.size}x{self.size} map with a cell to cover")  # smaller maps draw fewer (Tables 6.2, 7.2)
        if not self.starting_position_random and self.starting_position is None:
            bad("starting_position_random is False but no starting_position is given")
        if self.map_family not in MAP_FAMILIES:
            bad(f"map_family must be one of {MAP_FAMILIES}, got {self.map_family!r}")
        weights = self.map_family_weights
        if weights is not None:
            if self.map_family != "mixed":
                bad(f"map_family_weights needs map_family 'mixed', got {self.map_family!r}")
            if not isinstance(weights, dict) or set(weights) - set(MAP_FAMILIES[:-1]):
                bad(f"map_family_weights must map some of {MAP_FAMILIES[:-1]} to weights, got {weights!r}")
            if not all(isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v) and v >= 0
                       for v in weights.values()) or not sum(weights.values()) > 0:
                bad(f"map_family_weights must be finite weights >= 0, not all 0, got {weights!r}")
        self.family.validate()


def cli(f, **kwargs):
    """tyro.cli(f, **kwargs) for the scripts, with a flag tyro cannot parse reported as one line `error: ...` on
    stderr and a non-zero exit, like every other bad input, in place of tyro's box; --help is tyro's own."""
    import io

    import tyro  # here, not above: the environment's users need no CLI parser

    captured = io.StringIO()
    try:
        with contextlib.redirect_stderr(captured):
            parsed = tyro.cli(f, **kwargs)
    except SystemExit as e:
        lines = [line.strip(" │╭╮╰╯") for line in captured.getvalue().splitlines()]
        rule = [not line.strip("-─") for line in lines]  # tyro's box: a title, a rule (where no terminal), the message
        start = next((i for i in range(1, len(lines)) if not rule[i]), len(lines))
        end = next((i for i in range(start, len(lines)) if rule[i]), len(lines))
        if e.code == 2 and start < end:
            message = " ".join(lines[start:end])
            raise SystemExit(f"error: {message} (see {os.path.basename(sys.argv[0])} --help)") from None
        sys.stderr.write(captured.getvalue())
        raise
    sys.stderr.write(captured.getvalue())
    return parsed


class _DuplicateKey(yaml.YAMLError):
    """A key given twice in one YAML mapping (PyYAML keeps the last silently)."""

    def __init__(self, key, line: int):
        super().__init__(f"{key!r} is given twice (again at line {line})")
        self.key, self.line = key, line


class _UniqueKeyLoader(yaml.SafeLoader):
    """yaml.SafeLoader refusing a key repeated in one mapping: a second stage (or setting) of the same name would
    silently replace the first."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = set()
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=deep)
                try:
                    if key in seen:
                        raise _DuplicateKey(key, key_node.start_mark.line + 1)
                    seen.add(key)
                except TypeError:  # an unhashable key: SafeLoader's own error follows
                    pass
        return super().construct_mapping(node, deep)


def _interrupt(signum, frame):
    raise KeyboardInterrupt(signum)


@contextlib.contextmanager
def cli_errors(interrupted: str = "nothing written"):
    """The `__main__` block of a script: `with gridworld.cli_errors(): main(gridworld.cli(Args))`. A ValueError is
    one `error: ...` line on stderr and exit status 1; Ctrl-C (SIGINT) or SIGTERM is one line, `error: interrupted
    by SIGINT; <interrupted>`, and the shell's 130 or 143, never a traceback. SIGTERM raises KeyboardInterrupt
    (with the signal number) while the block runs."""
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        yield
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    except KeyboardInterrupt as e:
        signum = e.args[0] if e.args and isinstance(e.args[0], int) else int(signal.SIGINT)
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C while leaving prints no traceback either
        print(f"error: interrupted by {signal.Signals(signum).name}; {interrupted}", file=sys.stderr, flush=True)
        raise SystemExit(128 + signum) from None
    finally:
        signal.signal(signal.SIGTERM, previous)


def fits_in_memory(need: int, what: str) -> None:
    """A one-line error before allocating when `need` bytes exceed this machine's memory (a typo in a count is then
    an error, not a process the kernel kills hours later)."""
    memory = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    if need > memory:
        raise ValueError(f"{what} needs {need / 2**30:,.1f} GiB, this machine has {memory / 2**30:.1f} GiB")


# ----------------------------------------------------------------------------- the write rule of every script
REPO = os.path.dirname(os.path.abspath(__file__))
GUARDED = {"models": "model", "results": "result", "maps": "dataset"}  # committed folders: the one kind each holds
UMASK = os.umask(0o022)
os.umask(UMASK)


def check_output(path: str, kind: str, overwrite: bool = False, flag: str = "--out") -> str:
    """The rule every script's output obeys, checked before the work that produces it: inside models/, results/ or
    maps/ of this repository only that folder's kind of file (a model, a result, a dataset); never a folder; a file
    already there is replaced only with --overwrite (`overwrite`), except under runs/, the scripts' own scratch
    space (gitignored). A refusal is a one-line ValueError naming `flag`. Returns `path`."""
    real = os.path.realpath(path)

    def inside(folder: str) -> bool:
        return os.path.commonpath([real, os.path.join(REPO, folder)]) == os.path.join(REPO, folder)

    for folder, holds in GUARDED.items():
        if inside(folder) and kind != holds:
            raise ValueError(f"{flag} {path}: inside {folder}/, which holds committed {holds}s, not a {kind}; "
                             "write it under runs/ or outside the repository")
    if os.path.isdir(path):
        raise ValueError(f"{flag} {path}: a folder, not a file")
    scratch = os.path.realpath("runs") in (real, os.path.commonpath([real, os.path.realpath("runs")]))
    if os.path.lexists(path) and not overwrite and not (inside("runs") or scratch):
        raise ValueError(f"{flag} {path}: there already; --overwrite replaces it")
    return path


@contextlib.contextmanager
def staged_output(path: str, kind: str, overwrite: bool = False, flag: str = "--out"):
    """`with staged_output(path, kind) as tmp:` write the file at `tmp` (in path's folder, with its extension, so
    torch, numpy, matplotlib and moviepy see the format). It replaces `path` in one os.replace only if the block
    ends without an exception; otherwise it is removed and `path` stays as it was. check_output's rule first;
    a full or read-only disk is a one-line ValueError."""
    check_output(path, kind, overwrite, flag)
    folder = os.path.dirname(os.path.abspath(path))
    stem, ext = os.path.splitext(os.path.basename(path))
    tmp = None
    try:
        os.makedirs(folder, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{stem}.", suffix=f".partial{ext}")
        os.close(fd)
        os.chmod(tmp, 0o666 & ~UMASK)  # mkstemp makes 0600; the file gets what open() would have given it
        yield tmp
        os.replace(tmp, path)
    except OSError as e:
        raise ValueError(f"{flag} {path}: cannot write ({e.strerror or e}); any earlier file there stays") from None
    finally:
        if tmp is not None and os.path.exists(tmp):
            os.remove(tmp)


def write_json(path: str, data: Any, kind: str, overwrite: bool = False, flag: str = "--out",
               allow_nan: bool = False) -> str:
    """`data` as JSON at `path`, through staged_output; strict unless `allow_nan` (Python's NaN for "no value",
    as a report's statistic of no episodes): a number that is not finite is a ValueError."""
    try:
        text = json.dumps(data, indent=1, allow_nan=allow_nan)
    except ValueError:
        raise ValueError(f"{flag} {path}: holds a number that is not finite, which JSON cannot; nothing written") from None
    with staged_output(path, kind, overwrite, flag) as tmp, open(tmp, "w") as f:
        f.write(text + "\n")
    return path


def load_config(path: str) -> dict[str, EnvConfig]:
    """Named environments from a YAML file (curriculum stages, Table 4.1 keys).

    The file is either a mapping name -> settings or a list of settings each with a `name`. A name (or a setting)
    given twice is an error, not the last one winning."""
    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8") as f:
            data = yaml.load(f, Loader=_UniqueKeyLoader)  # a SafeLoader, stricter
    except OSError as e:
        raise ValueError(f"{path}: cannot read config ({e.strerror})") from None
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text file") from None
    except _DuplicateKey as e:
        raise ValueError(f"{path}: duplicate name: {e}") from None
    except yaml.YAMLError as e:
        raise ValueError(f"{path}: not valid YAML ({str(e).splitlines()[0]})") from None
    if isinstance(data, list):
        if not all(isinstance(d, dict) for d in data):
            raise ValueError(f"{path}: every list item must be a mapping of settings")
        names = [str(d.get("name", f"env{i + 1}")) for i, d in enumerate(data)]
        twice = next((n for i, n in enumerate(names) if n in names[:i]), None)
        if twice is not None:
            raise ValueError(f"{path}: duplicate name: {twice!r} names two list items")
        data = dict(zip(names, data))
    if not isinstance(data, dict) or not all(isinstance(v, dict) for v in data.values()):
        raise ValueError(f"{path}: expected a mapping of environment names to settings")
    configs = {}
    for name, d in data.items():
        try:
            configs[str(name)] = EnvConfig.from_dict({"name": str(name), **d})
            configs[str(name)].validate()
        except (ValueError, TypeError) as e:
            raise ValueError(f"{path}: {name}: {e}") from None
    return configs


def curriculum(path: str | None, default: list[dict], single_agent: bool = False) -> list[EnvConfig]:
    """A trainer's stages: the YAML file at `path` (named environments, `base_steps` each), else `default`; no stages,
    a base_steps that is not a whole number > 0 or, with `single_agent`, a stage of several agents is an error."""
    stages = list(load_config(path).values()) if path else [EnvConfig.from_dict(s) for s in default]
    if not stages:
        raise ValueError(f"{path}: no stages")
    for s in stages:
        if single_agent and s.number_agents != 1:
            raise ValueError(f"stage {s.name}: this trainer is single-agent (number_agents: 1)")
        if not isinstance(s.base_steps, int) or s.base_steps <= 0:
            raise ValueError(f"stage {s.name}: base_steps must be a whole number > 0")
    return stages


# ----------------------------------------------------------------------------- runs: provenance, locks and stops
def provenance(script: str) -> dict:
    """What made a run, read once at its start: the script, the git commit of this repository (dirty: tracked files
    changed since), the machine's CPU and cores, Python and the command line."""
    def git(*command):
        try:
            out = subprocess.run(["git", "-C", REPO, *command], capture_output=True, text=True, timeout=30)
        except (OSError, subprocess.SubprocessError):
            return None
        return out.stdout.strip() if out.returncode == 0 else None

    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), None)
    except OSError:
        cpu = None
    commit = git("rev-parse", "HEAD")
    status = git("status", "--porcelain", "--untracked-files=no") if commit else None
    return {"script": script, "git_commit": commit, "git_dirty": None if status is None else bool(status),
            "cpu": cpu or platform.processor() or platform.machine(), "cores": os.cpu_count(),
            "python": platform.python_version(), "command": shlex.join([os.path.basename(sys.executable), *sys.argv])}


def lineage(path: str | None) -> dict | None:
    """The parent of a warm start: its path and hash and, from the JSON beside it, its flags, steps, provenance and
    own parent, so the chain reaches back to the first model trained from scratch."""
    if not path:
        return None
    with open(path, "rb") as f:
        parent = {"path": path, "sha256": hashlib.sha256(f.read()).hexdigest()}
    beside = os.path.splitext(path)[0] + ".json"
    if not os.path.exists(beside):
        return parent
    try:
        with open(beside) as f:
            record = json.load(f)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{beside}: not a model record ({(str(e).splitlines() or [type(e).__name__])[0]})") from None
    if not isinstance(record, dict):
        raise ValueError(f"{beside}: not a model record (a {type(record).__name__}, not a mapping)")
    return parent | {k: record[k] for k in ("global_step", "stage", "wall_seconds", "machine", "torch_threads",
                                            "init_from_note", "provenance", "parent", "args") if k in record}


def run_folder(run_name: str | None, exp_name: str, seed: int, resume: bool) -> str:
    """--run-name, else CleanRL's unique f"{exp_name}__{seed}__{unix time}": one folder under runs/, whose run is
    continued (--resume) or left alone, never overwritten."""
    if resume and not run_name:
        raise ValueError("--resume needs --run-name (the folder under runs/ to continue)")
    if run_name is not None and not run_name.strip():
        raise ValueError("--run-name must not be empty (leave it out for the default name)")
    name = run_name or f"{exp_name}__{seed}__{int(time.time())}"
    if name in (".", "..") or os.path.basename(name) != name or "\\" in name:
        raise ValueError(f"--run-name must be a folder name under runs/ (no '/' or '..'), got {name!r}")
    if not resume and os.path.exists(os.path.join("runs", name, "checkpoint.pt")):
        raise ValueError(f"runs/{name} holds a run already: --resume continues it, or choose another --run-name")
    return name


def check_export(path: str, script: str) -> None:
    """Before training: --export names a .pt file outside results/ and maps/, in a folder this process can write,
    and never replaces a model another script made (its JSON's provenance says which)."""
    if not path.endswith(".pt") or os.path.isdir(path):
        raise ValueError(f"--export must name a .pt file, got {path!r}")
    sidecar = os.path.splitext(path)[0] + ".json"
    for file in (path, sidecar):
        check_output(file, "model", overwrite=True, flag="--export")
    folder = os.path.dirname(os.path.abspath(path))
    while not os.path.exists(folder):  # the nearest folder that exists: staged_output makes the rest
        folder = os.path.dirname(folder)
    try:  # a file made there, since os.access lets root write anywhere (/proc too)
        tempfile.TemporaryFile(dir=folder).close()
    except OSError as e:
        raise ValueError(f"--export {path}: cannot write under {folder} ({e.strerror})") from None
    made_by = script
    if os.path.isfile(path) and os.path.isfile(sidecar):
        with contextlib.suppress(OSError, ValueError, KeyError, TypeError), open(sidecar) as f:
            made_by = json.load(f)["provenance"]["script"]
    if made_by != script:
        raise ValueError(f"--export {path} holds a model of {made_by}: export this run elsewhere")


def exported_by(path: str, run_name: str) -> bool:
    """Whether the export at `path` was written by the run `run_name` (its JSON says so)."""
    try:
        with open(os.path.splitext(path)[0] + ".json") as f:
            return json.load(f)["args"]["run_name"] == run_name
    except (OSError, ValueError, KeyError, TypeError):
        return False


def lock_run(run_dir: str):
    """An exclusive lock on runs/RUN/.lock for as long as the returned file stays open: a second run in the same
    folder is a one-line error instead of two runs writing one checkpoint."""
    os.makedirs(run_dir, exist_ok=True)
    lock = open(os.path.join(run_dir, ".lock"), "w")
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        lock.close()
        raise ValueError(f"{run_dir} is in use by another run; wait for it or choose another --run-name") from None
    return lock


def stop_signals() -> tuple[dict, dict]:
    """Ctrl-C and SIGTERM ask a training loop to stop: it ends, saves and exits 128 + the signal's number. Returns
    the flag the loop reads ({"signal": 0} until then) and the handlers restore_signals puts back."""
    stop = {"signal": 0}
    previous = {s: signal.signal(s, lambda n, _: stop.update(signal=n)) for s in (signal.SIGINT, signal.SIGTERM)}
    return stop, previous


def restore_signals(previous: dict) -> None:
    """The handlers stop_signals replaced, back in place."""
    for signum, handler in previous.items():
        signal.signal(signum, handler)


def peak_memory_mb() -> int:
    """The most resident memory this process has held so far, in MiB (Linux reports KiB)."""
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)


# ----------------------------------------------------------------------------- the trainers' files, flags and logs
UNREADABLE = (OSError, EOFError, RuntimeError, KeyError, IndexError, TypeError, ValueError, AttributeError,
              pickle.UnpicklingError, zipfile.BadZipFile)  # what torch.load of a foreign or truncated file raises


def reason(e: BaseException) -> str:
    """Why a file was refused, in one line: the error's first line, or what torch's weights-only refusal means."""
    if isinstance(e, pickle.UnpicklingError):
        return "not a torch file of tensors and plain values"
    return (str(e).splitlines() or [type(e).__name__])[0]


def read_torch(path: str, what: str) -> Any:
    """torch.load of tensors and plain values only, onto the CPU; a truncated or foreign file is a one-line
    ValueError saying it is not `what`."""
    import torch  # only the trainers' files need it

    try:
        with warnings.catch_warnings():  # torch warns about pickles it then refuses: the error says it all
            warnings.simplefilter("ignore")
            return torch.load(path, map_location="cpu", weights_only=True)
    except UNREADABLE as e:
        raise ValueError(f"{path}: not a {what} ({reason(e)})") from None


def save_torch(path: str, state: dict, kind: str = "run", flag: str = "checkpoint") -> None:
    """torch.save through staged_output: a crash or a full disk never leaves half a file."""
    import torch

    with staged_output(path, kind, overwrite=True, flag=flag) as tmp:
        torch.save(state, tmp)


def shapes_differ(here: dict, held: dict) -> str:
    """The first three differences between two {name: shape} records, in one line ("" when they agree)."""
    differ = sorted([f"{k} {held[k]} in the file, {here[k]} here" for k in here.keys() & held.keys()
                     if here[k] != held[k]] + [f"{k} only here" for k in here.keys() - held.keys()]
                    + [f"{k} only in the file" for k in held.keys() - here.keys()])
    return "; ".join(differ[:3]) + (f" and {len(differ) - 3} more" if len(differ) > 3 else "")


def check_ranges(args: Any, at_least: dict[str, float], unit: tuple = (), positive: tuple = (),
                 nonnegative: tuple = ()) -> None:
    """A script's numeric flags: every float finite, each of `at_least` at least its number, `unit` in [0, 1],
    `positive` above 0 and `nonnegative` at least 0 (a flag left at None is not checked); else a one-line error."""
    def flag(name):
        return f"--{name.replace('_', '-')}"

    for name, value in vars(args).items():
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"{flag(name)} must be a finite number, got {value}")
    rules = [(n, lambda v, least=least: v >= least, f">= {least}") for n, least in at_least.items()]
    rules += [(n, lambda v: 0.0 <= v <= 1.0, "in [0, 1]") for n in unit]
    rules += [(n, lambda v: v > 0, "> 0") for n in positive] + [(n, lambda v: v >= 0, ">= 0") for n in nonnegative]
    for name, ok, wanted in rules:
        if getattr(args, name) is not None and not ok(getattr(args, name)):
            raise ValueError(f"{flag(name)} must be {wanted}, got {getattr(args, name)}")


def resumed_flags(args: Any, saved: dict, source: str, own: tuple, replaceable: tuple = ()) -> dict:
    """The flags a resumed run keeps from `saved` (its checkpoint's): one left at its default takes the saved value;
    one set otherwise must agree with it (a one-line error), but for `own` (how a run goes: the command line's) and
    `replaceable` (the command line's when given)."""
    defaults = {f.name: f.default for f in dataclasses.fields(args)}
    kept = {}
    for name, value in saved.items():
        if name not in defaults or name in own or getattr(args, name) == value:
            continue
        if getattr(args, name) == defaults[name]:
            kept[name] = value
        elif name not in replaceable:
            may = f" (--{', --'.join(r.replace('_', '-') for r in replaceable)} may change)" if replaceable else ""
            raise ValueError(f"--{name.replace('_', '-')} {getattr(args, name)} contradicts {source} "
                             f"({name.replace('_', ' ')} {value}): a resumed run keeps its flags{may}")
    return kept


CHECKPOINT_KEYS = ("model", "optimizer", "global_step", "stage", "wall", "numpy_rng", "torch_rng")  # a training state
RUN_FLAGS = ("exp_name", "run_name", "resume", "threads", "cuda", "torch_deterministic", "track", "wandb_project_name",
             "wandb_entity", "quiet", "capture_video", "total_steps", "time_limit", "eval_every", "eval_maps",
             "save_every", "curve_every", "export", "overwrite", "init_from")  # how a run goes, not what it learns
# a resume may step slower, refill longer, draw other maps or lag its target network more
RESUME_FLAGS = ("learning_rate", "learning_starts", "seed", "tau")


def check_choices(args: Any) -> None:
    """A flag typed Literal[...] (tyro checks the command line; this, Args built in code) outside its choices is a
    one-line error."""
    import typing

    def choices(kind) -> tuple:  # Literal[...] itself, or inside `| None`
        if typing.get_origin(kind) is typing.Literal:
            return typing.get_args(kind)
        return tuple(c for a in typing.get_args(kind) for c in choices(a))

    for name, kind in typing.get_type_hints(type(args)).items():
        offered, value = choices(kind), getattr(args, name)
        if offered and value is not None and value not in offered:
            raise ValueError(f"--{name.replace('_', '-')} must be one of {', '.join(offered)}, got {value!r}")


def read_model(path: str) -> dict:
    """A trainer's saved network (an export or a checkpoint); a missing, truncated or foreign file is a one-line
    ValueError."""
    if not os.path.exists(path):
        raise ValueError(f"{path}: no such checkpoint")
    blob = read_torch(path, "rainbow_cpp / rainbow_marl model")
    if not isinstance(blob, dict) or not isinstance(blob.get("weights", blob.get("model")), dict):
        raise ValueError(f"{path}: not a rainbow_cpp / rainbow_marl model (no weights in it)")
    return blob


def load_checkpoint(path: str, script: str) -> dict:
    """A training checkpoint of `script` to resume, checked to hold a whole training state."""
    if not os.path.exists(path):
        raise ValueError(f"{path}: nothing to resume")
    state = read_model(path)
    missing = [k for k in CHECKPOINT_KEYS if k not in state]
    if missing:
        raise ValueError(f"{path}: not a training checkpoint (no {', '.join(missing)})")
    if state.get("script", script) != script:  # older checkpoints do not say
        raise ValueError(f"{path}: a {state['script']}.py run; resume it with {state['script']}.py")
    return state


def export_model(q: Any, args: Any, info: dict) -> None:
    """Deployable weights at args.export (the noisy layers' means, fp16, with the network's record q.network()) and
    beside them a JSON of the flags, the network and `info` (steps, provenance, parent model)."""
    weights = {k: v.cpu().half() for k, v in q.state_dict().items() if "sigma" not in k and "eps" not in k}
    save_torch(args.export, {"weights": weights, **q.network()}, "model", "--export")
    write_json(os.path.splitext(args.export)[0] + ".json", {"args": dataclasses.asdict(args), "network": q.network(),
                                                            **info}, "model", True, "--export")


def save_run(run_dir: str, script: str, q: Any, target: Any, optimizer: Any, args: Any, rng: np.random.Generator,
             global_step: int, stage_index: int, stage_name: str, wall: float, parent: dict | None, machine: dict,
             curve: list | None = None) -> None:
    """The checkpoint (the training state but the replay memory, with the curve so far) and the export with its JSON;
    weights that are not finite (a diverged run) are a ValueError and the last checkpoint and export stay."""
    import torch

    if not all(torch.isfinite(v).all() for v in q.state_dict().values()):
        raise ValueError(f"the network's weights are not finite at step {global_step:,} (training diverged); "
                         f"{run_dir} keeps its last checkpoint and export")
    save_torch(os.path.join(run_dir, "checkpoint.pt"), {
        "model": q.state_dict(), "optimizer": optimizer.state_dict(), "global_step": global_step,
        "stage": stage_index, "wall": wall, "args": dataclasses.asdict(args), "script": script,
        "numpy_rng": rng.bit_generator.state, "torch_rng": torch.get_rng_state(), "parent": parent,
        "target": target.state_dict(), "curve": curve or [], **q.network()})
    threads = torch.get_num_threads()
    export_model(q, args, {
        "global_step": global_step, "stage": stage_name, "wall_seconds": round(wall),
        "machine": f"{machine['cores']}-core {machine['cpu']}, {threads} torch thread(s)", "torch_threads": threads,
        "provenance": {**machine, "torch_threads": threads, "device": str(device_of(q)), "env_steps": global_step,
                       "wall_seconds": round(wall, 1),
                       "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")},
        "parent": parent})


def load_mean_weights(q: Any, blob: dict, path: str, script: str) -> Any:
    """q with the mean weights of a file read by read_model (its noisy layers' sigmas stay), checked to fit q and to
    be finite, in one-line ValueErrors; noise off, in eval mode."""
    import torch

    weights = blob.get("weights", blob.get("model"))
    differ = shapes_differ(*({k: tuple(v.shape) for k, v in w.items() if "sigma" not in k and "eps" not in k}
                             for w in (q.state_dict(), weights)))
    if differ:
        raise ValueError(f"{path}: weights do not match {script}.py's network ({differ}); a model of a changed copy of "
                         "the trainer: evaluate.py --trainer COPY.py")
    try:
        q.load_state_dict({k: v.float() for k, v in weights.items()}, strict=False)
    except UNREADABLE as e:
        raise ValueError(f"{path}: weights do not match this network ({reason(e)})") from None
    if not all(torch.isfinite(v).all() for v in q.state_dict().values()):
        raise ValueError(f"{path}: its weights are not finite (the run that made it diverged)")
    q.reset_noise(False)
    return q.eval()


def check_network_size(build: Any, flags: str) -> None:
    """A one-line error, before any memory is taken, when the network `build()` makes cannot be described or its
    online and target copies with Adam's two moments (16 bytes a weight) exceed this machine's memory."""
    import torch

    try:
        with torch.device("meta"):
            weights = sum(w.numel() for w in build().parameters())
    except RuntimeError as e:  # a shape past what torch can describe
        raise ValueError(f"the network cannot be built ({reason(e)}); see {flags}") from None
    fits_in_memory(16 * weights, f"the network ({weights:,} weights; {flags})")


def restore_run(state: dict, path: str, q: Any, target: Any, optimizer: Any, rng: np.random.Generator,
                learning_rate: float, seed: int) -> None:
    """A checkpoint's online and target weights, optimizer and random states put back, at `learning_rate` (the
    flag's, not the saved one: a diverged run resumes slower); with a `seed` other than the run's, the random states
    stay as that seed set them (other maps, coin flips and noise); a state that does not fit is a one-line error."""
    import torch

    try:
        q.load_state_dict(state["model"])
        target.load_state_dict(state.get("target") or state["model"])
        optimizer.load_state_dict(state["optimizer"])
        for group in optimizer.param_groups:
            group["lr"] = learning_rate
        if state.get("args", {}).get("seed", seed) == seed:
            rng.bit_generator.state = state["numpy_rng"]
            torch.set_rng_state(state["torch_rng"])
    except UNREADABLE as e:
        raise ValueError(f"{path}: does not fit this run ({reason(e)})") from None


def summary_writer(args: Any, run_dir: str) -> Any:
    """CleanRL's logging: a TensorBoard SummaryWriter in run_dir with the flags as its hyperparameters text and, with
    --track, Weights & Biases mirroring it (close it with close_writer)."""
    from torch.utils.tensorboard import SummaryWriter

    flags = dataclasses.asdict(args)
    if args.track:
        import wandb

        wandb.init(project=args.wandb_project_name, entity=args.wandb_entity, sync_tensorboard=True, config=flags,
                   name=os.path.basename(run_dir), dir=run_dir, save_code=True)
    writer = SummaryWriter(run_dir)
    writer.add_text("hyperparameters", "|param|value|\n|-|-|\n" + "\n".join(f"|{k}|{v}|" for k, v in flags.items()))
    return writer


def close_writer(writer: Any, track: bool) -> None:
    """The end of summary_writer's logging (and of its Weights & Biases run)."""
    writer.close()
    if track:
        import wandb

        wandb.finish()


def progress_bar(total: int, initial: int, quiet: bool):
    """A tqdm bar over environment steps; off with --quiet or when stdout is not a terminal."""
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, unit="step", unit_scale=True, dynamic_ncols=True,
                disable=quiet or not sys.stdout.isatty())


def device_of(q: Any):
    """Where a network's weights live (the CPU for one without any)."""
    import torch

    return next(q.parameters(), torch.empty(0)).device


def to_torch(maps: np.ndarray, extras: np.ndarray, device: Any = None) -> tuple:
    """A stack's maps and extras as tensors, on `device` (default: the CPU, without a copy)."""
    import torch

    maps, extras = torch.from_numpy(np.ascontiguousarray(maps)), torch.from_numpy(extras)
    if device is None or device.type == "cpu":
        return maps, extras
    return maps.to(device, non_blocking=True), extras.to(device, non_blocking=True)


# ----------------------------------------------------------------------------- maps on disk
@dataclass
class Scenario:
    """A map with optional agent starts and initial coverage (row-major, obstacle=True)."""

    obstacles: np.ndarray
    starts: np.ndarray | None = None
    covered: np.ndarray | None = None


def check_map_side(h: int, w: int, where: str) -> None:
    """A ValueError naming the limit if an h x w map is larger than MAX_MAP_SIDE on a side."""
    if max(h, w) > MAX_MAP_SIDE:
        raise ValueError(f"{where}: a {h}x{w} map is larger than the largest map side allowed, "
                         f"{MAX_MAP_SIDE} (gridworld.MAX_MAP_SIDE)")


def _parse_rows(rows: list[str], path: str, first_line: int) -> Scenario:
    if not rows:
        raise ValueError(f"{path}: no map rows")
    widths = {len(r) for r in rows}
    if len(widths) != 1:
        raise ValueError(f"{path}: ragged rows (lengths {sorted(widths)})")
    check_map_side(len(rows), len(rows[0]), path)
    chars = np.array([list(r) for r in rows])
    known = FREE_CHARS | BLOCKED_CHARS | set("0123456789x")
    unknown = ~np.isin(chars, list(known))
    if unknown.any():
        y, x = np.argwhere(unknown)[0]
        raise ValueError(f"{path}: unknown character {str(chars[y, x])!r} at line {first_line + y}, "
                         f"column {x + 1}")
    obstacles = np.isin(chars, list(BLOCKED_CHARS))
    digits = np.char.isdigit(chars)
    starts = None
    if digits.any():
        ids = chars[digits].astype(int)
        if len(set(ids.tolist())) != len(ids) or set(ids.tolist()) != set(range(len(ids))):
            raise ValueError(f"{path}: agent starts must be the digits 0..{len(ids) - 1}, once each")
        starts = np.argwhere(digits)[np.argsort(ids)]
    covered = chars == "x"
    return Scenario(obstacles, starts, covered if covered.any() else None)


def load_map(path: str) -> Scenario:
    """Load a MovingAI `.map` file or a plain ASCII map (`.` free, `@`/`#` obstacle, `x` covered,
    digits 0-9 agent starts). Raises ValueError naming the file and the problem."""
    path = os.fspath(path)
    try:
        if os.path.isfile(path) and os.path.getsize(path) > MAX_MAP_FILE_BYTES:
            raise ValueError(f"{path}: over {MAX_MAP_FILE_BYTES >> 20} MB, larger than any map of at most "
                             f"{MAX_MAP_SIDE}x{MAX_MAP_SIDE} cells (gridworld.MAX_MAP_SIDE)")
        with open(path, encoding="utf-8") as f:
            lines = f.read().splitlines()
    except OSError as e:
        raise ValueError(f"{path}: cannot read map ({e.strerror})") from None
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text map file") from None
    if path.endswith(".map"):
        header = [ln.split() for ln in lines[:4]]
        if (len(header) < 4 or header[0][:1] != ["type"] or header[1][:1] != ["height"]
                or header[2][:1] != ["width"] or header[3] != ["map"]):
            raise ValueError(f"{path}: bad MovingAI header (expected type/height/width/map lines)")
        try:
            h, w = int(header[1][1]), int(header[2][1])
        except (IndexError, ValueError):
            raise ValueError(f"{path}: bad MovingAI header (height/width not integers)") from None
        check_map_side(h, w, path)
        rows = [ln for ln in lines[4:] if ln.strip()]
        if len(rows) != h or any(len(r) != w for r in rows):
            raise ValueError(f"{path}: header says {h}x{w} but the rows do not match")
        scenario = _parse_rows(rows, path, 5)
    else:
        scenario = _parse_rows([ln.rstrip() for ln in lines if ln.strip()], path, 1)
    check_scenario(scenario, path)
    return scenario


def save_map(path: str, scenario: Scenario) -> None:
    """Write a plain ASCII map (the format `load_map` reads for non-.map files)."""
    if scenario.starts is not None and len(scenario.starts) > 10:
        raise ValueError(f"{path}: the ASCII format holds at most 10 agent starts (digits 0-9)")
    chars = np.where(scenario.obstacles, "@", ".").astype("<U1")
    if scenario.covered is not None:
        chars[scenario.covered & ~scenario.obstacles] = "x"
    if scenario.starts is not None:
        for i, (y, x) in enumerate(scenario.starts):
            chars[y, x] = str(i)
    with staged_output(path, "dataset", overwrite=True, flag="map") as tmp, open(tmp, "w") as f:
        f.write("\n".join("".join(r) for r in chars) + "\n")


def check_scenario(s: Scenario, where: str = "map") -> None:
    """Raise ValueError if a scenario cannot be fully covered as given."""
    free = ~s.obstacles
    if not free.any():
        raise ValueError(f"{where}: no free cell")
    if s.starts is not None:
        st = np.asarray(s.starts)
        h, w = s.obstacles.shape
        if st.ndim != 2 or st.shape[1] != 2:
            raise ValueError(f"{where}: starts must be a list of [row, col]")
        inside = (st[:, 0] >= 0) & (st[:, 0] < h) & (st[:, 1] >= 0) & (st[:, 1] < w)
        if not inside.all():
            raise ValueError(f"{where}: start {st[~inside][0].tolist()} is out of bounds ({h}x{w})")
        if s.obstacles[st[:, 0], st[:, 1]].any():
            y, x = st[s.obstacles[st[:, 0], st[:, 1]]][0]
            raise ValueError(f"{where}: start [{y}, {x}] is on an obstacle")
        if len({(int(y), int(x)) for y, x in st}) != len(st):
            raise ValueError(f"{where}: duplicate starts")
    if not one_component(free[None])[0]:
        raise ValueError(f"{where}: free cells are not one 4-connected component; full coverage "
                         "is impossible")


def generate_scenarios(n: int, seed: int = 0, **config) -> list[Scenario]:
    """n random scenarios drawn by Algorithms 9-10 with the given settings (initial state:
    obstacles, agent starts, pre-covered cells including the starts)."""
    core = GridWorldCore(EnvConfig.from_dict(config), n, seed=seed)
    core.reset()
    return core.snapshot()


def save_dataset(path: str, scenarios: list[Scenario], **columns: np.ndarray) -> None:
    """Save scenarios as compressed .npz: obstacles (M,H,W) padded with obstacles, sizes (M,2),
    starts (M,Nmax,2) padded with -1, covered (M,H,W), plus any per-scenario `columns` (M, ...)
    such as the settings a scenario was drawn with (read them with np.load)."""
    if not scenarios:
        raise ValueError(f"{path}: no scenarios to save")
    reserved = {"obstacles", "sizes", "starts", "covered"}
    for name, col in columns.items():
        if name in reserved or len(col) != len(scenarios):
            raise ValueError(f"{path}: column {name!r} must be new and have one row per scenario")
    obstacles, sizes, starts, covered = _stack(scenarios)
    with staged_output(path, "dataset", overwrite=True, flag="dataset") as tmp:
        np.savez_compressed(tmp, obstacles=obstacles, sizes=sizes, starts=starts, covered=covered, **columns)


def _stack(scenarios: list[Scenario]) -> tuple[np.ndarray, ...]:
    """Scenarios as padded arrays: obstacles, sizes, starts (-1 padded), covered."""
    H = max(s.obstacles.shape[0] for s in scenarios)
    W = max(s.obstacles.shape[1] for s in scenarios)
    n = max((0 if s.starts is None else len(s.starts)) for s in scenarios)
    obstacles = np.ones((len(scenarios), H, W), bool)
    covered = np.zeros((len(scenarios), H, W), bool)
    starts = np.full((len(scenarios), n, 2), -1, np.int16)
    sizes = np.array([s.obstacles.shape for s in scenarios], np.int16)
    for i, s in enumerate(scenarios):  # one small copy per scenario
        h, w = s.obstacles.shape
        obstacles[i, :h, :w] = s.obstacles
        if s.covered is not None:
            covered[i, :h, :w] = s.covered
        if s.starts is not None:
            starts[i, :len(s.starts)] = s.starts
    return obstacles, sizes, starts, covered


def check_scenarios(scenarios: list[Scenario], where: str = "scenarios") -> None:
    """check_scenario for many scenarios at once; the error names the first bad one."""
    bad = _invalid_scenarios(*_stack(scenarios)[:3])
    if bad.any():
        i = int(np.argmax(bad))
        check_scenario(scenarios[i], f"{where}[{i}]")


def load_dataset(path: str) -> list[Scenario]:
    """Scenarios saved by save_dataset; raises ValueError naming the file for anything else (a
    missing, truncated or foreign file, missing arrays, wrong shapes or types, unusable maps)."""
    path = os.fspath(path)

    def bad(problem):
        return ValueError(f"{path}: not a gridworld dataset ({problem})")

    if not os.path.isfile(path):
        raise bad("no such file" if not os.path.exists(path) else "not a file")
    if not zipfile.is_zipfile(path):
        raise bad("not an .npz archive")
    try:  # the shapes first, from the .npy headers, so that nothing too large is ever decompressed
        shapes = _npz_shapes(path)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as e:
        raise bad((str(e).splitlines() or [type(e).__name__])[0]) from None
    shape = shapes.get("obstacles")
    if shape is not None and len(shape) == 3:
        check_map_side(shape[1], shape[2], path)
    for name, shape in shapes.items():
        if math.prod(shape) > MAX_DATASET_CELLS:
            raise ValueError(f"{path}: its {name!r} array of shape {shape} holds {math.prod(shape):,} values, more than "
                             f"the {MAX_DATASET_CELLS:,} allowed (gridworld.MAX_DATASET_CELLS); split the dataset")
    try:
        with np.load(path) as data:
            arrays = {k: data[k] for k in ("obstacles", "sizes", "starts", "covered") if k in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as e:
        raise bad((str(e).splitlines() or [type(e).__name__])[0]) from None
    missing = [k for k in ("obstacles", "sizes", "starts") if k not in arrays]
    if missing:
        raise bad(f"no {missing[0]!r} array")
    obstacles, sizes, starts = arrays["obstacles"], arrays["sizes"], arrays["starts"]
    covered = arrays.get("covered", np.zeros_like(obstacles))
    if obstacles.ndim != 3 or sizes.ndim != 2 or starts.ndim != 3:
        raise bad("arrays of inconsistent shapes")
    M, H, W = obstacles.shape
    if (sizes.shape != (M, 2) or len(starts) != M or starts.shape[-1:] != (2,) or covered.shape != obstacles.shape):
        raise bad("arrays of inconsistent shapes")
    if M == 0:
        raise bad("no scenarios")
    for name, a in (("obstacles", obstacles), ("covered", covered)):
        if a.dtype != bool and not (a.dtype.kind in "iu" and np.isin(a, (0, 1)).all()):
            raise bad(f"{name} must be boolean, got {a.dtype}")
    for name, a in (("sizes", sizes), ("starts", starts)):
        if a.dtype.kind not in "iu":
            raise bad(f"{name} must be integers, got {a.dtype}")
    if (sizes < 1).any() or (sizes[:, 0] > H).any() or (sizes[:, 1] > W).any():
        raise bad(f"sizes must lie in 1..{H} x 1..{W}")
    obstacles, covered = obstacles.astype(bool, copy=False), covered.astype(bool, copy=False)
    out = []
    for i, (h, w) in enumerate(sizes):  # one small copy per scenario
        st = starts[i][starts[i, :, 0] >= 0]
        out.append(Scenario(obstacles[i, :h, :w].copy(), st if len(st) else None,
                            covered[i, :h, :w].copy() if covered[i].any() else None))
    check_scenarios(out, path)
    return out


def _npz_shapes(path: str) -> dict[str, tuple[int, ...]]:
    """The shape of each array of an .npz, read from the .npy headers alone (nothing is decompressed past them);
    arrays whose header this numpy cannot read are left out."""
    shapes = {}
    with zipfile.ZipFile(path) as archive:
        for info in archive.infolist():
            if not info.filename.endswith(".npy"):
                continue
            with archive.open(info) as f:
                version = np.lib.format.read_magic(f)
                if version == (1, 0):
                    shape = np.lib.format.read_array_header_1_0(f)[0]
                elif version == (2, 0):
                    shape = np.lib.format.read_array_header_2_0(f)[0]
                else:
                    continue
            shapes[info.filename[:-len(".npy")]] = tuple(int(n) for n in shape)
    return shapes


def _invalid_scenarios(obstacles: np.ndarray, sizes: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Batch form of check_scenario over padded arrays: True where a scenario is unusable."""
    M, H, W = obstacles.shape
    inmap = (np.arange(H)[:, None] < sizes[:, None, None, 0]) & (np.arange(W) < sizes[:, None, None, 1])
    free = ~obstacles & inmap
    bad = ~free.any((1, 2)) | ~one_component(free)
    used = starts[..., 0] >= 0
    y, x = np.clip(starts[..., 0], 0, H - 1), np.clip(starts[..., 1], 0, W - 1)
    outside = ((starts[..., 0] >= sizes[:, None, 0]) | (starts[..., 1] >= sizes[:, None, 1])
               | (starts[..., 1] < 0))
    on_obstacle = obstacles[np.arange(M)[:, None], y, x]
    same = (starts[:, :, None] == starts[:, None, :]).all(-1) & used[:, :, None] & used[:, None, :]
    duplicate = same.sum((1, 2)) > used.sum(1)
    return bad | (used & (outside | on_obstacle)).any(1) | duplicate


# ----------------------------------------------------------------------------- grid helpers
def _pack(m: np.ndarray) -> np.ndarray:
    """Bool (..., H, W) -> bitboard (..., H, ceil(W/64)) uint64, bit x%64 of word x//64."""
    packed = np.packbits(m, axis=-1, bitorder="little")
    out = np.zeros(m.shape[:-1] + (-(-m.shape[-1] // 64) * 8,), np.uint8)
    out[..., :packed.shape[-1]] = packed
    return out.view(np.uint64)


def _unpack(bits: np.ndarray, W: int) -> np.ndarray:
    return np.unpackbits(bits.view(np.uint8), axis=-1, count=W, bitorder="little").view(bool)


def _dilate(f: np.ndarray) -> np.ndarray:
    """A bitboard grown by its 4-neighbourhood (cells past the edges fall off)."""
    out = f.copy()
    out[..., 1:, :] |= f[..., :-1, :]
    out[..., :-1, :] |= f[..., 1:, :]
    out |= f << np.uint64(1)
    out[..., 1:] |= f[..., :-1] >> np.uint64(63)
    out |= f >> np.uint64(1)
    out[..., :-1] |= f[..., 1:] << np.uint64(63)
    return out


def flood(passable: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """Cells of `passable` 4-connected to `seed`, for a batch (B, H, W) at once."""
    pas = _pack(passable)
    reach = _pack(seed) & pas
    while True:
        grown = _dilate(reach) & pas
        if np.array_equal(grown, reach):
            return _unpack(reach, passable.shape[-1])
        reach = grown


def one_component(free: np.ndarray) -> np.ndarray:
    """Whether the free cells of each map of a batch (B, H, W) are one 4-connected component (B,); no free cell
    counts as one."""
    B = len(free)
    seed = np.zeros_like(free)
    seed.reshape(B, -1)[np.arange(B), free.reshape(B, -1).argmax(1)] = True
    return (flood(free, seed & free) == free).all((1, 2))


def _distance_from(passable: np.ndarray, seed: np.ndarray) -> np.ndarray:
    """Steps from the nearest `seed` cell to every cell of `passable` (4-connected, -1 where unreachable), for a
    batch (B, H, W) at once."""
    dist = np.where(seed & passable, 0, -1)
    front, d = seed & passable, 0
    while front.any():
        grown = front.copy()
        grown[:, 1:] |= front[:, :-1]
        grown[:, :-1] |= front[:, 1:]
        grown[:, :, 1:] |= front[:, :, :-1]
        grown[:, :, :-1] |= front[:, :, 1:]
        d += 1
        front = grown & passable & (dist < 0)
        dist[front] = d
    return dist


@functools.lru_cache(maxsize=16)
def _block_mean_table(scales: int, factor: int) -> tuple[np.ndarray, np.ndarray]:
    """The multiscale observation's rounding: table[offsets[s] + n] = round-half-up(255 * n / a) (uint8) for
    n = 0..a cells of a block of a = factor**(2s) cells at scale s."""
    area = factor ** (2 * np.arange(scales, dtype=np.int64))
    offsets = np.concatenate([[0], np.cumsum(area + 1)[:-1]])
    n = np.concatenate([np.arange(a + 1) for a in area])
    a = np.repeat(area, area + 1)
    table = ((510 * n + a) // (2 * a)).astype(np.uint8)
    table.flags.writeable = offsets.flags.writeable = False  # shared by every core (cached)
    return table, offsets


def _line_of_sight_table(r: int) -> tuple[np.ndarray, np.ndarray]:
    """Offsets of the (2r+1)^2 sensor square and, for each, the cells strictly between the
    agent and it on a DDA line (padded with the agent's own cell)."""
    d = np.arange(-r, r + 1)
    offsets = np.stack(np.meshgrid(d, d, indexing="ij"), -1).reshape(-1, 2)
    n = np.abs(offsets).max(1)
    k = np.arange(1, max(r, 2))
    frac = k[None, :] / np.maximum(n, 1)[:, None]
    between = np.floor(offsets[:, None, :] * frac[..., None] + 0.5).astype(np.int64)
    between[k[None, :] >= n[:, None]] = 0
    return offsets, between


# ----------------------------------------------------------------------------- map families
# Structured maps beside Algorithm 9's random ones (EnvConfig.map_family, shaped by FamilyParams). A generator draws
# k maps at once as a (k, H, W) obstacle array, map b of sides hw[b] in the top-left corner and True outside it; the
# free cells of each form one 4-connected region by construction, so Algorithm 10 removes nothing. Loops run over
# partition levels, lattice merge rounds or placement rounds, never over cells or worlds.
def structured_obstacles(family: str, rng: np.random.Generator, hw: np.ndarray, H: int, W: int,
                         params: FamilyParams | None = None) -> np.ndarray:
    """Obstacles (k, H, W) of k maps of a structured family with sides hw (k, 2), True outside each map.

    Maps too small for the family's structure come out open; every map keeps >= 2 free cells, all 4-connected."""
    params = FamilyParams() if params is None else params
    params.validate()
    if family not in STRUCTURED_FAMILIES:
        raise ValueError(f"unknown structured map family {family!r}, expected one of {STRUCTURED_FAMILIES}")
    hw = np.asarray(hw, np.int64).reshape(-1, 2)
    if len(hw) and ((hw < 2).any() or (hw[:, 0] > H).any() or (hw[:, 1] > W).any()):
        raise ValueError(f"map sides must be >= 2 and fit the {H}x{W} canvas, got {hw.min(0).tolist()}..{hw.max(0).tolist()}")
    inmap = (np.arange(H)[None, :, None] < hw[:, 0, None, None]) & (np.arange(W)[None, None, :] < hw[:, 1, None, None])
    if not len(hw):
        return ~inmap
    whole = {f.name: tuple(int(v) for v in getattr(params, f.name)) for f in dataclasses.fields(params)
             if isinstance(getattr(params, f.name), (tuple, list)) and f.name != "block_count"}
    params = dataclasses.replace(params, **whole)  # 4.0 from YAML indexes like 4
    walls = {"rooms": _rooms, "corridors": _corridors, "clutter": _clutter, "maze": _maze}[family](rng, hw, H, W, params)
    walls &= inmap
    too_few = (inmap & ~walls).sum((1, 2)) < 2
    walls[too_few] = False  # safety net: a map without room for an agent and a cell to cover is drawn open
    return walls | ~inmap


def _uniform_int(rng, lo, hi) -> np.ndarray:
    """One integer in [lo, hi] per entry of the broadcast arrays lo, hi (inclusive)."""
    lo, hi = np.broadcast_arrays(np.asarray(lo, np.int64), np.asarray(hi, np.int64))
    return rng.integers(lo, hi + 1) if lo.size else lo.copy()


def _paint_rects(k: int, H: int, W: int, b, y0, y1, x0, x1) -> np.ndarray:
    """(k, H, W) bool: cells inside any rectangle [y0, y1) x [x0, x1) of world b (flat arrays; clipped to the canvas)."""
    b, y0, y1, x0, x1 = (np.ravel(a).astype(np.int64) for a in (b, y0, y1, x0, x1))
    y0, y1, x0, x1 = np.clip(y0, 0, H), np.clip(y1, 0, H), np.clip(x0, 0, W), np.clip(x1, 0, W)
    keep = (y1 > y0) & (x1 > x0)
    b, y0, y1, x0, x1 = b[keep], y0[keep], y1[keep], x0[keep], x1[keep]
    base = b * ((H + 1) * (W + 1))
    corners = np.concatenate([base + y0 * (W + 1) + x0, base + y0 * (W + 1) + x1,
                              base + y1 * (W + 1) + x0, base + y1 * (W + 1) + x1])
    signs = np.repeat(np.array([1.0, -1.0, -1.0, 1.0]), len(b))
    diff = np.bincount(corners, signs, k * (H + 1) * (W + 1)).reshape(k, H + 1, W + 1)  # 2-D difference array
    return diff.cumsum(1).cumsum(2)[:, :H, :W] > 0.5


def _lattice(NH: int, NW: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Links of an NH x NW lattice: endpoints u, v (node = i * NW + j) and orientation (True = horizontal, v right of u)."""
    node = np.arange(NH * NW).reshape(NH, NW)
    u = np.concatenate([node[:, :-1].ravel(), node[:-1, :].ravel()])
    v = np.concatenate([node[:, 1:].ravel(), node[1:, :].ravel()])
    horizontal = np.arange(len(u)) < NH * (NW - 1)
    return u, v, horizontal


def _random_spanning_tree(rng, u: np.ndarray, v: np.ndarray, usable: np.ndarray, n: int) -> np.ndarray:
    """(k, E) bool: a random minimum spanning forest of the usable links of each world (Boruvka with random weights).

    Batched Boruvka: every round each component takes its lightest outgoing link and components merge by pointer
    jumping, so the loop runs O(log n) rounds for all k worlds at once. Random-weight MSTs make Kruskal-like mazes
    (many short dead ends), not uniform spanning trees; Wilson/Aldous-Broder would be uniform but are sequential."""
    k, E = usable.shape
    weight = rng.integers(0, 1 << 40, (k, E)) * E + np.arange(E)  # distinct within a world: no ties, so no cycles
    big = np.iinfo(np.int64).max
    weight[~usable] = big
    label = np.arange(k * n).reshape(k, n)  # component ids are global (world * n + node) so worlds never mix
    tree = np.zeros((k, E), bool)
    while True:
        lu, lv = label[:, u], label[:, v]
        cross = usable & (lu != lv)
        if not cross.any():
            return tree
        w = np.where(cross, weight, big)
        best = np.full(k * n, big)
        np.minimum.at(best, lu[cross], w[cross])
        np.minimum.at(best, lv[cross], w[cross])
        by_u, by_v = cross & (w == best[lu]), cross & (w == best[lv])
        tree |= by_u | by_v
        parent = np.arange(k * n)
        parent[lu[by_u]] = lv[by_u]
        parent[lv[by_v]] = lu[by_v]
        mutual = (parent[parent] == np.arange(k * n)) & (np.arange(k * n) < parent)
        parent[mutual] = np.flatnonzero(mutual)  # two components that chose the same link: the smaller id is the root
        while True:
            jumped = parent[parent]
            if np.array_equal(jumped, parent):
                break
            parent = jumped
        label = parent[label]


def _carve_links(k, H, W, Y, X, u, v, horizontal, open_, width) -> np.ndarray:
    """(k, H, W) bool: open lattice links carved as passages from node (Y_i, X_j) to the next node, `width` thick."""
    NW = X.shape[1]
    iu, ju, iv, jv = u // NW, u % NW, v // NW, v % NW
    wdt = np.broadcast_to(width, open_.shape)[open_]
    bi = np.broadcast_to(np.arange(k)[:, None], open_.shape)
    yu, xu = Y[bi, iu[None]][open_], X[bi, ju[None]][open_]
    yv, xv = Y[bi, iv[None]][open_], X[bi, jv[None]][open_]
    horiz = np.broadcast_to(horizontal, open_.shape)[open_]
    y1 = np.where(horiz, yu + wdt, yv + wdt)  # top-left aligned: a passage covers both endpoint nodes' corners
    x1 = np.where(horiz, xv + wdt, xu + wdt)
    return _paint_rects(k, H, W, bi[open_], yu, y1, xu, x1)


def _incident(u: np.ndarray, v: np.ndarray, horizontal: np.ndarray, n: int) -> np.ndarray:
    """(n, 4) link ids touching each node (-1 where none): its links to the right, left, below and above."""
    inc = np.full((n, 4), -1)
    e = np.arange(len(u))
    slot = np.where(horizontal, 0, 2)  # horizontal links fill slots 0/1, vertical ones 2/3
    inc[u, slot] = e
    inc[v, slot + 1] = e
    return inc


def _rooms(rng, hw, H, W, p: FamilyParams) -> np.ndarray:
    """Binary space partition: split every room longer than room_size[1] by a 1-cell wall at a random position keeping
    both parts >= room_size[0] (or as large as fits), then cut one door per wall where it joins free cells on both sides."""
    k = len(hw)
    rmin, rmax = p.room_size
    y0, x0 = np.zeros((k, 1), np.int64), np.zeros((k, 1), np.int64)
    y1, x1 = hw[:, :1].copy(), hw[:, 1:].copy()
    alive = np.ones((k, 1), bool)
    walls = []  # per level: (world, horizontal?, position, start, end) of each new wall
    while True:
        hgt, wid = y1 - y0, x1 - x0
        long_side = np.maximum(hgt, wid)
        split = alive & (long_side > rmax) & (long_side >= 3)
        if not split.any():
            break
        across = (hgt > wid) | ((hgt == wid) & (rng.random(hgt.shape) < 0.5))  # split the longer side: squarish rooms
        size = np.where(across, hgt, wid)
        m = np.clip(np.minimum(rmin, (size - 1) // 2), 1, None)  # smallest part: room_size[0], or what fits
        cut = _uniform_int(rng, m, np.maximum(size - 1 - m, m))  # wall offset from the room's start
        start = np.where(across, y0, x0)
        pos = start + cut
        bi = np.broadcast_to(np.arange(k)[:, None], split.shape)
        walls.append((bi[split], across[split], pos[split], np.where(across, x0, y0)[split], np.where(across, x1, y1)[split]))
        # the first part keeps the slot, the second part goes to a new slot
        ny0 = np.where(split & ~across, y0, np.where(split, pos + 1, y0))
        nx0 = np.where(split & across, x0, np.where(split, pos + 1, x0))
        a_y1 = np.where(split & across, pos, y1)
        a_x1 = np.where(split & ~across, pos, x1)
        y0, x0, y1, x1 = (np.concatenate([a, c], 1) for a, c in ((y0, ny0), (x0, nx0), (a_y1, y1), (a_x1, x1)))
        alive = np.concatenate([alive, split], 1)
        order = np.argsort(~alive, 1, kind="stable")[:, :alive.sum(1).max()]  # compact: live rooms first
        y0, x0, y1, x1, alive = (np.take_along_axis(a, order, 1) for a in (y0, x0, y1, x1, alive))
    if not walls:
        return np.zeros((k, H, W), bool)
    b, horiz, pos, lo, hi = (np.concatenate(c) for c in zip(*walls))
    wall = _paint_rects(k, H, W, b, np.where(horiz, pos, lo), np.where(horiz, pos + 1, hi),
                  np.where(horiz, lo, pos), np.where(horiz, hi, pos + 1))
    # door candidates: wall cells whose two cross neighbours are free (never a T-junction, so it joins both sides)
    L = max(H, W)
    t = lo[:, None] + np.arange(L)
    inside = t < hi[:, None]
    hz, pc, bb = horiz[:, None], pos[:, None], b[:, None]

    def beside(offset):  # wall map at the cells `offset` across the wall from each of its cells
        r = np.clip(np.where(hz, pc + offset, t), 0, H - 1)
        c = np.clip(np.where(hz, t, pc + offset), 0, W - 1)
        return wall[bb, r, c]

    ok = inside & ~beside(-1) & ~beside(1)
    d = np.minimum(_uniform_int(rng, np.full(len(b), p.door_width[0]), np.full(len(b), p.door_width[1])),
                   np.maximum((hi - lo) // 2, 1))  # at most half the wall: it stays a wall, not a stub
    cs = np.concatenate([np.zeros((len(b), 1), np.int64), ok.cumsum(1)], 1)
    end = np.minimum(np.arange(L)[None] + d[:, None], L)
    run = (np.take_along_axis(cs, end, 1) - cs[:, :-1] == d[:, None]) & ok  # d door cells in a row, all joining
    d = np.where(run.any(1), d, 1)  # no room for a wide door between T-junctions: a 1-cell one (first cell always fits)
    run = np.where(run.any(1)[:, None], run, ok)
    start = lo + np.argmax(np.where(run, rng.random(run.shape), -1.0), 1)
    door = _paint_rects(k, H, W, b, np.where(horiz, pos, start), np.where(horiz, pos + 1, start + d),
                  np.where(horiz, start, pos), np.where(horiz, start + d, pos + 1))
    return wall & ~door


def _corridors(rng, hw, H, W, p: FamilyParams) -> np.ndarray:
    """Passages on a jittered coarse lattice (lines passage_width[1] + passage_gap apart) following a random spanning
    tree, each passage with its own width, plus loop_fraction of the spare links; everything else is rock."""
    k = len(hw)
    wmin, wmax = p.passage_width
    gmin, gmax = p.passage_gap

    def lines(side, n):
        gaps = _uniform_int(rng, np.full((k, n), wmax + gmin), np.full((k, n), wmax + gmax))
        pos = np.concatenate([np.zeros((k, 1), np.int64), gaps[:, :-1].cumsum(1)], 1)
        ok = (pos + wmax <= side[:, None]) | (np.arange(n) == 0)  # the first line always exists (clipped if narrow)
        last = np.where(ok, pos, 0).max(1)
        spare = np.maximum(side - wmax - last, 0)
        m0 = _uniform_int(rng, 0, np.minimum(gmin, spare))  # a little rock at either border, at random
        m1 = _uniform_int(rng, 0, np.minimum(gmin, spare - m0))
        scale = np.where(last > 0, (side - wmax - m0 - m1) / np.maximum(last, 1), 1.0)  # >= 1: fill the side
        return m0[:, None] + np.floor(pos * scale[:, None] + 0.5).astype(np.int64), ok

    NH, NW = (max(S - wmax, 0) // (wmax + gmin) + 1 for S in (H, W))
    Y, vy = lines(hw[:, 0], NH)
    X, vx = lines(hw[:, 1], NW)
    u, v, horizontal = _lattice(NH, NW)
    node_ok = (vy[:, :, None] & vx[:, None, :]).reshape(k, -1)
    usable = node_ok[:, u] & node_ok[:, v]
    open_ = _random_spanning_tree(rng, u, v, usable, NH * NW)
    open_ |= usable & (rng.random(usable.shape) < p.loop_fraction)
    width = _uniform_int(rng, np.full(open_.shape, wmin), np.full(open_.shape, wmax))
    free = _carve_links(k, H, W, Y, X, u, v, horizontal, open_, width)
    return ~free & (node_ok.sum(1) >= 2)[:, None, None]  # a single lattice node has no passage: leave the map open


def _clutter(rng, hw, H, W, p: FamilyParams) -> np.ndarray:
    """Rectangular blocks at random spots of an open room, never touching each other (not even diagonally), so
    each obstacle component is one rectangle and no chain of blocks can enclose free cells."""
    k = len(hw)
    h, w = hw[:, 0], hw[:, 1]
    rate = p.block_count[0] + rng.random(k) * (p.block_count[1] - p.block_count[0])
    target = np.round(rate * h * w / 100).astype(np.int64)
    A = int(target.max()) if k else 0
    by, bx, bh, bw = (np.zeros((k, A), np.int64) for _ in range(4))
    count = np.zeros(k, np.int64)
    lo = np.minimum(p.block_size[0], hw - 1)  # a block never spans a whole side, so it cannot cut the map in two
    hi = np.minimum(p.block_size[1], hw - 1)
    for _ in range(12):  # placement rounds: the map fills up, so later rounds accept fewer candidates
        need = target - count
        if A == 0 or need.max() <= 0:
            break
        M = int(min(need.max() + 4, 64))
        ch = _uniform_int(rng, np.broadcast_to(lo[:, :1], (k, M)), np.broadcast_to(hi[:, :1], (k, M)))
        cw = _uniform_int(rng, np.broadcast_to(lo[:, 1:], (k, M)), np.broadcast_to(hi[:, 1:], (k, M)))
        cy, cx = _uniform_int(rng, 0, h[:, None] - ch), _uniform_int(rng, 0, w[:, None] - cw)

        def touch(ay, ax, ah, aw, qy, qx, qh, qw):  # 8-adjacent or overlapping: no free cell between them
            return (ay <= qy + qh) & (qy <= ay + ah) & (ax <= qx + qw) & (qx <= ax + aw)

        placed = np.arange(A)[None, None, :] < count[:, None, None]
        clash = (touch(cy[..., None], cx[..., None], ch[..., None], cw[..., None], by[:, None], bx[:, None], bh[:, None],
                       bw[:, None]) & placed).any(2)
        pair = touch(cy[:, :, None], cx[:, :, None], ch[:, :, None], cw[:, :, None], cy[:, None], cx[:, None], ch[:, None],
                     cw[:, None])
        ok = ~clash
        earlier = np.tril(np.ones((M, M), bool), -1)  # candidate j yields to any earlier non-clashing candidate it touches
        ok &= ~(pair & earlier & ok[:, None, :]).any(2)
        ok &= ok.cumsum(1) <= need[:, None]
        slot = count[:, None] + ok.cumsum(1) - 1
        bi = np.broadcast_to(np.arange(k)[:, None], ok.shape)
        for dst, src in ((by, cy), (bx, cx), (bh, ch), (bw, cw)):
            dst[bi[ok], slot[ok]] = src[ok]
        count += ok.sum(1)
    used = np.arange(A)[None] < count[:, None]
    bi = np.broadcast_to(np.arange(k)[:, None], used.shape)
    return _paint_rects(k, H, W, bi[used], by[used], (by + bh)[used], bx[used], (bx + bw)[used])


def _maze(rng, hw, H, W, p: FamilyParams) -> np.ndarray:
    """Braided maze: a random spanning tree on a lattice of c x c cells with 1-cell walls (c in maze_width), then
    `braid` of its dead ends knocked through to a random neighbour they were not joined to, which closes loops."""
    k = len(hw)
    c = _uniform_int(rng, np.full(k, p.maze_width[0]), np.full(k, p.maze_width[1]))
    c = np.clip(c, 1, np.maximum((hw.min(1) - 1) // 2, 1))  # narrow the corridors until 2 x 2 cells fit
    pitch = c + 1
    nh, nw = (hw[:, 0] + 1) // pitch, (hw[:, 1] + 1) // pitch
    tiny = (nh < 2) | (nw < 2)  # fewer than 2 x 2 maze cells: leave the map open
    NH, NW = int(nh.max()), int(nw.max())
    oy = _uniform_int(rng, 0, hw[:, 0] - (nh * pitch - 1))  # spare rows/cols (< pitch) split between the borders
    ox = _uniform_int(rng, 0, hw[:, 1] - (nw * pitch - 1))
    Y = oy[:, None] + np.arange(NH) * pitch[:, None]
    X = ox[:, None] + np.arange(NW) * pitch[:, None]
    u, v, horizontal = _lattice(NH, NW)
    node_ok = ((np.arange(NH) < nh[:, None])[:, :, None] & (np.arange(NW) < nw[:, None])[:, None, :]).reshape(k, -1)
    usable = node_ok[:, u] & node_ok[:, v]
    open_ = _random_spanning_tree(rng, u, v, usable, NH * NW)
    inc = _incident(u, v, horizontal, NH * NW)
    has = inc >= 0
    incc = np.where(has, inc, 0)
    deg = (open_[:, incc] & has).sum(2)
    dead = (deg == 1) & node_ok & (rng.random(deg.shape) < p.braid)
    closed = usable[:, incc] & ~open_[:, incc] & has
    pick = np.argmax(np.where(closed, rng.random(closed.shape), -1.0), 2)  # a random closed wall of each dead end
    knock = dead & closed.any(2)
    bi, ni = np.nonzero(knock)
    open_[bi, incc[ni, pick[bi, ni]]] = True
    free = _carve_links(k, H, W, Y, X, u, v, horizontal, open_, c[:, None])
    return ~free & ~tiny[:, None, None]


def draw_maps(core: GridWorldCore, k: int) -> None:
    """Algorithm 9 for k random worlds at once: size, the obstacles of a structured map family (if any),
    starts on free cells, Algorithm 9's random obstacles (family "random"), then Algorithm 10 (cells
    unreachable from agent 0 become obstacles); adds the usable ones to the world's pool of maps."""
    cfg, rng, H, W, N = core.config, core.rng, core.H, core.W, core.N
    bidx = np.arange(k)[:, None]
    active = core._active(k)
    side = rng.integers(cfg.min_size, cfg.size + 1, k) if cfg.random_size else np.full(k, cfg.size)
    hw = np.stack([side, side], 1)
    obstacle = ~((np.arange(H)[None, :, None] < side[:, None, None]) &
                 (np.arange(W)[None, None, :] < side[:, None, None]))
    fixed_starts = not cfg.starting_position_random and cfg.starting_position is not None
    if cfg.map_family == "mixed":  # one family per map, index into MAP_FAMILIES (0 = random)
        weights = cfg.map_family_weights or dict.fromkeys(MAP_FAMILIES[:-1], 1.0)
        p = np.array([weights.get(f, 0.0) for f in MAP_FAMILIES[:-1]], float)
        family = rng.choice(len(p), k, p=p / p.sum())
    else:
        family = np.full(k, MAP_FAMILIES.index(cfg.map_family))
    for f, name in enumerate(STRUCTURED_FAMILIES, 1):
        if (family == f).any():
            obstacle[family == f] = structured_obstacles(name, rng, hw[family == f], H, W, cfg.family)
    if fixed_starts and family.any():  # a fixed start on a wall or block: the cell is cleared (walled in: dropped below)
        st = np.atleast_2d(np.asarray(cfg.starting_position, np.int64))
        y, x = st[(st >= 0).all(1) & (st[:, 0] < H) & (st[:, 1] < W)].T
        obstacle[:, y, x] &= (y >= hw[:, :1]) | (x >= hw[:, 1:])  # outside the map stays blocked (_starts says so)
    starts = core._starts(obstacle, hw)
    start_mask = np.zeros((k, H, W), bool)
    start_mask[bidx, starts[..., 0], starts[..., 1]] = active
    scatter = family == 0  # Algorithm 9's obstacles: number_obstacles random cells, never on a start
    if scatter.any():
        ks = int(scatter.sum())
        n_obs = np.minimum(cfg.number_obstacles, side[scatter] * side[scatter] - N - 1)
        if cfg.obstacles_random:
            n_obs = rng.integers(0, n_obs + 1)
        keys = rng.random((ks, H * W))
        keys[(obstacle[scatter] | start_mask[scatter]).reshape(ks, -1)] = np.inf
        rank = np.argsort(np.argsort(keys, 1), 1).reshape(ks, H, W)
        obstacle[scatter] |= rank < n_obs[:, None, None]
    first = np.zeros_like(start_mask)
    first[np.arange(k), starts[:, 0, 0], starts[:, 0, 1]] = True
    obstacle |= ~flood(~obstacle, first)
    lost = active & obstacle[bidx, starts[..., 0], starts[..., 1]]
    if lost.any() and not fixed_starts:  # agents walled off: move them to agent 0's region
        start_mask &= ~obstacle
        spare = core._random_cells(~obstacle & ~start_mask, N)
        starts = np.where(lost[..., None], spare, starts)
        start_mask[bidx, starts[..., 0], starts[..., 1]] |= active
    n_free, n_active = (~obstacle).sum((1, 2)), active.sum(1)
    usable = (n_free > n_active) & ((start_mask & ~obstacle).sum((1, 2)) == n_active)
    if fixed_starts:
        usable &= ~lost.any(1)
    drawn = (obstacle, hw, starts, active, start_mask)
    core.pool = [np.concatenate([p, d[usable]]) for p, d in zip(core.pool, drawn)]


# ----------------------------------------------------------------------------- the core
class GridWorldCore:
    """B independent worlds with up to N agents each, as numpy arrays, stepped together.

    All cell arrays live in canvas coordinates: the largest map (H, W) padded by c = V // 2
    obstacle cells on every side, so a move never needs a bounds check and an agent's
    observation window is a plain strided slice. Agent positions are flat indices into the
    (B, H + 2c, W + 2c) arrays; `agent_cells()` gives [row, col] map coordinates."""

    PATH_TABLE_BYTES = 512 * 2**20  # the rollouts' shortest-path tables kept between calls (_path_tables_of)
    PATH_TABLE_CELLS = 2500  # larger maps search instead (a table is 4 bytes per pair of cells)

    def __init__(self, config: EnvConfig | dict | None = None, num_worlds: int = 1, seed=None):
        self.B = num_worlds
        self.rng = np.random.default_rng(seed)
        self.path_cache, self.path_calls = {}, 0
        self.H = self.W = 0
        self.config = EnvConfig()
        self.configure(config if config is not None else EnvConfig())

    # --- configuration -----------------------------------------------------------------
    def configure(self, config: EnvConfig | dict | None = None, scenarios: list[Scenario] | None = None,
                  **changes) -> None:
        """Change the settings; each world picks them up at its next reset (§4.2.1.1).
        `scenarios` (in memory, checked) replace map_configuration/dataset_path."""
        if isinstance(config, dict):
            config = EnvConfig.from_dict(config)
        config = config or self.config
        config = config.replace(**changes) if changes else config
        config.validate()
        if scenarios is not None:
            scenarios = list(scenarios)
            check_scenarios(scenarios)
        elif config.dataset_path:
            scenarios = load_dataset(config.dataset_path)
        elif config.map_configuration:
            scenarios = [load_map(config.map_configuration)]
        n = config.number_agents
        H = W = config.size
        if scenarios is not None:
            H = max(s.obstacles.shape[0] for s in scenarios)
            W = max(s.obstacles.shape[1] for s in scenarios)
            source = config.dataset_path or config.map_configuration or "scenarios"
            if config.load_state and any(s.starts is None for s in scenarios):
                raise ValueError(f"{source}: load_state needs scenarios with agent starts")
            if config.load_state:
                n = max(len(s.starts) for s in scenarios)
            for i, s in enumerate(scenarios):
                agents = len(s.starts) if config.load_state else n
                if (~s.obstacles).sum() <= agents:
                    raise ValueError(f"{source}[{i}]: {agents} agent(s) leave no free cell to cover")
                if config.load_state and s.covered is not None and not (~s.obstacles & ~s.covered).any():
                    raise ValueError(f"{source}[{i}]: every free cell is already covered")
        if config.starting_position is not None and not config.starting_position_random:
            st = np.atleast_2d(np.asarray(config.starting_position))
            if st.ndim != 2 or st.shape[1] != 2 or len(st) != n:
                raise ValueError(f"starting_position must give {n} [row, col] pair(s), got "
                                 f"{config.starting_position!r}")
        if config.sensor_range > config.view_size // 2:
            raise ValueError(f"sensor_range {config.sensor_range} exceeds the view radius "
                             f"{config.view_size // 2}")
        first = self.H == 0
        if not first and n != self.N:
            raise ValueError("changing number_agents needs a new environment")
        grow = first or H > self.H or W > self.W or config.view_size != self.config.view_size
        old = None if first else (self.agent_cells(), self.hw.copy())
        self.config, self.scenarios, self.next_scenario = config, scenarios, 0
        self.V = config.view_size
        rp = config.reward  # (event, weight) pairs with a non-zero weight, looked up once
        self.reward_terms = tuple(
            tuple((name, np.float32(getattr(rp, name))) for name in names if getattr(rp, name))
            for names in (("repeated_action", "finished", "finished_line", "wall_adjacent"),
                          ("blocked", "revisit", "waited", "timeout")))
        self.los_offsets, self.los_between = _line_of_sight_table(config.sensor_range)
        if grow:
            self._allocate(max(H, self.H), max(W, self.W), n, old)
        H, W, n = self.H, self.W, self.N
        self.pool = [np.zeros((0, H, W), bool), np.zeros((0, 2), np.int64), np.zeros((0, n, 2), np.int64),
                     np.zeros((0, n), bool), np.zeros((0, H, W), bool)]  # drawn random maps

    def _allocate(self, H: int, W: int, N: int, old) -> None:
        """(Re)build the canvas-coordinate arrays, keeping the worlds in progress."""
        c = self.config.view_size // 2
        B, Ph, Pw = self.B, H + 2 * c, W + 2 * c
        fits_in_memory(B * Ph * Pw * CANVAS_BYTES, f"the canvas of {B:,} worlds of {Ph}x{Pw} cells")
        keep = {}
        if old is not None:
            oc = self.c
            keep = {k: getattr(self, k)[:, oc:oc + self.H, oc:oc + self.W]
                    for k in ("obstacle", "covered", "seen", "occupied", "start")}
        self.H, self.W, self.N, self.c, self.Ph, self.Pw = H, W, N, c, Ph, Pw
        self.obstacle = np.ones((B, Ph, Pw), bool)
        self.seen = np.ones((B, Ph, Pw), bool)
        self.covered = np.zeros((B, Ph, Pw), bool)
        self.occupied = np.zeros((B, Ph, Pw), bool)
        self.start = np.zeros((B, Ph, Pw), bool)  # the agents' starting cells: the far-first heuristic's origin
        for k, v in keep.items():
            getattr(self, k)[:, c:c + v.shape[1], c:c + v.shape[2]] = v
        self.canvas = np.zeros((B, Ph, Pw, 4), np.uint8)
        self._bind_views()
        self.delta = np.array([-Pw, Pw, -1, 1, 0], np.int64)
        if old is None:
            self.pos = np.zeros((B, N), np.int64)
            self.active = np.zeros((B, N), bool)
            self.last_action = np.full((B, N), WAIT, np.int64)
            self.frozen = np.zeros((B, N), bool)  # faulty agents (§7.5.3.3)
            self.hw = np.ones((B, 2), np.int64)
            for k in ("battery", "budget", "steps", "new_cells", "agent_moves", "n_poi_start",
                      "n_free", "remaining"):
                setattr(self, k, np.zeros(B, np.int64))
            self.all_active, self.any_large, self.any_frozen = True, False, False
        else:
            b = np.arange(B)[:, None]
            self.pos = np.where(self.active, self._flat(b, old[0][..., 0], old[0][..., 1]),
                                self._flat(b, -c, -c))  # absent agents stay parked
            self._paint_worlds(np.arange(B))

    def _bind_views(self) -> None:
        """The flat views of the cell arrays and the strided observation windows over the canvas."""
        B, Ph, Pw, V = self.B, self.Ph, self.Pw, self.V
        self.canvas32 = self.canvas.view(np.uint32).reshape(-1)
        self.views = {k: getattr(self, k).reshape(-1) for k in ("obstacle", "seen", "covered", "occupied")}
        s = self.canvas32.strides[0]
        self.windows = np.lib.stride_tricks.as_strided(
            self.canvas32, (B * Ph * Pw - (V - 1) * (Pw + 1), V, V), (s, Pw * s, s), writeable=False)

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k not in ("canvas32", "views", "windows", "path_cache")}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)  # pickle copies views apart from their arrays: bind them anew
        self.path_cache = {}
        self._bind_views()

    def _flat(self, b, y, x) -> np.ndarray:
        """Flat canvas index of map cell [y, x] of world b."""
        return (b * self.Ph + y + self.c) * self.Pw + x + self.c

    def agent_cells(self) -> np.ndarray:
        """Agent positions as [row, col] map coordinates, (B, N, 2)."""
        y, x = np.divmod(self.pos % (self.Ph * self.Pw), self.Pw)
        return np.stack([y - self.c, x - self.c], -1)

    # --- episode initialisation (Algorithm 9) -------------------------------------------
    def reset(self, worlds=None, scenarios: list[Scenario] | None = None) -> None:
        """Start new episodes in the given worlds (all by default; a bool mask or indices), or
        restart them in given scenarios (their maps, starts and coverage; e.g. episodes kept
        because the agent failed them, §6.4.2.3)."""
        cfg, rng = self.config, self.rng
        w = self._world_indices(worlds)
        if len(w) == 0:
            return
        k, H, W, N = len(w), self.H, self.W, self.N
        if scenarios is not None:
            if len(scenarios) != k:
                raise ValueError(f"{len(scenarios)} scenarios for {k} worlds")
            check_scenarios(scenarios)
            obstacles, hw, starts, covered = _stack(scenarios)
            if obstacles.shape[1] > H or obstacles.shape[2] > W or starts.shape[1] > N:
                raise ValueError(f"scenarios larger than the worlds ({H}x{W}, {N} agents)")
            active = starts[..., 0] >= 0
            pad = np.ones((k, H, W), bool)
            pad[:, :obstacles.shape[1], :obstacles.shape[2]] = obstacles
            cov = np.zeros((k, H, W), bool)
            cov[:, :covered.shape[1], :covered.shape[2]] = covered
            full = np.zeros((k, N, 2), np.int64)
            full[:, :starts.shape[1]] = np.maximum(starts, 0)
            act = np.zeros((k, N), bool)
            act[:, :starts.shape[1]] = active
            start_mask = np.zeros((k, H, W), bool)
            start_mask[np.arange(k)[:, None], full[..., 0], full[..., 1]] = act
            return self._init_worlds(w, pad, hw.astype(np.int64), full, act, start_mask, cov)
        if self.scenarios is None:
            idle = 0  # draws in a row that gave no usable map
            while len(self.pool[0]) < k:  # maps are drawn in batches: one reset is cheap
                before = len(self.pool[0])
                draw_maps(self, max(64, k))
                idle = 0 if len(self.pool[0]) > before else idle + 1
                if idle == 20:
                    raise ValueError(f"map_family {cfg.map_family!r}: no usable map in 20 draws of {max(64, k)} (too "
                                     "many agents for the free cells, or a starting_position always walled in)")
            drawn = [a[:k] for a in self.pool]
            self.pool = [a[k:] for a in self.pool]
            return self._init_worlds(w, *drawn, np.zeros((k, H, W), bool))
        idx = (rng.integers(0, len(self.scenarios), k) if cfg.load_random else
               (self.next_scenario + np.arange(k)) % len(self.scenarios))
        self.next_scenario = int((self.next_scenario + k) % len(self.scenarios))
        obstacle = np.ones((k, H, W), bool)
        covered0 = np.zeros((k, H, W), bool)
        hw = np.zeros((k, 2), np.int64)
        starts = np.zeros((k, N, 2), np.int64)
        active = self._active(k)
        for j, i in enumerate(idx):  # one array copy per loaded map
            s = self.scenarios[i]
            h_, w_ = s.obstacles.shape
            obstacle[j, :h_, :w_], hw[j] = s.obstacles, (h_, w_)
            if cfg.load_state:
                starts[j, :len(s.starts)] = s.starts
                active[j] = np.arange(N) < len(s.starts)
                if s.covered is not None:
                    covered0[j, :h_, :w_] = s.covered
        if not cfg.load_state:
            starts = self._starts(obstacle, hw)
        start_mask = np.zeros((k, H, W), bool)
        start_mask[np.arange(k)[:, None], starts[..., 0], starts[..., 1]] = active
        self._init_worlds(w, obstacle, hw, starts, active, start_mask, covered0)

    def seed(self, seed) -> None:
        """Restart the random stream (and drop maps drawn from the old one)."""
        self.rng = np.random.default_rng(seed)
        self.pool = [p[:0] for p in self.pool]

    def _active(self, k: int) -> np.ndarray:
        """Which of the N agent slots play in k new episodes (§7.4.2.1: a random count)."""
        n = self.rng.integers(1, self.N + 1, k) if self.config.number_agent_random else np.full(k, self.N)
        return np.arange(self.N) < n[:, None]

    def _starts(self, obstacle: np.ndarray, hw: np.ndarray) -> np.ndarray:
        """Agent starts (k, N, 2): the configured ones (checked) or distinct random free cells."""
        cfg, (k, H, W) = self.config, obstacle.shape
        if cfg.starting_position_random or cfg.starting_position is None:
            return self._random_cells(~obstacle, self.N)
        st = np.atleast_2d(np.asarray(cfg.starting_position, np.int64))
        ok = (st >= 0).all(1)[None] & (st[None, :, 0] < hw[:, :1]) & (st[None, :, 1] < hw[:, 1:])
        ok &= ~obstacle[np.arange(k)[:, None], np.clip(st[:, 0], 0, H - 1), np.clip(st[:, 1], 0, W - 1)]
        if not ok.all():
            raise ValueError(f"starting_position {st.tolist()} is out of the map or on an obstacle")
        if len({tuple(p) for p in st.tolist()}) != len(st):
            raise ValueError(f"duplicate starting positions {st.tolist()}")
        return np.broadcast_to(st, (k, self.N, 2)).copy()

    def _world_indices(self, worlds) -> np.ndarray:
        """The indices of the given worlds: all (None), a bool mask or indices."""
        if worlds is None:
            return np.arange(self.B)
        w = np.asarray(worlds)
        return np.flatnonzero(w) if w.dtype == bool else w.astype(np.int64).ravel()

    def _random_cells(self, allowed: np.ndarray, n: int) -> np.ndarray:
        """n distinct uniformly random cells of `allowed` (k, H, W) per world -> (k, n, 2)."""
        k, H, W = allowed.shape
        keys = self.rng.random((k, H * W))
        keys[~allowed.reshape(k, -1)] = np.inf
        flat = np.argsort(keys, 1)[:, :n]
        return np.stack(np.divmod(flat, W), -1)

    def _init_worlds(self, w, obstacle, hw, starts, active, start_mask, covered0) -> None:
        cfg, rng, c = self.config, self.rng, self.c
        k, H, W = obstacle.shape
        free = ~obstacle
        covered = covered0 & free
        if cfg.random_coverage:  # §6.4.2.5 / Table 4.1: up to a fraction pre-covered
            frac = rng.random(k) * cfg.random_coverage_max * (rng.random(k) < cfg.random_coverage_prob)
            covered |= free & (rng.random((k, H, W)) < frac[:, None, None])
        if cfg.number_points_of_interest > 0:  # n-point coverage; 1 = point-to-point
            candidates = free & ~start_mask
            if candidates.sum((1, 2)).min() < cfg.number_points_of_interest:
                raise ValueError(f"a map has fewer than {cfg.number_points_of_interest} free cells "
                                 "to keep as points of interest")
            keep = self._random_cells(candidates, cfg.number_points_of_interest)
            covered = free.copy()
            covered[np.arange(k)[:, None], keep[..., 0], keep[..., 1]] = False
        covered |= start_mask  # Algorithm 9 line 17
        none_left = ~(free & ~covered).any((1, 2))
        if none_left.any():  # keep one point of interest so that no episode starts finished
            cell = self._random_cells(free[none_left] & ~start_mask[none_left], 1)[:, 0]
            covered[np.flatnonzero(none_left), cell[:, 0], cell[:, 1]] = False
        inner = (w, slice(c, c + H), slice(c, c + W))
        self.obstacle[inner], self.covered[inner], self.occupied[inner] = obstacle, covered, start_mask
        self.start[w] = False
        self.start[inner] = start_mask
        self.seen[inner] = cfg.sensor == "full"
        self.seen[inner] |= ~((np.arange(H)[:, None] < hw[:, None, None, 0]) &
                              (np.arange(W) < hw[:, None, None, 1]))  # out of map: known obstacle
        self.hw[w] = hw
        park = self._flat(w[:, None], -c, -c)  # absent agents sit in the padding corner
        self.pos[w] = np.where(active, self._flat(w[:, None], starts[..., 0], starts[..., 1]), park)
        self.active[w] = active
        self.all_active = bool(self.active.all())
        self.any_large = bool((self.hw.max(1) > self.V // 2).any())
        self.last_action[w] = WAIT
        self.frozen[w] = False
        self.any_frozen = bool(self.frozen.any())
        self.budget[w] = np.ceil(cfg.battery_factor * hw[:, 0] * hw[:, 1]).astype(np.int64)
        self.battery[w] = self.budget[w]
        self.steps[w] = self.new_cells[w] = self.agent_moves[w] = 0
        self.n_free[w] = free.sum((1, 2))
        self.remaining[w] = self.n_poi_start[w] = (free & ~covered).sum((1, 2))
        if cfg.sensor != "full":
            self._sense(w, np.ones((len(w), self.N), bool))
        self._paint_worlds(w)

    # --- the observation buffer (derived from the arrays above) ------------------------
    def _codes(self, idx) -> np.ndarray:
        """uint32 cell codes (4 channel bytes) of the known map at flat canvas indices."""
        v = self.views
        seen, obst, cov = v["seen"][idx], v["obstacle"][idx], v["covered"][idx]
        code = (seen & ~obst) * np.where(cov, CODE[COVERED], CODE[POI])
        code |= (seen & obst) * CODE[OBSTACLE]
        code |= v["occupied"][idx] * CODE[AGENT]
        return code.astype(np.uint32)

    def _paint_worlds(self, w) -> None:
        base = (np.asarray(w) * self.Ph * self.Pw)[:, None]
        idx = (base + np.arange(self.Ph * self.Pw)).ravel()
        self.canvas32[idx] = self._codes(idx)

    # --- sensors (§4.2.2.4) -------------------------------------------------------------
    def _sense(self, w, working) -> np.ndarray:
        """Mark the sensor footprint of the active, working agents of worlds w as seen."""
        off, between = self.los_offsets, self.los_between
        step = off[:, 0] * self.Pw + off[:, 1]
        p = self.pos[w]
        cells = p[..., None] + step  # (k, N, (2r+1)^2)
        ok = np.broadcast_to((self.active[w] & working)[..., None], cells.shape)
        if self.config.sensor == "lidar":  # line of sight stops at obstacles (padding included)
            path = p[..., None, None] + between[..., 0] * self.Pw + between[..., 1]
            ok = ok & ~self.views["obstacle"][path].any(-1)
        cells = cells[ok]
        self.views["seen"][cells] = True
        return cells

    # --- the step (§4.2.2.5) ------------------------------------------------------------
    def step(self, actions) -> dict[str, np.ndarray]:
        """Advance every world one step. actions: (B, N) ints in 0..4. Returns per-agent event
        masks and rewards (B, N) and per-world terminated/truncated (B,)."""
        cfg, B, N, v = self.config, self.B, self.N, self.views
        a = np.array(actions, np.int64).reshape(B, N)  # a copy: kept as last_action
        if a.view(np.uint64).max() > WAIT:  # as unsigned, a negative action is out of range too
            raise ValueError(f"actions must be in 0..4 (N, S, W, E, WAIT), got {np.unique(a).tolist()}")
        delta = self.delta[a]
        if cfg.faulty_agent_step is not None:  # §7.5.3.3: a faulty agent freezes
            self.freeze(np.flatnonzero(self.steps >= cfg.faulty_agent_step), cfg.faulty_agent)
        if self.any_frozen or not self.all_active:
            a[self.frozen | ~self.active] = WAIT
            delta = self.delta[a]
        waited = a == WAIT
        moving = ~waited
        old = self.pos
        tgt = old + delta
        moves = moving & ~v["obstacle"][tgt]
        if N > 1:
            moves = self._resolve_conflicts(old, tgt, moves)
        pos = np.where(moves, tgt, old)
        new = moves & ~v["covered"][pos]
        live, left = (pos, old) if self.all_active else (pos[self.active], old[self.active])
        v["occupied"][left] = False
        v["occupied"][live] = True
        v["covered"][live] = True
        self.canvas32[left] = CODE[COVERED]  # an agent's cell is always covered and seen
        self.canvas32[live] = CODE[COVERED] | CODE[AGENT]
        self.pos = pos
        n_new = new.sum(1)
        self.remaining -= n_new
        self.new_cells += n_new
        self.agent_moves += moving.sum(1)
        self.steps += 1
        self.battery -= 1
        terminated = self.remaining == 0
        truncated = (self.battery <= 0) & ~terminated
        if cfg.sensor != "full":
            v["seen"][live] = True  # where an agent stands is known even if its sensor fails
            working = self.rng.random((B, N)) >= cfg.sensor_failure  # §6.5.3.3
            sensed = self._sense(np.arange(B), working)
            self.canvas32[sensed] = self._codes(sensed)
        events = dict(blocked=moving & ~moves, new=new, revisit=moves & ~new, waited=waited,
                      repeated_action=moving & (a == self.last_action),
                      finished=terminated[:, None].repeat(N, 1) if N > 1 else terminated[:, None],
                      timeout=truncated[:, None].repeat(N, 1) if N > 1 else truncated[:, None])
        if not self.all_active:
            events = {k: e & self.active for k, e in events.items()}
        self.last_action = a
        if cfg.reward.finished_line or cfg.reward.wall_adjacent:
            events.update(self._line_and_wall_events(new))
        events["reward"] = self._reward(events)
        events["terminated"], events["truncated"] = terminated, truncated
        return events

    def _resolve_conflicts(self, old, tgt, moves) -> np.ndarray:
        """Safety controller for several agents; iterates until no conflict is left."""
        B, N = moves.shape
        prio = np.broadcast_to(np.arange(N), (B, N)).ravel()
        swap = (tgt[:, :, None] == old[:, None, :]) & (tgt[:, None, :] == old[:, :, None])
        while True:
            dest = np.where(moves, tgt, old).ravel()
            order = np.lexsort((np.where(moves.ravel(), prio, -1), dest))  # stayers first
            first = np.ones(B * N, bool)
            first[1:] = dest[order][1:] != dest[order][:-1]
            lost = np.zeros(B * N, bool)
            lost[order] = ~first
            lost = moves & lost.reshape(B, N)
            lost |= moves & (swap & moves[:, None, :]).any(2)
            if not lost.any():
                return moves
            moves = moves & ~lost

    def _line_and_wall_events(self, new) -> dict[str, np.ndarray]:
        """Chapter-5 events: the new cell finished its row or column; it touches a wall."""
        poi = ~self.obstacle & ~self.covered
        b, y, x = np.unravel_index(self.pos, self.obstacle.shape)
        line = ~poi[b, y, :].any(-1) | ~poi[b, :, x].any(-1)
        wall = self.views["obstacle"][self.pos[..., None] + self.delta[:4]].any(-1)
        return dict(finished_line=new & line, wall_adjacent=new & wall)

    def _reward(self, ev) -> np.ndarray:
        """Reward of every agent from its events (eq. 6.13; eqs. 7.3-7.5; §5.3.4)."""
        rp = self.config.reward
        new = ev["new"]
        r = new * np.float32(rp.new_cell)
        if self.N > 1 and rp.structure != "competitive":
            n_active = self.active.sum(1, keepdims=True)
            share = (new.sum(1, keepdims=True) - new) / np.maximum(n_active - 1, 1)  # eq. 7.4
            own = 1.0 - rp.gain if rp.structure == "size_invariant" else 1.0  # eq. 7.5
            r = np.where(n_active > 1, own * r + rp.gain * rp.new_cell * share, r).astype(np.float32)
        bonus, penalty = self.reward_terms
        for name, weight in bonus:
            r += weight * ev[name]
        if rp.positive_only_if_new:
            r = np.where(new, r, np.minimum(r, 0))
        r += np.float32(rp.time_step)
        for name, weight in penalty:
            r += weight * ev[name]
        if rp.scale_by_area:
            r = (r / (self.hw[:, 0:1] * self.hw[:, 1:2])).astype(np.float32)
        return r if self.all_active else np.where(self.active, r, np.float32(0))

    WORLD_ARRAYS = ("obstacle", "seen", "covered", "occupied", "start", "canvas", "pos", "active", "last_action",
                    "frozen", "hw", "battery", "budget", "steps", "new_cells", "agent_moves", "n_poi_start",
                    "n_free", "remaining")  # every per-world array (leading axis B): copy_worlds copies them all

    def copy_worlds(self, src, dst, source: GridWorldCore | None = None) -> None:
        """Copy the full state of worlds src[i] (of `source`, this core by default) into worlds dst[i]
        of this core: map, coverage, known map, observation canvas, agents, counters, battery; the
        copies then step exactly as their originals would (e.g. lookahead planning). dst must be
        distinct; `source` must have this core's geometry (map size, view size, agents)."""
        source = self if source is None else source
        src, dst = np.asarray(src, np.int64).ravel(), np.asarray(dst, np.int64).ravel()
        if len(src) != len(dst) or len(np.unique(dst)) != len(dst):
            raise ValueError(f"copy_worlds needs one distinct destination per source, got {len(src)} "
                             f"source(s) and {len(dst)} destination(s)")
        if (source.H, source.W, source.N, source.c) != (self.H, self.W, self.N, self.c):
            raise ValueError("copy_worlds: the source core has another geometry (map size, view size, agents)")
        for k in self.WORLD_ARRAYS:  # fancy indexing reads src before writing dst: overlaps are safe
            getattr(self, k)[dst] = getattr(source, k)[src]
        self.pos[dst] += ((dst - src) * self.Ph * self.Pw)[:, None]  # flat canvas indices include the world
        self.all_active = bool(self.active.all())
        self.any_large = bool((self.hw.max(1) > self.V // 2).any())
        self.any_frozen = bool(self.frozen.any())

    def snapshot(self, worlds=None) -> list[Scenario]:
        """The current map, agent cells and coverage of worlds as Scenarios (e.g. to save a
        dataset, or keep an unsolved episode to replay it, §6.4.2.3)."""
        c = self.c
        cells = self.agent_cells()
        out = []
        for b in range(self.B) if worlds is None else worlds:  # one small copy per world
            h, w = self.hw[b]
            inner = (b, slice(c, c + h), slice(c, c + w))
            out.append(Scenario(self.obstacle[inner].copy(), cells[b][self.active[b]].copy(),
                                self.covered[inner].copy()))
        return out

    def freeze(self, worlds, agent) -> None:
        """Agent `agent` (one index, or one per world) of these worlds stops working for the
        rest of the episode (§7.5.3.3): it stays where it is, still blocks its cell, and the
        heuristic gives it no target."""
        w = np.asarray(worlds, np.int64)
        if len(w):
            self.frozen[w, agent] = True
            self.any_frozen = True

    def unreachable_poi(self, worlds=None) -> np.ndarray:
        """Per given world (all by default; a bool mask or indices), the uncovered points of interest of the true map
        that no working agent can reach, frozen agents' cells being blocked (§7.5.3.3: a faulty agent in a corridor
        walls off what lies behind it, so no team can complete the map)."""
        w = self._world_indices(worlds)
        c = self.c
        inner = (w, slice(c, c + self.H), slice(c, c + self.W))
        free = ~self.obstacle[inner] & ~self._agent_cells_mask(w, (self.active & self.frozen)[w])
        reach = flood(free, self._agent_cells_mask(w, (self.active & ~self.frozen)[w]))
        return (free & ~self.covered[inner] & ~reach).sum((1, 2))

    def _agent_cells_mask(self, w: np.ndarray, which: np.ndarray) -> np.ndarray:
        """(len(w), H, W): the map cells of the agents `which` (len(w), N) of worlds w."""
        mask = np.zeros((len(w), self.H, self.W), bool)
        cells = self.agent_cells()[w][which]
        mask[np.nonzero(which)[0], cells[:, 0], cells[:, 1]] = True
        return mask

    def recharge(self, worlds, factor: float = 2.0) -> None:
        """Give worlds a new battery of factor * h * w steps (partial reset, §6.4.2.2)."""
        w = np.asarray(worlds)
        self.battery[w] = np.ceil(factor * self.hw[w, 0] * self.hw[w, 1]).astype(np.int64)

    # --- metrics ------------------------------------------------------------------------
    def metrics(self) -> dict[str, np.ndarray]:
        """Per-world episode metrics so far: overlap (eq. 6.21), time-save factor (eq. 7.6), ρ."""
        new = self.new_cells
        return dict(steps=self.steps.copy(), new_cells=new.copy(), n_poi_start=self.n_poi_start.copy(),
                    revisits=self.agent_moves - new,
                    overlap=(self.agent_moves - new) / np.maximum(new, 1),
                    time_save=self.steps / np.maximum(self.n_poi_start, 1),
                    rho=self.steps / np.maximum(self.n_free, 1),
                    completed=self.remaining == 0)

    # --- observations -------------------------------------------------------------------
    def observe(self) -> dict[str, np.ndarray]:
        """Deep observation of every agent (§6.3.2), or the multiscale one (observation="multiscale": `map` is
        (scales * 5, scale_view, scale_view), see _multiscale); arrays with leading axes (B, N)."""
        B, N, V, c = self.B, self.N, self.V, self.c
        if self.config.observation == "multiscale":
            oob = np.zeros((B * N, 4, 2), np.float32)
            reach = self._multiscale_reach()
            if self.hw.max() > min(reach) + 1:  # a map reaches past the coarsest window: eq. 6.5 beyond it
                self._compress(None, oob, reach)
            battery = (self.battery / self.budget).astype(np.float32)
            return {"map": self._multiscale(),
                    "out_of_bounds": oob.reshape(B, N, 4, 2),
                    "last_action": ONE_HOT[self.last_action],
                    "battery": battery.reshape(B, 1, 1) if N == 1 else battery[:, None, None].repeat(N, 1)}
        pos = self.pos.ravel()
        start = pos - c * (self.Pw + 1)
        if not self.all_active:  # absent agents (parked in the padding) get a dummy window
            start = np.maximum(start, 0)
        maps = self.windows[start]
        oob = np.zeros((B * N, 4, 2), np.float32)
        if self.any_large:
            maps = self._compress(maps, oob)
        battery = (self.battery / self.budget).astype(np.float32)
        return {"map": maps.view(np.uint8).reshape(B, N, V, V, 4).transpose(0, 1, 4, 2, 3),
                "out_of_bounds": oob.reshape(B, N, 4, 2),
                "last_action": ONE_HOT[self.last_action],
                "battery": battery.reshape(B, 1, 1) if N == 1 else battery[:, None, None].repeat(N, 1)}

    def _multiscale_reach(self) -> tuple[int, int]:
        """Offsets (up/left, down/right) of the last map rows/cols the coarsest multiscale block row shows
        (equal for an odd block side; one less down/right for an even one)."""
        cfg = self.config
        side = cfg.scale_factor ** (cfg.scales - 1)
        return (cfg.scale_view // 2) * side + side // 2, (cfg.scale_view // 2) * side + side - 1 - side // 2

    def _compress(self, maps, oob, reach: tuple[int, int] | None = None) -> np.ndarray:
        """Algorithm 11 for agents whose map reaches past the window core (offsets beyond ±R):
        rows/cols 1 and V-2 become the mean of everything beyond, the outer ring stays
        obstacle; `oob` gets, per direction N, S, W, E, [rows/cols beyond, known points of
        interest beyond] (eq. 6.5). maps=None: only `oob`, counted beyond offsets -reach[0] and
        +reach[1] (the multiscale observation, whose coarse scales show the map up to there)."""
        V, c, R = self.V, self.c, self.V // 2 - 1
        lo, hi = (R, R) if reach is None else reach
        B, N = self.B, self.N
        b = np.repeat(np.arange(B), N)
        yx = self.agent_cells().reshape(-1, 2)
        y, x, h, w = yx[:, 0], yx[:, 1], self.hw[b, 0], self.hw[b, 1]
        beyond = np.stack([y - lo, h - 1 - y - hi, x - lo, w - 1 - x - hi], 1)
        far = np.flatnonzero((beyond > 0).any(1) & self.active.ravel())
        if len(far) == 0:
            return maps
        maps = None if maps is None else maps.copy()
        bk, yk, xk, hk, wk = b[far], y[far], x[far], h[far], w[far]
        worlds, q = np.unique(bk, return_inverse=True)
        known = self.canvas[worlds, c:c + self.H, c:c + self.W].transpose(0, 3, 1, 2) > 0
        if maps is not None:
            mk = maps[far]
            mk[:, [0, V - 1], :] = CODE[OBSTACLE]
            mk[:, :, [0, V - 1]] = CODE[OBSTACLE]
            if self.config.edge_compression:
                self._average_edges(mk, known, q, yk, xk, hk, wk)
            maps[far] = mk
        poi_rows, poi_cols = known[:, POI].sum(2)[q], known[:, POI].sum(1)[q]  # (K, H), (K, W)
        rows, cols = np.arange(self.H), np.arange(self.W)
        oob[far, :, 0] = np.maximum(beyond[far], 0)
        oob[far, :, 1] = np.stack([(poi_rows * (rows < (yk - lo)[:, None])).sum(1),
                                   (poi_rows * (rows > (yk + hi)[:, None])).sum(1),
                                   (poi_cols * (cols < (xk - lo)[:, None])).sum(1),
                                   (poi_cols * (cols > (xk + hi)[:, None])).sum(1)], 1)
        return maps

    def _average_edges(self, mk, known, q, y, x, h, w) -> None:
        """Rows/cols 1 and V-2 of the windows mk (K, V, V) := means of the known map (worlds
        known[q], (.., 4, H, W)) over every row/col from offset ±R outward; corners are block
        means. The block sums are small batched matrix products."""
        V, c, R, H, W = self.V, self.c, self.V // 2 - 1, self.H, self.W
        f32 = np.float32
        rows, cols, d = np.arange(H), np.arange(W), np.arange(V) - c
        row_blocks = np.stack([rows <= (y - R)[:, None],
                               (rows >= (y + R)[:, None]) & (rows < h[:, None])], 1)  # (K, 2, H): N, S
        col_blocks = np.stack([cols <= (x - R)[:, None],
                               (cols >= (x + R)[:, None]) & (cols < w[:, None])], 1)  # (K, 2, W): W, E
        n_rows, n_cols = row_blocks.sum(2), col_blocks.sum(2)
        kmap = known[q].astype(f32)  # (K, 4, H, W)
        col_t = col_blocks.transpose(0, 2, 1)[:, None].astype(f32)  # (K, 1, W, 2)
        ns = row_blocks[:, None].astype(f32) @ kmap  # (K, 4, 2, W): N/S block sums per column
        we = kmap @ col_t  # (K, 4, H, 2): W/E block sums per row
        corner = ns @ col_t  # (K, 4, 2, 2): [N/S, W/E] block sums

        def edge_codes(sums, along, limit, n_block, n_across, corner_sums):
            """Codes (K, 2, V) of the two edge lines: block sums (K, 4, 2, L) along one axis."""
            idx = along[:, None] + d  # map row/col shown at each window index
            inside = (idx >= 0) & (idx < limit[:, None])
            sums = np.take_along_axis(sums, np.clip(idx, 0, sums.shape[3] - 1)[:, None, None], 3)
            count = np.repeat(n_block[:, :, None], V, 2)
            empty = ~inside[:, None] | (count == 0)
            ends = [1, V - 2]
            sums[..., ends] = corner_sums
            count[..., ends] = n_block[:, :, None] * n_across[:, None, :]
            empty[..., ends] = count[..., ends] == 0
            empty[..., [0, V - 1]] = True
            mean = np.rint(255 * sums / np.maximum(count, 1)[:, None]).astype(np.uint32)
            code = (mean << (8 * np.arange(4, dtype=np.uint32))[:, None, None]).sum(1, dtype=np.uint32)
            return np.where(empty, CODE[OBSTACLE], code)

        mk[:, [1, V - 2], :] = edge_codes(ns, x, w, n_rows, n_cols, corner)
        mk[:, :, [1, V - 2]] = edge_codes(we.transpose(0, 1, 3, 2), y, h, n_cols, n_rows,
                                          corner.transpose(0, 1, 3, 2)).transpose(0, 2, 1)

    def _multiscale(self) -> np.ndarray:
        """Multiscale maps (B, N, scales * 5, v, v) uint8, v = scale_view, scale-major: scale s (0 = finest) has
        blocks of b x b map cells, b = scale_factor**s, block [i, j] covering map rows y - b//2 + (i - v//2) * b
        .. + b - 1 (cols likewise) around the agent's cell [y, x]: the agent's cell is the centre of the centre
        block for odd b, the cell below and right of its centre for even b. Channels per scale [POI, COVERED,
        OBSTACLE, AGENT, FRONTIER]; the first four are round-half-up(255 * fraction of the block's b*b cells),
        out of the map counting as obstacle and unseen cells as nothing; FRONTIER is 255 if any cell of the
        block is a known free cell 4-adjacent to an unseen one, else 0. Obstacle is a mean so that the network
        sees density (a wall, a scattered block, how much of the block lies past the border) while a frontier
        is a line one cell thin, as a mean about 255/b per cell of it, and a single frontier cell far away
        (the only lead left to unexplored space) would fade to 3 at b = 9 and round to 0 past 510 cells: as
        `any` it stays fully visible at every scale. Block sums are read off integral images of each world
        (four corner lookups per block, block edges clipped to the map): no per-agent loop."""
        cfg, B, N, H, W, c = self.config, self.B, self.N, self.H, self.W, self.c
        S, f, v, K, u64 = cfg.scales, cfg.scale_factor, cfg.scale_view, B * N, np.uint64
        # integral images [b, y, x] = sums over map cells [:y, :x] of the known map's four channels, packed as
        # lanes of uint64 words. uint64 arithmetic is exact modulo 2**64, so a block's sum (the sum of its lane
        # counts << lane offsets) decodes exactly whenever no count in a block can fill a lane: 16-bit lanes
        # while the map or the coarsest block has fewer than 65536 cells, else 32-bit (blocks < 2**32 cells)
        lane = np.uint16 if min(H * W, f ** (2 * S - 2)) < 1 << 16 else np.uint32
        cells = np.empty((B, H, W, 4), lane)
        np.bitwise_and(self.canvas[:, c:c + H, c:c + W], 1, out=cells)  # channel bytes 0/255 -> 0/1
        packed = cells.view(u64)  # (B, H, W, words)
        integral = np.zeros((B, H + 1, W + 1, packed.shape[-1]), u64)
        np.cumsum(packed, 1, out=integral[:, 1:, 1:])
        np.cumsum(integral[:, 1:, 1:], 2, out=integral[:, 1:, 1:])
        side = f ** np.arange(S, dtype=np.int64)  # block side per scale
        edges = (np.arange(v + 1) - v // 2) * side[:, None] - (side // 2)[:, None]  # (S, v + 1) block edge offsets
        b = np.repeat(np.arange(B), N)
        yx, hw = self.agent_cells().reshape(K, 2), self.hw[b]
        rows = np.clip(yx[:, 0, None, None] + edges, 0, hw[:, 0, None, None])  # (K, S, v + 1), clipped to the map
        cols = np.clip(yx[:, 1, None, None] + edges, 0, hw[:, 1, None, None])
        idx = (b[:, None, None, None] * (H + 1) + rows[..., :, None]) * (W + 1) + cols[..., None, :]
        corner = integral.reshape(-1, packed.shape[-1])[idx]  # (K, S, v + 1, v + 1, words)
        sums = (corner[:, :, 1:, 1:] - corner[:, :, :-1, 1:]) - (corner[:, :, 1:, :-1] - corner[:, :, :-1, :-1])
        table, offsets = _block_mean_table(S, f)
        counts = np.empty((K, S, 4, v, v), np.int32)  # index into `table`: scale offset + count
        np.add(sums.view(lane).transpose(0, 1, 4, 2, 3), offsets[:, None, None, None], out=counts)
        outside = side[:, None, None] ** 2 - np.diff(rows)[..., :, None] * np.diff(cols)[..., None, :]
        counts[:, :, OBSTACLE] += outside.astype(np.int32)  # out of the map counts as obstacle
        out = np.empty((K, S, MULTISCALE_CHANNELS, v, v), np.uint8)
        np.take(table, counts, out=out[:, :, :FRONTIER])
        if cfg.sensor == "full":  # everything is seen: no frontier
            out[:, :, FRONTIER] = 0
        else:  # out of the map is seen (a known obstacle): no frontier there
            seen = self.seen[:, c - 1:c + H + 1, c - 1:c + W + 1]
            front = np.zeros((B, H + 1, W + 1), np.int32)
            front[:, 1:, 1:] = (seen[:, 1:-1, 1:-1] & ~self.obstacle[:, c:c + H, c:c + W]
                                & ~(seen[:, :-2, 1:-1] & seen[:, 2:, 1:-1] & seen[:, 1:-1, :-2] & seen[:, 1:-1, 2:]))
            np.cumsum(front[:, 1:, 1:], 1, out=front[:, 1:, 1:])
            np.cumsum(front[:, 1:, 1:], 2, out=front[:, 1:, 1:])
            fc = front.reshape(-1)[idx]
            out[:, :, FRONTIER] = ((fc[:, :, 1:, 1:] - fc[:, :, :-1, 1:])
                                   != (fc[:, :, 1:, :-1] - fc[:, :, :-1, :-1])) * np.uint8(255)  # any
        return out.reshape(B, N, S * MULTISCALE_CHANNELS, v, v)

    def observe_tabular(self) -> np.ndarray:
        """§5.3.1 readings r' for every agent, (B, N, 8) int8 in the order N, S, E, W, NE, NW,
        SE, SW: -1 obstacle or wall adjacent, 0 adjacent cell covered, else the number of
        consecutive uncovered cells (at most r-1 cardinal and floor(r/sqrt2)-1 diagonal, at
        least 1: 2 and 1 for r = 3, as in the author's code)."""
        r = self.config.sensor_range
        cap = np.array([max(1, r - 1)] * 4 + [max(1, int(r / math.sqrt(2)) - 1)] * 4)
        k = np.arange(1, cap.max() + 1)
        dirs = np.array([[-1, 0], [1, 0], [0, 1], [0, -1], [-1, 1], [-1, -1], [1, 1], [1, -1]])
        step = dirs[:, 0] * self.Pw + dirs[:, 1]
        cells = self.pos[..., None, None] + step[:, None] * k  # (B, N, 8, kmax)
        blocked = self.views["obstacle"][cells]
        open_ = ~blocked & ~self.views["covered"][cells] & (k <= cap[:, None])
        run = np.cumprod(open_, -1).sum(-1)
        return np.where(blocked[..., 0], -1, run).astype(np.int8)

# ----------------------------------------------------------------------------- the navigation heuristic
# The heuristic (§6.3.1) and its one-step and multiagent rollouts: functions of a world (a GridWorldCore) that
# read its state and never change it.
def _grown(front: np.ndarray, Wp: int) -> np.ndarray:
    """Flat bordered maps (n, P), rows Wp wide, grown by the 4-neighbourhood (the border stops wrap-around)."""
    grown = front.copy()
    grown[:, Wp:] |= front[:, :-Wp]
    grown[:, :-Wp] |= front[:, Wp:]
    grown[:, 1:] |= front[:, :-1]
    grown[:, :-1] |= front[:, 1:]
    return grown


def _neighbours(poi: np.ndarray, Wp: int) -> np.ndarray:
    """How many of each cell's 4 neighbours are points of interest, for flat bordered maps (n, P)."""
    degree = np.zeros(poi.shape, np.int64)
    degree[:, Wp:] += poi[:, :-Wp]
    degree[:, :-Wp] += poi[:, Wp:]
    degree[:, 1:] += poi[:, :-1]
    degree[:, :-1] += poi[:, 1:]
    return degree


def _path_tables(free: np.ndarray, Wp: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Shortest paths between the free cells of one flat bordered map (row width Wp), for the rollouts' walkers:
    the table row of each cell (-1 where not free); the distance from each free cell to every cell (int16, 32767
    where unreachable); and the heuristic's first cell from each free cell toward every cell, where the walk back
    from the goal, each step to the first closer cell in N, S, W, E order, ends."""
    cells = np.flatnonzero(free)
    n, P, far = len(cells), free.size, np.iinfo(np.int16).max
    row = np.full(P, -1, np.int64)
    row[cells] = np.arange(n)
    dist = np.full((n, P), far, np.int16)
    front = np.zeros((n, P), bool)
    front[np.arange(n), cells] = True
    visited, i = front.copy(), 0
    while front.any():  # breadth-first from every free cell at once
        dist[front] = i
        front = _grown(front, Wp) & free & ~visited
        visited |= front
        i += 1
    ahead = np.full((4, n, P), far, np.int16)  # the distance of each cell's N, S, W, E neighbour
    ahead[0, :, Wp:], ahead[1, :, :-Wp], ahead[2, :, 1:], ahead[3, :, :-1] = (
        dist[:, :-Wp], dist[:, Wp:], dist[:, :-1], dist[:, 1:])
    back = (ahead == dist - 1).argmax(0)
    here = np.arange(P)
    first = np.where((dist >= 2) & (dist < far), here + np.array([-Wp, Wp, -1, 1])[back], here).astype(np.int32)
    for _ in range(max(1, int(np.ceil(np.log2(max(i, 2)))))):  # pointer doubling: each pass halves the walk left
        first = np.take_along_axis(first, first, 1)
    return row, dist, first.astype(np.int16)


def _symmetric(a: np.ndarray, k: int) -> np.ndarray:
    """Boards (..., H, W) in the k-th of the square's 8 symmetries: transposed for k >= 4, then turned k % 4
    quarter turns (np.rot90). The first 2 and the first 4 mix row-first and column-first scans (row-major ties)."""
    if k >= 4:
        a = np.swapaxes(a, -1, -2)
    return np.ascontiguousarray(np.rot90(a, k % 4, axes=(-2, -1)))


def _symmetric_cells(cells: np.ndarray, k: int, H: int, W: int) -> np.ndarray:
    """Cells (n, 2) of H x W boards where _symmetric(board, k) has them."""
    y, x = cells[:, 0], cells[:, 1]
    if k >= 4:
        y, x, H, W = x, y, W, H
    for _ in range(k % 4):  # a quarter turn puts (y, x) at (W - 1 - x, y) of a W x H board
        y, x, H, W = W - 1 - x, y, W, H
    return np.stack([y, x], 1)


@functools.cache
def _symmetric_moves(k: int) -> np.ndarray:
    """m[a]: the move of _symmetric(board, k) that is move a (N, S, W, E) of the board (read-only: cached)."""
    d = ACTION_DELTAS[:4]
    turned = _symmetric_cells(d + 1, k, 3, 3) - 1  # the moves as cells around the centre of a 3 x 3 board
    moves = np.array([int(np.flatnonzero((d == t).all(1))[0]) for t in turned])
    moves.setflags(write=False)
    return moves


_NEVER, _UNREACHED = np.iinfo(np.int64).max, np.iinfo(np.int16).max  # the walkers' 'no target' key, _path_tables' distance


class _Walkers:
    """Single agents following the deterministic navigation heuristic (heuristic_actions with
    random_ties=False, one agent, full view) on bare maps, in lockstep: the rollouts' tries. A map is its free
    cells and points of interest, flat with a border of obstacle; several walkers may share a map (`map_of`).
    Only a walker with no point of interest next to it looks further: in its map's _path_tables where they are
    given (a few array operations, and the target found is kept for the walk to it), else by a breadth-first
    search; the others pick among their neighbours."""

    def __init__(self, free: np.ndarray, poi: np.ndarray, cells: np.ndarray, dead_ends_first: bool,
                 tables: list | None = None, start: np.ndarray | None = None):
        n, H, W = free.shape
        self.Wp, self.P, self.dead_ends_first = W + 2, (H + 2) * (W + 2), dead_ends_first
        pad = np.zeros((2, n, H + 3, W + 2), bool)  # a spare row: a border cell's neighbours are in the array
        pad[:, :, 1:H + 1, 1:-1] = free, poi
        self.free, self.poi = pad[0].reshape(n, -1), pad[1].reshape(n, -1)
        self.from_start = None  # far-first (start: the starting cells): each map's steps from them, flat
        if start is not None:
            steps = np.zeros((n, H + 3, W + 2), np.int64)
            steps[:, 1:H + 1, 1:-1] = _distance_from(free, start)
            self.from_start = steps.reshape(n, -1)
        self.map_of = np.arange(n)
        self.pos = (cells[:, 0] + 1) * self.Wp + cells[:, 1] + 1
        self.goal = np.full(n, -1)  # a far walker's target from _look_up, kept until it is next to one (-1: none)
        self.planned = np.full(n, -1)  # the last moves(): a walker stepping otherwise drops its goal
        self.remaining = self.poi.sum(1)
        self.delta = np.array([-self.Wp, self.Wp, -1, 1])  # N, S, W, E
        self.tables = tables or [None] * n  # per map: _path_tables of its free cells, or None (search)

    def take(self, rows: np.ndarray) -> _Walkers:
        """The walkers `rows` (repeats allowed), each with its own copy of its points of interest."""
        out = object.__new__(_Walkers)
        out.__dict__.update(self.__dict__)
        out.map_of, out.pos, out.remaining = self.map_of[rows], self.pos[rows], self.remaining[rows]
        out.goal, out.planned = self.goal[rows], self.planned[rows]
        out.poi = self.poi[rows]
        return out

    def _key(self, degree: np.ndarray, cells: np.ndarray, maps: np.ndarray) -> np.ndarray:
        """The heuristic's order among equally near targets of walkers on `maps` (broadcast with cells): fewer
        target neighbours first (dead-ends-first) minus steps from the start (far-first; with both, holes first),
        then row-major (the border keeps flat order row-major)."""
        rank = degree + self.P if self.dead_ends_first else np.full(np.shape(cells), self.P)
        if self.from_start is not None:
            if self.dead_ends_first:  # holes (no target neighbour) first, as heuristic_actions
                rank = rank + np.where(degree > 0, 2 * self.P, 0)
            rank = rank - self.from_start[maps, cells]
        return rank * self.P + cells

    def moves(self) -> np.ndarray:
        """The heuristic's move of every walker (WAIT where no point of interest is reachable)."""
        rows = np.arange(len(self.pos))
        near = self.pos[:, None] + self.delta
        target = self.poi[rows[:, None], near]
        degree = self.poi[rows[:, None, None], near[..., None] + self.delta].sum(-1) if self.dead_ends_first else 0
        key = np.where(target, self._key(degree, near, self.map_of[:, None]), _NEVER)
        move = np.where(target.any(1), key.argmin(1), WAIT)
        far = np.flatnonzero(~target.any(1))
        self.goal[target.any(1)] = -1
        if len(far):
            tabled = np.array([self.tables[m] is not None for m in self.map_of[far]], bool)
            if tabled.any():
                move[far[tabled]] = self._look_up(far[tabled])
            if not tabled.all():
                move[far[~tabled]] = self._search(far[~tabled])
        self.planned = move
        return move

    def _look_up(self, far: np.ndarray) -> np.ndarray:
        """_search's moves from the walkers' _path_tables: the nearest targets by distance, ties by _key, and the
        tabled first cell toward the chosen one. A walker keeps its target until it is next to one: its points of
        interest do not change on the way and the target stays the nearest by that order (each step brings it
        one closer, and any other one at most one), so only the first step of a walk searches."""
        going = self.goal[far] >= 0
        move = np.zeros(len(far), np.int64)
        if going.any():
            first = np.array([self.tables[m][2][self.tables[m][0][p], g] for m, p, g in
                              zip(self.map_of[far[going]], self.pos[far[going]], self.goal[far[going]])], np.int64)
            move[going] = (first[:, None] == self.pos[far[going], None] + self.delta).argmax(1)
        if not going.all():
            move[~going] = self._nearest_goal(far[~going])
        return move

    def _nearest_goal(self, far: np.ndarray) -> np.ndarray:
        """_look_up for walkers without a target: it is chosen (and kept in self.goal) and the first move made."""
        Wp = self.Wp
        rows = [(self.tables[m], self.tables[m][0][p]) for m, p in zip(self.map_of[far], self.pos[far])]
        dist = np.stack([t[1][r] for t, r in rows])
        poi = self.poi[far]
        dist = np.where(poi, dist, _UNREACHED)
        nearest = dist == dist.min(1, keepdims=True)
        degree = _neighbours(poi, Wp) if self.dead_ends_first else 0
        key = self._key(degree, np.arange(poi.shape[1]), self.map_of[far, None])
        goal = np.where(nearest & poi, key, _NEVER).argmin(1)
        first = np.array([t[2][r, g] for (t, r), g in zip(rows, goal)], np.int64)
        move = (first[:, None] == self.pos[far, None] + self.delta).argmax(1)
        reached = poi.any(1) & (dist.min(1) < _UNREACHED)
        self.goal[far] = np.where(reached, goal, -1)
        return np.where(reached, move, WAIT)

    def _search(self, far: np.ndarray) -> np.ndarray:
        """Breadth-first search from walkers with no neighbouring target to their nearest one (ties by _key), and
        the first move of the walk back from it (each step to the first closer cell in N, S, W, E order)."""
        k, Wp, rows = len(far), self.Wp, np.arange(len(far))
        free, poi = self.free[self.map_of[far]], self.poi[far]
        front = np.zeros(poi.shape, bool)
        front[rows, self.pos[far]] = True
        visited, layers = front.copy(), [front]
        goal, dist = np.zeros(k, np.int64), np.zeros(k, np.int64)
        while True:
            front = _grown(front, Wp) & free & ~visited
            front[dist > 0] = False  # walkers that found their target stop
            if not front.any():
                break
            visited |= front
            layers.append(front)
            hit = front & poi
            found = np.flatnonzero(hit.any(1))
            if len(found):
                degree = _neighbours(poi[found], Wp) if self.dead_ends_first else 0
                key = self._key(degree, np.arange(poi.shape[1]), self.map_of[far[found], None])
                key = np.where(hit[found], key, _NEVER)
                goal[found], dist[found] = key.argmin(1), len(layers) - 1
        for i in range(int(dist.max()) - 1, 0, -1):  # walk back from the goal to distance 1
            near = goal[:, None] + self.delta
            pick = layers[i][rows[:, None], near].argmax(1)
            goal = np.where(dist > i, near[rows, pick], goal)
        first = (goal[:, None] == self.pos[far, None] + self.delta).argmax(1)
        return np.where(dist > 0, first, WAIT)

    def step(self, move: np.ndarray) -> None:
        """Every walker moves (into a free cell, never WAIT) and covers the cell it enters."""
        rows = np.arange(len(self.pos))
        self.goal = np.where(move == self.planned, self.goal, -1)
        self.pos = self.pos + self.delta[move]
        self.remaining = self.remaining - self.poi[rows, self.pos]
        self.poi[rows, self.pos] = False


def heuristic_actions(core: GridWorldCore, random_ties: bool = True, dead_ends_first: bool = False,
                      far_first: bool = False) -> np.ndarray:
    """One step along a shortest path to the nearest known point of interest for every agent at once, (B, N).
    With several agents, targets are claimed greedily by distance (the nearest agent-target pair first, the
    lower index on a tie), so no two agents chase one cell and a contested cell goes to the agent with the
    shorter path. Ties between equally near targets and equally short paths are broken at random (§6.3.1: a
    reinforced random walk), or with random_ties=False by the first target in row-major order and the first
    move in N, S, W, E order. Paths use known free cells; a world with no known point of interest targets
    its frontier (known free cells next to unseen ones), and so does an agent that reaches no known point of
    interest over known cells (a camera sees through walls). An agent left without a target waits (WAIT).
    With dead_ends_first, equally near targets with fewer target neighbours come first (Warnsdorff's rule):
    a cell that would be left behind as an isolated hole is covered now, which halves greedy's overlap
    (RESULTS.md). With far_first, equally near targets farther from the agents' starting cells (steps over the
    known passable cells) come first, so the walk sweeps away from the start and ends near it, as the
    wavefront planner's does; in a team also those farther from the agent's working teammates (twice the mean
    Manhattan steps to them), and an agent chases only targets no working teammate is nearer to (its Voronoi
    region, in steps over the known passable cells; the far half of it first when it holds over 1.5 x the
    team's mean, in a team of three or more) while it has any, then those of the region with the most, so the
    team spreads out. With both, a target with no target neighbour (a hole if left) first, then the fewest
    (target neighbours - steps from the start - 2 x mean steps to the teammates). The row-major or random
    order then breaks the remaining ties."""
    B, H, W, c = core.B, core.H, core.W, core.c
    inner = (slice(None), slice(c, c + H), slice(c, c + W))
    seen = core.seen[inner]
    passable = seen & ~core.obstacle[inner]
    if core.any_frozen:  # a frozen agent never moves off its cell: a path through it would wait forever (§7.5.3.3)
        passable &= ~core._agent_cells_mask(np.arange(B), core.active & core.frozen)
    passable, targets = _pack(np.stack([passable, passable & ~core.covered[inner]]))
    known = np.bitwise_count(targets).sum((1, 2)) > 0
    frontier = None if known.all() else _frontier(core, passable, seen)
    if frontier is not None:
        targets = np.where(known[:, None, None], targets, frontier)
    move, stuck = _moves_toward(core, passable, targets, random_ties, dead_ends_first, far_first)
    stuck &= known[:, None]
    if stuck.any():  # a camera sees through walls: the known points of interest may lie past unseen cells only
        frontier = _frontier(core, passable, seen) if frontier is None else frontier
        stuck &= (np.bitwise_count(frontier).sum((1, 2)) > 0)[:, None]
    if stuck.any():
        targets = np.where(stuck.any(1)[:, None, None], targets | frontier, targets)
        move = np.where(stuck, _moves_toward(core, passable, targets, random_ties, dead_ends_first, far_first)[0],
                        move)
    return move


def _frontier(core: GridWorldCore, passable: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Known passable cells next to unseen ones, other than those agents stand on (bitboards, (B, H, words))."""
    c, H, W = core.c, core.H, core.W
    return passable & _dilate(~_pack(seen)) & ~_pack(core.occupied[:, c:c + H, c:c + W])


def _moves_toward(core: GridWorldCore, passable: np.ndarray, targets: np.ndarray, random_ties: bool, dead_ends_first: bool,
                  far_first: bool) -> tuple[np.ndarray, np.ndarray]:
    """heuristic_actions' search over bitboards (B, H, words): the first move of every agent, (B, N), and
    whether each agent is working and reaches no target, (B, N)."""
    B, N, H, W = core.B, core.N, core.H, core.W
    M, rows = B * N, np.arange(B * N)
    yx = core.agent_cells().reshape(M, 2)
    working = core.active & ~core.frozen
    b = np.repeat(np.arange(B), N)
    pas, tg = (passable, targets) if N == 1 else (passable[b], targets[b])
    front = np.zeros_like(pas)
    on = working.ravel()  # absent (parked outside the map) and frozen agents search nothing and wait
    front[rows[on], yx[on, 0], yx[on, 1] >> 6] = np.uint64(1) << (yx[on, 1] & 63).astype(np.uint64)
    if far_first and N > 1:
        tg = _own_targets(core, pas, tg, front)
    need = np.where(on, np.minimum(N, np.bitwise_count(tg).sum((1, 2), dtype=np.int64)), 0)
    visited, layers = front.copy(), [front]
    found = np.zeros(M, np.int64)
    while (found < need).any():  # BFS from every agent until it has reached enough targets
        front = _dilate(front) & pas & ~visited
        if not front.any():
            break
        visited |= front
        layers.append(front)
        found += np.bitwise_count(tg & front).sum((1, 2), dtype=np.int64)
        front = front * (found < need)[:, None, None]  # agents with enough targets stop
    layers = np.stack(layers)  # (L, M, H, words): cells at each BFS distance
    # every target each agent reached, as (agent, distance, cell); its N nearest are kept
    hits = layers & tg[None]
    l, m, y, word = np.nonzero(hits)
    bits = np.unpackbits(hits[l, m, y, word].view(np.uint8).reshape(-1, 8), axis=1,
                         bitorder="little")
    k, bit = np.nonzero(bits)
    l, m, cell = l[k], m[k], y[k] * W + word[k] * 64 + bit
    tie = core.rng.random(len(l)) if random_ties else cell / (H * W)
    rank = np.zeros(len(l), np.int64)  # the order among equally near targets, ahead of the tie in [0, 1)
    if dead_ends_first:  # 4-neighbours that are targets too, 0-4
        t = _unpack(targets, W).astype(np.int8)
        degree = np.zeros_like(t)
        degree[:, 1:] += t[:, :-1]
        degree[:, :-1] += t[:, 1:]
        degree[:, :, 1:] += t[:, :, :-1]
        degree[:, :, :-1] += t[:, :, 1:]
        rank += degree.reshape(B, H * W)[m // N, cell]
    if far_first:
        if dead_ends_first:  # a target with no target neighbour would be left as a hole: it still comes first
            rank += np.where(rank > 0, 4 * (H + 1) * (W + 1), 0)  # past any (steps from start + to teammates)
        rank -= _steps_from_start(core, passable).reshape(B, H * W)[m // N, cell]
    if far_first and N > 1:  # and away from the working teammates (mean Manhattan steps, twice): the team spreads out
        world, y, x = m // N, cell // W, cell % W
        apart = (np.abs(y[:, None] - yx[:, 0].reshape(B, N)[world])
                 + np.abs(x[:, None] - yx[:, 1].reshape(B, N)[world]))
        mates = working[world] & (np.arange(N) != (m % N)[:, None])
        rank -= 2 * np.where(mates, apart, 0).sum(1) // np.maximum(mates.sum(1), 1)  # no working teammate: 0
    if len(rank):  # squeezed into [0, 1): the distance stays the first key
        tie = (rank - rank.min() + tie) / (rank.max() - rank.min() + 1)
    order = np.lexsort((l + tie, m))
    l, m, cell = l[order], m[order], cell[order]
    rank = np.arange(len(m)) - np.searchsorted(m, m)
    near = rank < N
    cand_dist = np.full((M, N), np.inf)
    cand_cell = np.full((M, N), -1)
    cand_dist[m[near], rank[near]], cand_cell[m[near], rank[near]] = l[near], cell[near]
    cand_dist, cand_cell = cand_dist.reshape(B, N * N), cand_cell.reshape(B, N * N)
    goal = np.full((B, N), -1)
    dist = np.zeros((B, N), np.int64)
    for _ in range(N):  # claims: the nearest free (agent, target) pair of each world first
        taken = (cand_cell[:, :, None] == goal[:, None, :]).any(-1) | (goal >= 0).repeat(N, 1)
        d = np.where(taken, np.inf, cand_dist)
        pair = d.argmin(1)
        ok = np.flatnonzero(np.isfinite(d[np.arange(B), pair]))
        if len(ok) == 0:
            break
        agent = pair[ok] // N
        goal[ok, agent] = cand_cell[ok, pair[ok]]
        dist[ok, agent] = cand_dist[ok, pair[ok]]
    goal, dist = np.maximum(goal, 0).ravel(), dist.ravel()
    goal = np.stack(np.divmod(goal, W), 1)
    gy, gx = goal[:, 0], goal[:, 1]
    for i in range(int(dist.max()) - 1, 0, -1):  # walk back from the goal to distance 1
        ny, nx = gy[:, None] + ACTION_DELTAS[:4, 0], gx[:, None] + ACTION_DELTAS[:4, 1]
        inside = (ny >= 0) & (ny < H) & (nx >= 0) & (nx < W)
        ny, nx = ny % H, nx % W  # wrapped cells are masked by `inside`
        word = layers[i, rows[:, None], ny, nx >> 6]
        closer = inside & ((word >> (nx & 63).astype(np.uint64)) & np.uint64(1)).astype(bool)
        pick = np.argmax(closer * core.rng.random((M, 4)) if random_ties else closer, 1)
        walk = dist > i
        gy = np.where(walk, ny[rows, pick], gy)
        gx = np.where(walk, nx[rows, pick], gx)
    has_goal = dist > 0
    move = FIRST_STEP[np.where(has_goal, gy - yx[:, 0], 0) + 1, np.where(has_goal, gx - yx[:, 1], 0) + 1]
    return move.reshape(B, N), ((found == 0) & working.ravel()).reshape(B, N)


def _own_targets(core: GridWorldCore, passable: np.ndarray, targets: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Each agent's targets in its Voronoi region: those no working teammate reaches in fewer steps over the
    passable cells (a cell as near to two agents is in both regions). An agent whose region holds more than
    1.5 x the team's mean, of three working agents or more, takes its far half first (_far_half), and an
    agent with none there helps the agent with the most (its targets: that agent's), else keeps them all.
    passable, targets: (B * N, H, words), each agent's copy of its world's; cells: each working agent's cell,
    an empty board for the others."""
    shape = (core.B, core.N) + passable.shape[1:]
    passable, front = passable.reshape(shape), cells.reshape(shape)
    agents = front  # the loop below rebinds front, never writes into it
    region, reached = front.copy(), np.bitwise_or.reduce(front, 1)
    while front.any():  # the agents' breadth-first searches grow together; a cell goes to those that reach it first
        front = _dilate(front) & passable & ~reached[:, None]
        region |= front
        reached |= np.bitwise_or.reduce(front, 1)
    own = targets & region.reshape(targets.shape)
    count = np.bitwise_count(own).sum((1, 2)).reshape(core.B, core.N)
    working = core.active & ~core.frozen  # the agents with a cell on `cells`
    mean = np.where(working, count, 0).sum(1, keepdims=True) / np.maximum(working.sum(1, keepdims=True), 1)
    # over 1.5 x the mean with three working agents or more; with two it cost more than it gained (docs/experiments.md)
    overloaded = (working & (count > 1.5 * mean) & (working.sum(1, keepdims=True) > 2)).ravel()
    big = np.flatnonzero(overloaded)
    if len(big):  # one search for each overloaded agent only
        world = big // core.N
        mates = np.bitwise_or.reduce(agents, 1)[world] & ~agents.reshape(own.shape)[big]
        far = _far_half(passable.reshape(own.shape)[big], mates, own[big])
        far_too = np.bitwise_count(far).sum((1, 2)) > 0
        own[big[far_too]] = far[far_too]
    busiest = region[np.arange(core.B), count.argmax(1)]  # the lower index on a tie
    helping = targets & np.repeat(busiest, core.N, 0)
    own = np.where((count == 0).reshape(-1, 1, 1), helping, own)
    return np.where((np.bitwise_count(own).sum((1, 2)) > 0)[:, None, None], own, targets)


def _far_half(passable: np.ndarray, mates: np.ndarray, own: np.ndarray) -> np.ndarray:
    """An agent's targets at least half as many steps (over the passable cells) from its nearest working
    teammate as its farthest target is, and those no teammate reaches: an overloaded agent heads for the part
    of its region no teammate will reach soon and leaves the near part to those who run out of work (a team
    queueing behind one agent down a corridor to a large room is what it prevents). Measured from the
    teammates, not from the agent itself, so the half does not move as the agent walks into it. passable,
    mates (the working teammates' cells), own (its targets): one board per agent, (M, H, words)."""
    front, seen, layers = mates, mates.copy(), [mates & own]
    while front.any():
        front = _dilate(front) & passable & ~seen
        seen |= front
        layers.append(front & own)
    layers = np.stack(layers)  # (L, M, H, words): each agent's targets by steps from its nearest teammate
    hit = np.bitwise_count(layers).sum((2, 3)) > 0
    farthest = len(layers) - 1 - np.argmax(hit[::-1], 0)
    half = np.arange(len(layers))[:, None] >= np.ceil(farthest / 2)
    return np.bitwise_or.reduce(layers * half[..., None, None], 0) | (own & ~seen)


def _steps_from_start(core: GridWorldCore, passable: np.ndarray) -> np.ndarray:
    """Steps from the agents' starting cells over the passable cells (bitboards, (B, H, words)), (B, H, W); a
    world's are kept until its passable cells or starts change (with full information: once an episode)."""
    c, H, W = core.c, core.H, core.W
    key = np.concatenate([passable, _pack(core.start[:, c:c + H, c:c + W])], 1).reshape(core.B, -1)
    old_key, steps = getattr(core, "_from_start", (None, None))
    stale = np.ones(core.B, bool) if old_key is None or old_key.shape != key.shape else (old_key != key).any(1)
    if stale.any():  # a copy: copies of this core may share the old array
        steps = np.zeros((core.B, H, W), np.int64) if stale.all() else steps.copy()
        steps[stale] = _distance_from(_unpack(passable[stale], W), core.start[stale, c:c + H, c:c + W])
        core._from_start = (key, steps)
    return steps


def rollout_actions(core: GridWorldCore, worlds=None, dead_ends_first: bool = True, max_steps: int | None = None,
                    view: str = "full", costs: bool = False, far_first: bool = False, symmetries: int = 1):
    """The one-step rollout (Bertsekas) of the deterministic heuristic (random_ties=False; greedy-dead-ends
    by default) for one agent, batched: in each given world (all by default; a bool mask or indices) try
    each move, finish each try with the heuristic and take the move with the fewest total steps (the
    heuristic's own move on ties, then N, S, W, E order), (len(worlds),) actions. With view="full" it plans
    on the full state (map, coverage), also in sensor tasks: a privileged teacher, not a policy of the
    observation. With view="known" it plans on the agent's known map (a policy of what it has seen): unknown
    cells are free points of interest, except those walled in by known obstacles (unreachable, so obstacles).

    The tries are walkers of _Walkers (the heuristic's moves on bare maps: no battery, rewards or sensing),
    one per legal move, run in lockstep, so the first to finish has the fewest steps and decides its world;
    a blocked move is not a try, and a world with a single try takes it at once. A try that can reach no
    point of interest never finishes. After max_steps steps (default 4 * H * W) the heuristic's own move is
    kept. A finished world, or one whose agent is absent or frozen, gets the heuristic's move (WAIT). This
    core is not changed (nor its random stream). With costs=True every try runs on to its end and it also
    returns (len(worlds), 4) steps to cover the map after each first move, that move included (max_steps
    where the heuristic cannot finish, -1 for a move not tried: blocked, or a world's only move). With
    far_first the heuristic (the base and the tries) takes far-first ties (heuristic_actions).

    With symmetries k > 1 the tries also run in k - 1 mirrored or turned copies of each world (_symmetric's
    order) and a move's cost is its mean over the k copies (costs: floats). The heuristic's last tie order
    (row-major) is arbitrary, and one copy's cheapest move is another's at only ~84% of the states where they
    differ; the mean is a steadier label (docs/experiments.md). The move taken is the cheapest by the
    mean among those whose steps in the world itself are no more than the heuristic's move's: each step then
    shortens the heuristic's own steps to the end, so the walk is never longer than the heuristic's (a mean
    alone can send an agent back and forth)."""
    if core.N != 1:
        raise ValueError(f"rollout_actions plans for one agent, the worlds have {core.N}")
    if view not in ("full", "known"):
        raise ValueError(f"rollout_actions: view must be 'full' or 'known', got {view!r}")
    if symmetries not in (1, 2, 4, 8):
        raise ValueError(f"rollout_actions: symmetries must be 1, 2, 4 or 8, got {symmetries}")
    w = core._world_indices(worlds)
    n, K = len(w), 4
    if n == 0:
        return (np.zeros(0, np.int64), np.zeros((0, K), np.int64)) if costs else np.zeros(0, np.int64)
    c, H, W = core.c, core.H, core.W
    inner = (w, slice(c, c + H), slice(c, c + W))
    free, covered = ~core.obstacle[inner], core.covered[inner]
    if view == "known":  # the optimistic known map: what the agent can reach and has not seen is to cover
        unknown = ~core.seen[inner]
        free = flood(free | unknown, core.occupied[inner])
        covered = covered & ~unknown
    agent = core.active[w, 0] & ~core.frozen[w, 0]
    cells = np.where(agent[:, None], core.agent_cells()[w, 0], 0)  # an absent agent is parked off the map
    start = core.start[inner] if far_first else None
    out, steps, base = _rollout_tries(core, w, free, covered, cells, agent, start, dead_ends_first, view,
                                           max_steps, costs or symmetries > 1)
    if symmetries == 1:
        return (out, steps) if costs else out
    total = steps.astype(np.float64)
    for k in range(1, symmetries):
        turned = [None if a is None else _symmetric(a, k) for a in (free, covered, start)]
        _, more, _ = _rollout_tries(core, w, turned[0], turned[1], _symmetric_cells(cells, k, H, W), agent,
                                         turned[2], dead_ends_first, view, max_steps, True)
        total += more[:, _symmetric_moves(k)]
    mean = total / symmetries  # -1 where the move is not a try, in every copy alike
    decided = (mean >= 0).sum(1) >= 2
    own = steps[np.arange(n), np.minimum(base, K - 1)]
    safe = (steps >= 0) & (steps <= own[:, None])  # no dearer than the heuristic's move in this world itself
    priority = np.where(np.arange(K) == base[:, None], -1, np.arange(K))  # ties: the heuristic's, then N, S, W, E
    order = np.lexsort((priority, np.where(safe, mean, np.inf)), axis=1)
    out = np.where(decided, order[:, 0], out)
    return (out, mean) if costs else out


def _rollout_tries(core: GridWorldCore, w, free, covered, cells, agent, start, dead_ends_first, view, max_steps, costs):
    """rollout_actions on given boards (n, H, W) of the worlds w: its actions, its costs (with costs) and the
    heuristic's own moves."""
    n, K, H, W = len(w), 4, core.H, core.W
    walkers = _Walkers(free, free & ~covered, cells, dead_ends_first, start=start)
    if view == "full":  # the map of an episode does not change: its tables serve every later call
        walkers.tables = _path_tables_of(core, walkers.free, walkers.Wp)
    base = walkers.moves()  # the heuristic's own move on the state planned on
    out = np.where(agent, base, WAIT)
    live = (core.remaining[w] > 0) & agent & (walkers.remaining > 0)
    moves = np.arange(K)
    run = walkers.free[np.arange(n)[:, None], walkers.pos[:, None] + walkers.delta] & live[:, None]
    single = run.sum(1) == 1
    out[single] = run[single].argmax(1)
    run[single] = False
    priority = np.where(moves == base[:, None], -1, moves)  # ties: the heuristic's move, then N, S, W, E
    owner = np.flatnonzero(run.ravel())  # the (world, move) of each walker, flat
    walkers = walkers.take(owner // K)
    walkers.step(owner % K)
    limit = 4 * H * W if max_steps is None else max_steps
    open_ = np.ones(n, bool)  # worlds not decided yet
    steps = np.where(run, limit, -1)  # costs: each try's steps to the end
    for t in range(1, limit + 1):  # t: the steps each running try has taken
        done = np.zeros(n * K, bool)
        done[owner] = walkers.remaining == 0
        done = done.reshape(n, K)
        steps[done] = t
        decided = done.any(1) & open_
        if decided.any():
            out[decided] = np.where(done[decided], priority[decided], K).argmin(1)
            open_[decided] = False
            run[decided] &= costs  # with costs the other tries run on
        run &= ~done
        if t == limit:
            break
        move = walkers.moves()
        keep = run.ravel()[owner] & (move < WAIT)  # a walker with no reachable target never finishes
        if not keep.all():
            owner, walkers, move = owner[keep], walkers.take(np.flatnonzero(keep)), move[keep]
        if len(owner) == 0:
            break
        walkers.step(move)
    return out, steps, base


def _path_tables_of(core: GridWorldCore, free: np.ndarray, Wp: int) -> list:
    """_path_tables of each flat bordered map (n, P), kept between calls by map. A map over PATH_TABLE_CELLS
    free cells, or one whose tables would pass PATH_TABLE_BYTES after dropping those the last call did not
    use, gets None (its walkers search)."""
    core.path_calls += 1
    out = []
    for m in free:
        key = (Wp, m.tobytes())
        entry = core.path_cache.get(key)
        n = int(m.sum())
        if entry is None and n <= core.PATH_TABLE_CELLS:
            size = 4 * n * m.size
            used = sum(e[2] for e in core.path_cache.values())
            for old in [k for k, e in core.path_cache.items() if e[1] < core.path_calls - 1]:
                if used + size <= core.PATH_TABLE_BYTES:
                    break
                used -= core.path_cache.pop(old)[2]
            if used + size <= core.PATH_TABLE_BYTES:
                entry = core.path_cache[key] = [_path_tables(m, Wp), 0, size]
        if entry is not None:
            entry[1] = core.path_calls
        out.append(None if entry is None else entry[0])
    return out


def _scratch(core: GridWorldCore, m: int) -> GridWorldCore:
    """m empty worlds of this core's geometry (its agents, full sensor: no sensing) for the rollouts."""
    scratch = GridWorldCore(EnvConfig(view_size=core.config.view_size, number_agents=core.N), m)
    if (scratch.H, scratch.W) != (core.H, core.W):
        scratch._allocate(core.H, core.W, core.N, None)
    return scratch


def _compacted(core: GridWorldCore, scratch: GridWorldCore, owner: np.ndarray, alive: np.ndarray):
    """The rollouts' scratch core rebuilt without its stopped tries once they are half of it (stepping frozen
    worlds still costs), with the owners and liveness of the kept ones."""
    if 2 * alive.sum() > len(owner) or len(owner) <= 8:
        return scratch, owner, alive
    keep = np.flatnonzero(alive)
    small = _scratch(core, len(keep))
    small.copy_worlds(keep, np.arange(len(keep)), source=scratch)
    return small, owner[keep], alive[keep]


def team_rollout_actions(core: GridWorldCore, worlds=None, dead_ends_first: bool = True, max_steps: int | None = None,
                         far_first: bool = False) -> np.ndarray:
    """The multiagent rollout (Bertsekas 2020, "Multiagent rollout algorithms and reinforcement learning") of the
    deterministic heuristic with claims (random_ties=False; greedy-dead-ends by default), batched: in each given
    world (all by default; a bool mask or indices) the agents choose in index order, agent i trying each of its
    moves with agents < i on their chosen moves and agents > i on the heuristic's; each try is finished by the
    heuristic for the whole team and the cheapest is kept: the fewest steps until every point of interest is
    covered (the team makespan), then the fewest agent moves, then the heuristic's own move, then N, S, W, E, WAIT
    order. (len(worlds), N) actions from at most 4 tries an agent besides the incumbent, not 5^N joint moves (WAIT
    is a move for several agents; a single agent never gains by waiting, so with one agent this is rollout_actions).
    Like rollout_actions it plans on the full state (map, coverage), also in sensor tasks: a privileged teacher,
    not a policy of the observation.

    Agent i's tries are copies (copy_worlds) of their world in a scratch core, run in lockstep with one batched
    heuristic call a step; moves into obstacles are not tried. The incumbent (agent i on the heuristic's move) is
    the previous agent's winner, so its cost is known and only agent 0's is simulated; a try stops once it cannot
    beat the incumbent (it needs at least steps + ceil(remaining / working agents) steps and moves + remaining
    moves), and a world decides when its first try finishes (the others need more steps) or the incumbent's step
    count is reached. After max_steps steps (default 4 * H * W: a heuristic that cannot finish) agent i keeps the
    heuristic's move. Absent and frozen agents get WAIT, finished worlds the heuristic's moves. This core is not
    changed (nor its random stream). With far_first the heuristic takes far-first ties (heuristic_actions)."""
    w = core._world_indices(worlds)
    n, N = len(w), core.N
    K = 4 if N == 1 else 5  # WAIT only lets another agent by
    if n == 0:
        return np.zeros((0, N), np.int64)
    c = core.c
    inner = (slice(None), slice(c, c + core.H), slice(c, c + core.W))
    probe = _scratch(core, n)
    probe.copy_worlds(w, np.arange(n), source=core)
    probe.seen[inner] = True  # the full state (outside the map is obstacle)
    chosen = heuristic_actions(probe, False, dead_ends_first, far_first)  # agents < i: chosen; agents >= i: the heuristic's
    working = core.active[w] & ~core.frozen[w]
    n_work = np.maximum(working.sum(1), 1)[:, None]
    live = core.remaining[w] > 0
    cost = np.full((n, 2), np.inf)  # the incumbent's steps and agent moves to finish, where known
    moves, rows = np.arange(K), np.arange(n)
    moves0 = core.agent_moves[w][:, None]
    limit = 4 * core.H * core.W if max_steps is None else max_steps
    for i in range(N):  # the sequential choice: agent i knows the moves of agents < i
        tgt = core.pos[w, i, None] + core.delta[:K]
        legal = (~core.views["obstacle"][tgt] | (moves == WAIT)) & (live & working[:, i])[:, None]
        known = np.isfinite(cost[:, :1])
        incumbent = moves == chosen[:, i, None]
        single = ~known[:, 0] & (legal.sum(1) == 1)  # nothing to compare: the only move is taken
        chosen[single, i] = legal[single].argmax(1)
        run = legal & ~single[:, None] & ~(incumbent & known)  # (n, K) tries still running
        if not run.any():
            continue
        owner = np.flatnonzero(run.ravel())  # the (world, move) of each scratch world, flat
        scratch = _scratch(core, len(owner))
        scratch.copy_worlds(w[owner // K], np.arange(len(owner)), source=core)
        scratch.seen[inner] = True
        first = chosen[owner // K]
        first[:, i] = owner % K
        scratch.step(first)
        tie = np.where(incumbent, 0, moves + 1)  # ties: the heuristic's move, then N, S, W, E, WAIT
        for t in range(1, limit + 1):  # t: the steps each running try has taken
            remaining, moved = np.zeros(n * K, np.int64), np.zeros(n * K, np.int64)
            remaining[owner], moved[owner] = scratch.remaining, scratch.agent_moves
            remaining, moved = remaining.reshape(n, K), moved.reshape(n, K) - moves0
            done = run & (remaining == 0)
            key = np.where(done, moved * (K + 1) + tie, np.inf)
            best = key.argmin(1)
            decided = done.any(1) | (cost[:, 0] <= t)
            win = decided & (key[rows, best] < np.where(cost[:, 0] == t, cost[:, 1] * (K + 1), np.inf))
            chosen[win, i] = best[win]
            cost[win] = np.stack([np.full(win.sum(), t), moved[win, best[win]]], 1)
            run[decided] = False
            steps_lb, moves_lb = t + -(-remaining // n_work), moved + remaining
            run &= (steps_lb < cost[:, :1]) | ((steps_lb == cost[:, :1]) & (moves_lb < cost[:, 1:]))
            if not run.any() or t == limit:
                break
            alive = run.ravel()[owner]
            scratch, owner, alive = _compacted(core, scratch, owner, alive)
            scratch.frozen[:] = core.frozen[w[owner // K]] | ~alive[:, None]  # stopped tries are skipped
            scratch.any_frozen = True
            scratch.step(heuristic_actions(scratch, False, dead_ends_first, far_first))
    return chosen


# ----------------------------------------------------------------------------- evaluation (§6.5.2), curves, who is stuck
def replay_config(scenarios: list[Scenario], sensor: str = "full", sensor_range: int = 3, sensor_failure: float = 0.0,
                  observation: dict | None = None) -> EnvConfig:
    """Worlds that replay the given scenarios as they are (maps, starts, coverage), as many agents as the most starts,
    observed as `observation` says (EnvConfig fields; default: the deep observation)."""
    return EnvConfig(load_state=True, load_random=False, sensor=sensor, sensor_range=sensor_range,
                     sensor_failure=sensor_failure, number_agents=max(len(s.starts) for s in scenarios),
                     **(observation or {}))


def heuristic_walk(config: EnvConfig, scenarios: list[Scenario], random_ties: bool, dead_ends_first: bool,
                   far_first: bool = False) -> dict:
    """The navigation heuristic alone (targets claimed among agents) once on each scenario, the yardstick beside a
    learned agent: per-episode arrays of the metrics, each world's own steps and its time-save factor."""
    core = GridWorldCore(config, len(scenarios))
    core.configure(scenarios=scenarios)
    core.reset()
    done, steps = np.zeros(core.B, bool), np.zeros(core.B, np.int64)
    while not done.all():
        ev = core.step(np.where(done[:, None], WAIT, heuristic_actions(core, random_ties, dead_ends_first, far_first)))
        steps += ~done
        done |= ev["terminated"] | ev["truncated"]
    m = core.metrics()
    return {**m, "steps": steps, "time_save": steps / np.maximum(m["n_poi_start"], 1)}


CURVE_SLICES = {"cpp_eval": 5, "structured_eval": 14}  # a learning curve's held-out maps: every 5th, every 14th


def curve_maps() -> dict[str, list[Scenario]]:
    """A learning curve's fixed held-out maps (CURVE_SLICES of maps/), each with its first start (one agent)."""
    return {name: [Scenario(s.obstacles, s.starts[:1], s.covered)
                   for s in load_dataset(os.path.join(REPO, "maps", f"{name}.npz"))[::every]]
            for name, every in CURVE_SLICES.items()}


def curve_point(maps: dict[str, list[Scenario]], evaluate: Any) -> dict:
    """A policy on each set of curve_maps, evaluate(scenarios, fallback) giving greedy_episodes' arrays, with the
    fallback (`name`) and without it (`name`_alone): overlap, completion, §6.5.2's outliers (overlap > 0.5 or
    truncated), the fallback's share; on cpp_eval by size too."""
    point = {}
    for name, scenarios in maps.items():
        for fallback in (True, False):
            m = evaluate(scenarios, fallback)
            row = {"maps": len(scenarios), "overlap": round(float(m["overlap"].mean()), 4),
                   "completion": round(float(m["completed"].mean()), 4),
                   "outliers": int(((m["overlap"] > 0.5) | m["truncated"]).sum())}
            if fallback:
                row["fallback_share"] = round(float(m["heuristic_steps"].sum() / max(m["steps"].sum(), 1)), 4)
            if name == "cpp_eval":
                sizes = np.array([s.obstacles.shape[0] for s in scenarios])
                row["overlap_by_size"] = {str(z): round(float(m["overlap"][sizes == z].mean()), 4)
                                          for z in np.unique(sizes)}
            point[name if fallback else f"{name}_alone"] = row
    return point


def world_paths(cells: list, steps: np.ndarray, active: np.ndarray) -> list[np.ndarray]:
    """Per world, its agents' (row, col) at every step to its own end, (T + 1, N, 2), from the cells of every step."""
    path = np.stack(cells)
    return [path[:t + 1, b][:, active[b]].astype(np.int64) for b, t in enumerate(steps)]


def observe(core: GridWorldCore, hint: bool = False, dead_ends_first: bool = True, far_first: bool = False) -> dict:
    """Every agent's observation, agent-major (stream b * N + i is agent i of world b), as the trainers act and store
    it; with `hint` also the deterministic heuristic's move on the agent's known map, which the agent could compute."""
    obs = {k: v.reshape(-1, *v.shape[2:]) for k, v in core.observe().items()}
    if hint:
        obs["hint"] = heuristic_actions(core, False, dead_ends_first, far_first).reshape(-1)
    return obs


def stuck(since_new: np.ndarray, moved: np.ndarray, size: np.ndarray) -> np.ndarray:
    """§6.4.2.4 conditions 3-4, per agent: no new cell in more than M steps (M = map edge), or
    none and at most two cells of displacement in the last five steps."""
    return (since_new > size) | ((since_new >= 5) & (moved <= 2))


class StuckWatch:
    """Who is stuck (`stuck`) among a core's agents, and §6.5.2.1's fallback: an agent that gets stuck hands over to
    the heuristic for as many new cells as it has been stuck this episode. step() after every core.step, restart()
    for worlds that start a new episode."""

    def __init__(self, core: GridWorldCore):
        self.since_new, self.times_stuck, self.owed = (np.zeros((core.B, core.N), np.int64) for _ in range(3))
        self.history = [core.agent_cells()] * 6  # cells at t-5 .. t

    def stuck(self, core: GridWorldCore) -> np.ndarray:
        moved = np.abs(core.agent_cells() - self.history[0]).sum(-1)
        return stuck(self.since_new, moved, core.hw.max(1)[:, None])

    def hand_over(self, core: GridWorldCore, working: np.ndarray) -> np.ndarray:
        """The working agents (B, N) the heuristic moves now."""
        now_stuck = self.stuck(core) & working & (self.owed == 0)
        self.times_stuck += now_stuck
        self.owed = np.where(now_stuck, self.times_stuck, self.owed)
        return (self.owed > 0) & working

    def step(self, core: GridWorldCore, new: np.ndarray) -> None:
        self.since_new = np.where(new, 0, self.since_new + 1)
        self.owed = np.maximum(self.owed - new, 0)
        self.history = self.history[1:] + [core.agent_cells()]

    def restart(self, core: GridWorldCore, worlds: np.ndarray) -> None:
        self.since_new[worlds] = self.times_stuck[worlds] = self.owed[worlds] = 0
        cells = core.agent_cells()[worlds]
        for h in self.history:
            h[worlds] = cells


def greedy_episodes(config: EnvConfig, scenarios: list[Scenario], act: Any, hint: bool = False, heuristic: bool = True,
                    random_ties: bool = False, dead_ends_first: bool = True, far_first: bool = False,
                    endgame: bool = False, action_loss: float = 0.0, faulty_at: float | None = None,
                    trajectories: list | None = None, seed: int = 0) -> dict:
    """A learned policy's evaluation (§6.5.2): each scenario once, with as many agents as it has starts, every agent
    acting on its own observation through act(obs, restart, acting) -> the moves of the streams `acting` (obs as
    observe() gives them, agent-major; `restart` marks each stream's first frame). With `heuristic` an agent that is
    stuck (§6.4.2.4) hands over to the heuristic for as many new cells as it has been stuck this episode (§6.5.2.1)
    and, with `endgame`, every agent does once no more cells are left than working agents. `action_loss`: chance an
    agent misses its action and stays; `faulty_at`: the last agent freezes once this share of the points of interest
    is covered (§7.5.3.3), and an episode ends, not completed, once the working agents have covered all they can
    reach (`walled_off`: the frozen agent left cells no working agent reaches). `trajectories`, a list, gets each
    episode's (T + 1, N, 2) cells. Returns per-episode arrays: the metrics, `steps`, `time_save`, `rho`, `agents`,
    `truncated`, `heuristic_steps` (agent-steps of the heuristic) and, with `faulty_at`, `walled_off`."""
    core = GridWorldCore(config, len(scenarios), seed=seed)
    core.configure(scenarios=scenarios)
    core.reset()
    B, N = core.B, core.N
    rng = np.random.default_rng(seed)
    restart = np.ones(B * N, bool)
    done, truncated, faulty = (np.zeros(B, bool) for _ in range(3))
    unreachable = np.zeros(B, np.int64)  # points of interest behind the frozen agent, counted when it freezes
    watch = StuckWatch(core)
    steps, used = np.zeros(B, np.int64), np.zeros(B, np.int64)  # each world's own, not the waits after its end
    cells = [core.agent_cells()]
    while not done.all():
        working = core.active & ~core.frozen & ~done[:, None]
        acting = np.flatnonzero(working.ravel())  # finished worlds and absent agents cost nothing
        action = np.full(B * N, WAIT)
        action[acting] = act(observe(core, hint, dead_ends_first, far_first), restart, acting)
        action, restart = action.reshape(B, N), np.zeros(B * N, bool)
        if heuristic:
            fallback = watch.hand_over(core, working)
            if endgame:
                fallback |= (core.remaining <= working.sum(1))[:, None] & working
            if fallback.any():
                action = np.where(fallback, heuristic_actions(core, random_ties, dead_ends_first, far_first), action)
            used += fallback.sum(1)
        if action_loss:
            action = np.where(rng.random((B, N)) < action_loss, WAIT, action)
        ev = core.step(np.where(done[:, None], WAIT, action))
        steps += ~done
        watch.step(core, ev["new"])
        if trajectories is not None:
            cells.append(core.agent_cells())
        truncated |= ev["truncated"] & ~done
        done |= ev["terminated"] | ev["truncated"]
        if faulty_at is not None:
            due = np.flatnonzero(~faulty & ~done & (core.new_cells >= faulty_at * core.n_poi_start))
            core.freeze(due, core.active[due].sum(1) - 1)
            faulty[due] = True
            unreachable[due] = core.unreachable_poi(due)
            done |= (unreachable > 0) & (core.remaining <= unreachable)  # all the working agents reach is covered
    if trajectories is not None:
        trajectories.extend(world_paths(cells, steps, core.active))
    m = core.metrics()
    return {**m, "steps": steps, "time_save": steps / np.maximum(m["n_poi_start"], 1),
            "rho": steps / np.maximum(core.n_free, 1), "agents": core.active.sum(1), "truncated": truncated,
            "heuristic_steps": used, **({"walled_off": unreachable > 0} if faulty_at is not None else {})}


# ----------------------------------------------------------------------------- spaces
def agent_observation_space(cfg: EnvConfig) -> spaces.Space:
    """One agent's observation space under `cfg`: the shapes a trainer sizes its network by."""
    if cfg.observation == "tabular":
        return spaces.Box(-1, max(cfg.sensor_range, 2), (8,), np.int8)
    V = cfg.view_size
    shape = ((cfg.scales * MULTISCALE_CHANNELS, cfg.scale_view, cfg.scale_view) if cfg.observation == "multiscale"
             else (4, V, V))
    return spaces.Dict({
        "map": spaces.Box(0, 255, shape, np.uint8),
        "out_of_bounds": spaces.Box(0, np.inf, (4, 2), np.float32),
        "last_action": spaces.Box(0, 1, (5,), np.float32),
        "battery": spaces.Box(0, 1, (BATTERY_FEATURES,), np.float32),
    })


def frame_shape(observation: dict) -> tuple[int, int]:
    """(channels, view) of one map frame of an observation, given by its EnvConfig fields (observation, view_size,
    the scales)."""
    shape = agent_observation_space(EnvConfig(**observation))["map"].shape
    return shape[0], shape[-1]


def frame_features(obs: dict[str, np.ndarray]) -> np.ndarray:
    """The FRAME_FEATURES floats of each deep observation beside its map (leading axes kept):
    last_action, then out_of_bounds flattened row by row and divided by OUT_OF_BOUNDS_SCALE."""
    oob = obs["out_of_bounds"]
    return np.concatenate([obs["last_action"], oob.reshape(*oob.shape[:-2], -1) / np.float32(OUT_OF_BOUNDS_SCALE)], -1)


def packed_frame_bytes(channels: int, view: int) -> int:
    """Bytes of one deep map frame under pack_frames."""
    return (channels * view * view + 7) // 8 + 4 * channels * view


def pack_frames(maps: np.ndarray) -> np.ndarray:
    """Deep map frames (n, C, V, V) uint8 as packed_frame_bytes each: every cell as one bit (a deep map is 0 or 255)
    but for rows and columns 1 and V - 2, which carry eq. 6.5's compressed out-of-bounds lines and are kept raw."""
    V = maps.shape[-1]
    edges = [maps[:, :, 1], maps[:, :, V - 2], maps[:, :, :, 1], maps[:, :, :, V - 2]]
    return np.concatenate([np.packbits((maps > 0).reshape(len(maps), -1), axis=1),
                           *(e.reshape(len(maps), -1) for e in edges)], 1)


def unpack_frames(packed: np.ndarray, channels: int, view: int) -> np.ndarray:
    """pack_frames' inverse: (n, C, V, V) uint8."""
    C, V, n = channels, view, len(packed)
    bits = (C * V * V + 7) // 8
    maps = np.unpackbits(packed[:, :bits], axis=1, count=C * V * V).reshape(n, C, V, V) * np.uint8(255)
    edges = packed[:, bits:].reshape(n, 4, C, V)
    maps[:, :, 1], maps[:, :, V - 2], maps[:, :, :, 1], maps[:, :, :, V - 2] = edges.transpose(1, 0, 2, 3)
    return maps


def _make_config(config: EnvConfig | dict | None, kwargs: dict) -> EnvConfig:
    if isinstance(config, EnvConfig):
        return config.replace(**kwargs) if kwargs else config
    return EnvConfig.from_dict({**(config or {}), **kwargs})


EVENT_KEYS = ("blocked", "new", "revisit", "waited", "repeated_action")


def _configure(core: GridWorldCore, config, changes: dict) -> None:
    """Reconfigure a face's core; the observation space of a face is fixed once made."""
    new = _make_config(config if config is not None else core.config, changes)
    if (agent_observation_space(new) != agent_observation_space(core.config)
            or new.number_agents != core.config.number_agents):
        raise ValueError("view_size, observation (scales, scale_factor, scale_view) and number_agents are fixed "
                         "once an env is made")
    core.configure(new)


def _info(core: GridWorldCore, events: dict | None = None, metrics: bool = True) -> dict[str, np.ndarray]:
    """Per-world info: the step's events, the active-agent mask and (optionally) metrics."""
    info = core.metrics() if metrics else {}
    if events is not None:
        info.update({k: events[k] for k in EVENT_KEYS})
    info["active"] = core.active.copy()
    return info


# ----------------------------------------------------------------------------- Gymnasium Env
class GridWorldEnv(gym.Env):
    """One world, one agent: the Gymnasium face of the core (registered as GridWorld-v0)."""

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 10}

    def __init__(self, config: EnvConfig | dict | None = None, render_mode: str | None = None, **kwargs):
        cfg = _make_config(config, kwargs)
        if cfg.number_agents != 1:
            raise ValueError("GridWorldEnv is single-agent; use parallel_env or GridWorldVectorEnv")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']}")
        self.core = GridWorldCore(cfg, 1)
        self.render_mode = render_mode
        self.observation_space = agent_observation_space(cfg)
        self.action_space = spaces.Discrete(4)
        self._window = None

    def configure(self, config=None, **changes) -> None:
        _configure(self.core, config, changes)

    def _obs(self):
        if self.core.config.observation == "tabular":
            return self.core.observe_tabular()[0, 0]
        return {k: v[0, 0] for k, v in self.core.observe().items()}

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        if seed is not None:
            self.core.seed(seed)
        self.core.reset()
        if self.render_mode == "human":
            self.render()
        return self._obs(), {k: v[0] for k, v in _info(self.core).items()}

    def step(self, action):
        ev = self.core.step(np.array([[int(action)]]))
        info = {k: v[0] for k, v in _info(self.core, ev).items()}
        if self.render_mode == "human":
            self.render()
        return (self._obs(), float(ev["reward"][0, 0]), bool(ev["terminated"][0]),
                bool(ev["truncated"][0]), info)

    def heuristic_action(self) -> int:
        return int(heuristic_actions(self.core)[0, 0])

    def render(self):
        return _render(self, self.core, 0)

    def close(self):
        _close_window(self)


def _render(face, core: GridWorldCore, world: int):
    img = render_rgb(core, world)
    if face.render_mode == "rgb_array":
        return img
    if face.render_mode == "human":
        import pygame
        if face._window is None:
            pygame.init()
            face._window = pygame.display.set_mode(img.shape[1::-1])
            pygame.display.set_caption("GridWorld")
        pygame.event.pump()
        face._window.blit(pygame.surfarray.make_surface(img.swapaxes(0, 1)), (0, 0))
        pygame.display.flip()
    return None


def _close_window(face):
    if getattr(face, "_window", None) is not None:
        import pygame
        pygame.display.quit()
        face._window = None


# ----------------------------------------------------------------------------- VectorEnv
class GridWorldVectorEnv(VectorEnv):
    """B worlds stepped by one core (native Gymnasium VectorEnv, same-step autoreset).

    With number_agents == 1 arrays are (B, ...); with N > 1 every observation, action and
    reward gets an agent axis (B, N, ...), termination/truncation stay per world, and
    info["active"] marks the agents present (number_agent_random). Each step's info holds
    the event masks (B, N); when worlds finish, info["final_obs"] and info["final_info"]
    (episode metrics: overlap, time_save, rho, steps, ...) describe the ended episodes and
    the returned observation is the next episode's first."""

    metadata = {"render_modes": ["rgb_array"], "autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, num_envs: int = 1, config: EnvConfig | dict | None = None,
                 render_mode: str | None = None, **kwargs):
        cfg = _make_config(config, kwargs)
        self.core = GridWorldCore(cfg, num_envs)
        self.num_envs, self.render_mode = num_envs, render_mode
        agent_space = agent_observation_space(cfg)
        self.N = cfg.number_agents
        if self.N == 1:
            self.single_observation_space = agent_space
            self.single_action_space = spaces.Discrete(4)
        else:
            self.single_observation_space = _stack_space(agent_space, self.N)
            self.single_action_space = spaces.MultiDiscrete([4] * self.N)
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, num_envs)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, num_envs)

    def configure(self, config=None, **changes) -> None:
        _configure(self.core, config, changes)

    def _obs(self):
        core = self.core
        if core.config.observation == "tabular":
            obs = core.observe_tabular()
            return obs[:, 0] if self.N == 1 else obs
        obs = core.observe()
        return {k: v[:, 0] for k, v in obs.items()} if self.N == 1 else obs

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)  # seeds self.np_random, as Gymnasium's CartPoleVectorEnv does
        if seed is not None:
            self.core.seed(seed)
        mask = None if not options or "reset_mask" not in options else options["reset_mask"]
        self.core.reset(mask)
        return self._obs(), _info(self.core)

    def step(self, actions):
        a = np.asarray(actions).reshape(self.num_envs, self.N)
        ev = self.core.step(a)
        info = _info(self.core, ev, metrics=False)
        done = ev["terminated"] | ev["truncated"]
        reward = ev["reward"][:, 0] if self.N == 1 else ev["reward"]
        if done.any():
            info["final_obs"] = self._obs()
            info["final_info"] = _info(self.core, ev)
            info["_final_obs"] = info["_final_info"] = done
            self.core.reset(done)
            info["active"] = self.core.active.copy()  # describes the returned observations
        return self._obs(), reward, ev["terminated"], ev["truncated"], info

    def heuristic_actions(self) -> np.ndarray:
        h = heuristic_actions(self.core)
        return h[:, 0] if self.N == 1 else h

    def render(self):
        return render_rgb(self.core, 0) if self.render_mode == "rgb_array" else None


def _stack_space(space: spaces.Space, n: int) -> spaces.Space:
    if isinstance(space, spaces.Dict):
        return spaces.Dict({k: _stack_space(v, n) for k, v in space.spaces.items()})
    return spaces.Box(np.broadcast_to(space.low, (n, *space.shape)),
                      np.broadcast_to(space.high, (n, *space.shape)), (n, *space.shape), space.dtype)


# ----------------------------------------------------------------------------- PettingZoo
class GridWorldParallelEnv(ParallelEnv):
    """PettingZoo ParallelEnv: one world, `number_agents` agents named agent_0, agent_1, ..."""

    metadata = {"render_modes": ["human", "rgb_array"], "name": "gridworld_v0", "render_fps": 10}

    def __init__(self, config: EnvConfig | dict | None = None, render_mode: str | None = None, **kwargs):
        cfg = _make_config(config, kwargs)
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']}")
        self.core = GridWorldCore(cfg, 1)
        self.render_mode, self._window = render_mode, None
        self.possible_agents = [f"agent_{i}" for i in range(cfg.number_agents)]
        self.agents = []
        self._obs_space = agent_observation_space(cfg)
        self._act_space = spaces.Discrete(4)

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_window": None}  # a pygame window does not pickle; a copy opens its own

    def configure(self, config=None, **changes) -> None:
        _configure(self.core, config, changes)

    def observation_space(self, agent):
        return self._obs_space

    def action_space(self, agent):
        return self._act_space

    def _per_agent(self, values):
        return {a: values[int(a.split("_")[1])] for a in self.agents}

    def _obs(self):
        if self.core.config.observation == "tabular":
            return self._per_agent(self.core.observe_tabular()[0])
        obs = self.core.observe()
        return self._per_agent([{k: v[0, i] for k, v in obs.items()} for i in range(self.core.N)])

    def _infos(self, events=None):
        info = _info(self.core, events)
        return self._per_agent([{k: (v[0, i] if np.ndim(v) == 2 else v[0]) for k, v in info.items()}
                                for i in range(self.core.N)])

    def reset(self, seed=None, options=None):
        if seed is not None:
            self.core.seed(seed)
        self.core.reset()
        self.agents = [a for a, on in zip(self.possible_agents, self.core.active[0]) if on]
        return self._obs(), self._infos()

    def step(self, actions):
        a = np.full((1, self.core.N), WAIT)
        for name, act in actions.items():  # an agent missing from the dict gives no action
            a[0, int(name.split("_")[1])] = int(act)
        ev = self.core.step(a)
        obs, infos = self._obs(), self._infos(ev)
        rewards = self._per_agent([float(r) for r in ev["reward"][0]])
        term = {ag: bool(ev["terminated"][0]) for ag in self.agents}
        trunc = {ag: bool(ev["truncated"][0]) for ag in self.agents}
        if ev["terminated"][0] or ev["truncated"][0]:
            self.agents = []
        return obs, rewards, term, trunc, infos

    def heuristic_actions(self):
        return self._per_agent(heuristic_actions(self.core)[0].tolist())

    def render(self):
        return _render(self, self.core, 0)

    def close(self):
        _close_window(self)


def parallel_env(config: EnvConfig | dict | None = None, render_mode: str | None = None,
                 **kwargs) -> GridWorldParallelEnv:
    """PettingZoo ParallelEnv with `number_agents` agents in one world (PettingZoo's factory name)."""
    return GridWorldParallelEnv(config, render_mode, **kwargs)


gym.register("GridWorld-v0", entry_point=GridWorldEnv, vector_entry_point=GridWorldVectorEnv,
             disable_env_checker=True)


# ----------------------------------------------------------------------------- benchmark
def benchmark(seconds: float = 1.0, repeats: int = 3, batch: int = 64) -> list[dict]:
    """Agent-steps/s of the VectorEnv (random actions, full observations, autoreset) and the
    heuristic's time per call on the states it creates itself; medians of `repeats` windows."""
    rows = []
    for size in (10, 20, 30):
        for agents in (1, 5):
            config = EnvConfig(size=size, number_obstacles=size * size // 10, number_agents=agents)
            env = GridWorldVectorEnv(batch, config)
            env.reset(seed=0)
            actions = np.random.default_rng(0).integers(0, 4, (256, batch, agents))
            sps, ms = [], []
            for _ in range(repeats):
                n, t0 = 0, time.perf_counter()
                while time.perf_counter() - t0 < seconds:
                    env.step(actions[n % 256])
                    n += 1
                sps.append(n * batch * agents / (time.perf_counter() - t0))
                n, spent, t0 = 0, 0.0, time.perf_counter()
                while time.perf_counter() - t0 < seconds:
                    t1 = time.perf_counter()
                    h = env.heuristic_actions()
                    spent += time.perf_counter() - t1
                    env.step(h)
                    n += 1
                ms.append(1000 * spent / n)
            rows.append(dict(size=size, agents=agents, batch=batch,
                             agent_steps_per_s=round(float(np.median(sps))),
                             heuristic_ms_per_call=round(float(np.median(ms)), 3)))
    return rows


def observation_benchmark(seconds: float = 1.0, repeats: int = 3, batch: int = 64) -> list[dict]:
    """Agent-steps/s of the VectorEnv (one agent, random actions, autoreset, obstacles 10% of the cells) with the
    deep and the multiscale observation (default scales) on 20x20 and 50x50 maps; medians of `repeats` windows."""
    rows = []
    for size in (20, 50):
        for observation in ("deep", "multiscale"):
            env = GridWorldVectorEnv(batch, EnvConfig(size=size, number_obstacles=size * size // 10,
                                                      observation=observation))
            env.reset(seed=0)
            actions = np.random.default_rng(0).integers(0, 4, (256, batch))
            sps = []
            for _ in range(repeats):
                n, t0 = 0, time.perf_counter()
                while time.perf_counter() - t0 < seconds:
                    env.step(actions[n % 256])
                    n += 1
                sps.append(n * batch / (time.perf_counter() - t0))
            rows.append(dict(size=size, observation=observation, batch=batch,
                             agent_steps_per_s=round(float(np.median(sps)))))
    return rows


def map_family_benchmark(size: int = 20, seconds: float = 1.0, batch: int = 64) -> list[dict]:
    """Usable maps/s drawn into the core's pool per map family (size x size, one agent, `batch` maps per draw as
    a reset refills it: family obstacles, start placement and Algorithm 10 included); "random" with 10% obstacles."""
    rows = []
    for family in MAP_FAMILIES:
        core = GridWorldCore(EnvConfig(size=size, map_family=family, number_obstacles=size * size // 10), 1, seed=0)
        n, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            core.pool = [p[:0] for p in core.pool]
            draw_maps(core, batch)
            n += len(core.pool[0])
        rows.append(dict(map_family=family, size=size, batch=batch, maps_per_s=round(n / (time.perf_counter() - t0))))
    return rows


def heuristic_overlap(size: int, episodes: int = 64, seed: int = 0, random_ties: bool = True) -> dict:
    """Mean overlap of the navigation heuristic run to completion on random maps drawn as in
    §6.5.1.1 (obstacles 0-10% of the cells, random start, unreachable cells filled)."""
    env = GridWorldVectorEnv(episodes, size=size, number_obstacles=size * size // 10,
                             obstacles_random=True)
    env.reset(seed=seed)
    overlap = np.full(episodes, np.nan)
    while np.isnan(overlap).any():
        _, _, _, _, info = env.step(heuristic_actions(env.core, random_ties)[:, 0])
        if "final_info" in info:
            first = info["_final_info"] & np.isnan(overlap)
            overlap[first] = info["final_info"]["overlap"][first]
    return dict(size=size, episodes=episodes, random_ties=random_ties,
                heuristic_overlap_mean=round(float(overlap.mean()), 4))


# ----------------------------------------------------------------------------- recording
def render_rgb(core: GridWorldCore, world: int = 0, cell: int = 16) -> np.ndarray:
    """RGB image of one world's known map in the colours of §4.2.4."""
    h, w = core.hw[world]
    c = core.c
    known = core.canvas[world, c:c + h, c:c + w] > 0
    rgb = np.empty((h, w, 3), np.uint8)
    rgb[:] = (40, 90, 220)  # unseen: blue
    rgb[known[..., POI]] = (255, 255, 255)
    rgb[known[..., COVERED]] = (220, 50, 50)
    rgb[known[..., OBSTACLE]] = (0, 0, 0)
    img = rgb.repeat(cell, 0).repeat(cell, 1)
    yy, xx = np.mgrid[:cell, :cell] - (cell - 1) / 2
    disk = yy ** 2 + xx ** 2 <= (cell * 0.38) ** 2
    for (py, px), on in zip(core.agent_cells()[world], core.active[world]):
        if on:
            img[py * cell:(py + 1) * cell, px * cell:(px + 1) * cell][disk] = (20, 40, 160)
    return img


def _path_array(scenario: Scenario, paths) -> np.ndarray:
    """(T+1, N, 2) (row, col) cells from either that array or per-agent (T_i+1, 2) lists padded with each
    agent's last cell."""
    if isinstance(paths, np.ndarray) and paths.ndim == 3:
        a = paths.astype(np.int64)
    else:
        per_agent = [np.asarray(p, np.int64).reshape(-1, 2) for p in paths]
        if not per_agent or any(len(p) == 0 for p in per_agent):
            raise ValueError("paths: one non-empty path of [row, col] cells per agent")
        T = max(len(p) for p in per_agent)
        a = np.stack([np.concatenate([p, p[-1:].repeat(T - len(p), 0)]) for p in per_agent], 1)
    h, w = scenario.obstacles.shape
    if a.shape[-1] != 2 or a.shape[1] == 0 or len(a) == 0:
        raise ValueError(f"paths: expected (steps, agents, 2) cells, got shape {a.shape}")
    if (a < 0).any() or (a[..., 0] >= h).any() or (a[..., 1] >= w).any():
        raise ValueError(f"paths: a cell lies outside the {h}x{w} map")
    if (np.abs(np.diff(a, axis=0)).sum(-1) > 1).any():
        raise ValueError("paths: consecutive cells must be 4-adjacent")
    return a


def replay_frames(scenario: Scenario, paths, cell: int = 16, config: EnvConfig | dict | None = None) -> list[np.ndarray]:
    """RGB frames (h*cell, w*cell, 3) of the agents walking `paths` on `scenario`, the first at the starts: the
    moves are replayed through a core (the safety controller included), so what is drawn is what gridworld did.
    `config` sets the sensor (the known map is drawn); its battery is lifted so the replay never truncates."""
    a = _path_array(scenario, paths)
    cfg = _make_config(config, {}).replace(load_state=True, number_agents=a.shape[1], battery_factor=1e6)
    core = GridWorldCore(cfg, 1)
    core.configure(scenarios=[Scenario(scenario.obstacles, a[0], scenario.covered)])
    core.reset()
    actions = FIRST_STEP[np.diff(a[..., 0], axis=0) + 1, np.diff(a[..., 1], axis=0) + 1]  # (T, N)
    frames = [render_rgb(core, 0, cell)]
    for move in actions:
        core.step(move[None])
        frames.append(render_rgb(core, 0, cell))
    return frames


def write_video(frames: list[np.ndarray], path: str, fps: int = 10) -> str:
    """An MP4 of RGB frames (moviepy, H.264); frames are padded to even sides as yuv420p needs."""
    from moviepy import ImageSequenceClip

    if not frames:
        raise ValueError(f"{path}: no frames to write")
    h, w = frames[0].shape[:2]
    pad = ((0, h % 2), (0, w % 2), (0, 0))
    frames = [np.pad(f, pad) for f in frames]
    clip = ImageSequenceClip(frames + frames[-1:], fps=fps)  # moviepy's writer drops the last frame: show it once more
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    clip.write_videofile(path, codec="libx264", audio=False, logger=None)
    return path


def write_episode_video(scenario: Scenario, path: np.ndarray, video: str, sensor: str = "full",
                        sensor_range: int = 3, flag: str = "--capture-video") -> str:
    """An MP4 of one episode, replayed from its agents' cells, through the write rule."""
    frames = replay_frames(scenario, path, config=dict(sensor=sensor, sensor_range=sensor_range))
    with staged_output(video, "video", overwrite=True, flag=flag) as tmp:
        write_video(frames, tmp)
    return video


def plot_path(scenario: Scenario, paths, path: str = "", title: str = "", ax=None) -> str:
    """The final coverage (covered cells tinted, cells never reached white, obstacles black) with each agent's
    path drawn in step order (light to dark), its start a circle and its end a square. Saves a PNG at `path`
    unless `ax` is given, in which case it draws there and returns ""."""
    import matplotlib

    if ax is None:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    a = _path_array(scenario, paths)
    h, w = scenario.obstacles.shape
    covered = np.zeros((h, w), bool) if scenario.covered is None else scenario.covered.copy()
    covered[a[..., 0].ravel(), a[..., 1].ravel()] = True
    rgb = np.ones((h, w, 3))
    rgb[covered] = (1.0, 0.85, 0.85)
    rgb[scenario.obstacles] = 0.0
    fig = None
    if ax is None:
        fig, ax = plt.subplots(figsize=(max(3.0, w / 5), max(3.0, h / 5)))
    ax.imshow(rgb, interpolation="nearest")
    cmaps = ["Blues", "Greens", "Oranges", "Purples", "Reds", "Greys"]
    for i in range(a.shape[1]):
        xy = a[:, i, ::-1].astype(float)
        segments = np.stack([xy[:-1], xy[1:]], 1)
        keep = (segments[:, 0] != segments[:, 1]).any(1)
        ramp = np.linspace(0.35, 1.0, max(len(segments), 1))[keep]
        ax.add_collection(LineCollection(segments[keep], cmap=cmaps[i % len(cmaps)], array=ramp, norm=plt.Normalize(0, 1),
                                         linewidths=2))
        ax.plot(*xy[0], "o", color="tab:green", markersize=7, markeredgecolor="k")
        ax.plot(*xy[-1], "s", color="tab:red", markersize=6, markeredgecolor="k")
    ax.set(xlim=(-0.5, w - 0.5), ylim=(h - 0.5, -0.5), xticks=[], yticks=[], title=title)
    if fig is None:
        return ""
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


if __name__ == "__main__":
    if sys.argv[1:] not in ([], ["-h"], ["--help"], ["--bench"]):
        raise SystemExit(f"error: gridworld.py: unknown argument(s) {' '.join(sys.argv[1:])!r}; "
                         "usage: python gridworld.py [--bench]")
    if "--bench" in sys.argv:
        for row in benchmark():
            print(json.dumps(row), flush=True)
        for row in observation_benchmark():  # deep vs multiscale, 20x20 and 50x50
            print(json.dumps(row), flush=True)
        for row in map_family_benchmark():
            print(json.dumps(row), flush=True)
        for size in (5, 10, 15, 20, 25, 30):
            for random_ties in (True, False):
                print(json.dumps(heuristic_overlap(size, random_ties=random_ties)), flush=True)
    else:
        print(__doc__)
        print("usage: python gridworld.py [--bench]")

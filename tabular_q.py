"""Tabular TD learning for online coverage with the heuristic action (dissertation chapter 5).

    python tabular_q.py --algorithm q-learning --size 6 --corner-starts --episodes 100000   # Fig. 5.4
    python tabular_q.py --algorithm watkins --size 6 --corner-starts --number-obstacles 1 --no-heuristic
    python tabular_q.py --min-size 4 --size 10 --number-obstacles 3 --obstacles-random \\
        --episodes 3000000 --time-limit 2400 --num-worlds 512 --table-path models/tabular_q.npz --overwrite  # Fig. 5.5

The agent never sees the map: its state is the last K pairs (r'_t, a_{t-1}) of transformed range
readings (gridworld's tabular observation, §5.3.1) and the move that led to them, packed into one
int64 per world. Actions are N, S, W, E and the heuristic (§5.3.2), chosen by the decaying
ε-greedy policy of eq. 5.1 with the three rules of §5.3.3. One Q-table (an open-addressing hash
table over numpy arrays) is shared by `num_worlds` worlds of one gridworld core that act
together; Q-learning, SARSA (Algorithm 4), Double Q-learning (Algorithm 5) and Watkins's Q(λ)
(Algorithm 6) update it. The table is written as .npz (keys, Q-values, visit counts, K and r),
by default to runs/RUN_NAME/tabular_q.npz (RUN_NAME = {exp_name}__{seed}__{unix time} unless
--run-name; models/ only when --table-path names it), with a .json beside it recording how it
was trained (flags, git commit, CPU, date, wall time) and the learning curve (mean ρ per
`curve_window` episodes). Both are written through temporary files in the same folder, so the
previous table survives a kill or a full disk; a path under maps/ or results/ is refused, an
existing file that is not a tabular_q table (or its .json) is never replaced, and a table is
replaced only with --overwrite. Ctrl-C or SIGTERM ends training early: the table so far is saved
as at --time-limit, and the exit status is 130 (SIGINT) or 143 (SIGTERM).
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import signal
import sys
import tempfile
import threading
import time
import zipfile
import zlib
from dataclasses import asdict, dataclass
from datetime import UTC, datetime

import numpy as np
from tqdm import tqdm

import gridworld

ALGORITHMS = ("q-learning", "sarsa", "double-q", "watkins")
HEURISTIC = 4  # the fifth action of §5.3.2 (to the environment, 4 is WAIT: no move)
NO_MOVE = 4  # the last-move code of an episode's first reading
READING_OF_MOVE = np.array([0, 1, 3, 2])  # r' is ordered N, S, E, W; moves are N, S, W, E
HASH = np.uint64(0x9E3779B97F4A7C15)  # Fibonacci hashing multiplier (2^64 / golden ratio)
TABLE_ARRAYS = ("keys", "q", "visits", "updates", "memory", "sensor_range")  # what QTable.save writes


@dataclass
class Args:
    exp_name: str = os.path.basename(__file__)[: -len(".py")]
    """the name of this experiment (the first part of the default run name)"""
    run_name: str | None = None
    """folder under runs/ for the table and its .json; default: {exp_name}__{seed}__{unix time}, new for every run"""
    algorithm: str = "q-learning"
    """TD method: q-learning, sarsa, double-q or watkins (Q(λ) with eligibility traces)"""
    alpha: float = 0.1
    """step size α of every update"""
    alpha_visits: bool = False
    """use α = 1/n(s, a) instead (a sample average, as in the author's code)"""
    gamma: float = 1.0
    """discount factor γ (episodes always end: every move of the policy covers a new cell or
    follows the heuristic's path to one, and the battery of 5·h·w steps truncates the rest)"""
    lam: float = 0.9
    """trace decay λ of watkins"""
    memory: int = 3
    """K, the readings and moves kept in the state (§5.3.1)"""
    sensor_range: int = 3
    """r: cells sensed in the cardinal directions, r/√2 on the diagonals (§5.2)"""
    sensor: str = "lidar"
    """what builds the map the heuristic plans on (§5.3.1's SLAM map): lidar (line of sight
    within r), camera (the square of side 2r + 1) or full (the whole map known)"""
    heuristic: bool = True
    """the heuristic action (§5.3.2); off, a state whose neighbours are all covered or blocked
    chooses among the four moves"""
    size: int = 6
    """largest map edge N"""
    min_size: int | None = None
    """smallest map edge (random edge in [min_size, size] per episode); default: size"""
    number_obstacles: int = 0
    """obstacles per map (the most, with --obstacles-random)"""
    obstacles_random: bool = False
    """draw the obstacle count uniformly in [0, number_obstacles] per episode"""
    corner_starts: bool = False
    """start every episode in one of the four corners (§5.4.1; needs a single map size), not on a
    random free cell (§5.4.2)"""
    episodes: int = 100_000
    """training episodes"""
    time_limit: float = 0.0
    """stop after this many seconds of training (0: none); the .json records the episodes done"""
    num_worlds: int = 256
    """worlds stepped together (one numpy call for all); they share the table"""
    seed: int = 1
    """seed of the maps, starts and the policy's coin flips"""
    table_path: str | None = None
    """where the table (.npz) is written, its .json of how it was trained beside it; default:
    runs/RUN_NAME/tabular_q.npz (models/ is written only when named here; maps/ and results/ never)"""
    overwrite: bool = False
    """let --table-path replace an existing tabular_q table and its .json (a file that is not one is never replaced)"""
    init_table: str | None = None
    """continue training this table (it must have the same K and r)"""
    log_every: int = 10_000
    """episodes between progress lines"""
    curve_window: int = 1000
    """episodes per point of the learning curve saved in the .json"""
    quiet: bool = False
    """no progress bar (there is none either when stdout is not a terminal)"""


# ----------------------------------------------------------------------------- state (§5.3.1)
def reading_caps(sensor_range: int) -> tuple[int, int]:
    """Largest r' value in the cardinal and the diagonal directions (gridworld.observe_tabular)."""
    return max(1, sensor_range - 1), max(1, int(sensor_range / math.sqrt(2)) - 1)


class Encoder:
    """The last K pairs (r'_t, a_{t-1}) of each world as one int64 key. A pair is the mixed-radix
    number of its 8 readings (each in -1..cap) and its last move (N, S, W, E or none), plus one,
    so 0 marks an empty slot at an episode's start; the K slots are digits of base `base`."""

    def __init__(self, memory: int, sensor_range: int):
        if memory < 1 or sensor_range < 1:
            raise ValueError(f"need K >= 1 and r >= 1, got K = {memory}, r = {sensor_range}")
        cardinal, diagonal = reading_caps(sensor_range)
        radix = np.array([cardinal + 2] * 4 + [diagonal + 2] * 4, np.int64)
        self.weights = np.concatenate([[1], np.cumprod(radix[:-1])])
        self.base = int(np.prod(radix)) * 5 + 1
        if memory * math.log2(self.base) >= 63:  # by logarithms: base ** memory of a huge K would take forever
            raise ValueError(f"K = {memory} with r = {sensor_range} gives {self.base}^{memory} states, more "
                             "than an int64 key holds")
        self.memory = memory
        self.powers = np.array([self.base ** k for k in range(memory)], np.int64)

    def push(self, history: np.ndarray, worlds, readings: np.ndarray, moves) -> np.ndarray:
        """Shift the new pair into the K slots of `worlds` (history (B, K)); their keys."""
        h = history[worlds]
        h[:, 1:] = h[:, :-1]
        h[:, 0] = 1 + ((readings.astype(np.int64) + 1) @ self.weights) * 5 + moves
        history[worlds] = h
        return h @ self.powers


def allowed_actions(readings: np.ndarray, heuristic: bool) -> np.ndarray:
    """§5.3.3 rules 1-2 as a (B, 5) mask: the moves toward an adjacent uncovered cell (A'); the
    heuristic if and only if there is none (without it, then every move)."""
    toward = readings[:, READING_OF_MOVE] > 0
    stuck = ~toward.any(1)
    allowed = np.zeros((len(readings), 5), bool)
    allowed[:, :4] = toward
    if heuristic:
        allowed[:, HEURISTIC] = stuck
    else:
        allowed[stuck, :4] = True
    return allowed


# ----------------------------------------------------------------------------- files
def is_table(path: str) -> bool:
    """Whether `path` is an .npz with the arrays QTable.save writes (read from the zip's listing alone)."""
    try:
        with zipfile.ZipFile(path) as archive:
            names = set(archive.namelist())
    except (OSError, zipfile.BadZipFile, ValueError):
        return False
    return all(f"{name}.npy" in names for name in TABLE_ARRAYS)


def is_table_json(path: str) -> bool:
    """Whether `path` is the .json tabular_q writes beside a table (its flags, states and learning curve)."""
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except (OSError, ValueError):
        return False
    return (isinstance(data, dict) and {"args", "states", "curve_rho"} <= set(data)
            and isinstance(data["args"], dict) and "algorithm" in data["args"])


def check_table_path(table_path: str, overwrite: bool) -> None:
    """The write rule of --table-path: nowhere under maps/ or results/ of this repository; an existing file there
    (the .npz or the .json beside it) must be a tabular_q table or its .json, and is replaced only with
    --overwrite."""
    for path in (table_path, os.path.splitext(table_path)[0] + ".json"):
        gridworld.check_output(path, "model", overwrite=True, flag="--table-path")  # maps/ and results/ hold no tables
    json_path = os.path.splitext(table_path)[0] + ".json"
    for path, ours, what in ((table_path, is_table, "a tabular_q table"),
                             (json_path, is_table_json, "a tabular_q table's .json")):
        if os.path.lexists(path) and not (os.path.isfile(path) and ours(path)):
            raise ValueError(f"--table-path {table_path}: {path} exists and is not {what}; it is never replaced "
                             "(choose another path)")
    present = [p for p in (table_path, json_path) if os.path.lexists(p)]
    if present and not overwrite:
        raise ValueError(f"--table-path {table_path}: {' and '.join(present)} exist(s) already; --overwrite "
                         "replaces them")


# ----------------------------------------------------------------------------- the Q-table
class QTable:
    """Q-values and visit counts of the states seen, rows in order of first visit. Row 0 is the
    never-seen state (all zeros), which lookups without insertion return for unknown keys. A
    numpy open-addressing hash table (linear probing, load <= 1/2) maps keys to rows."""

    def __init__(self, memory: int, sensor_range: int, tables: int = 1, capacity: int = 1 << 12):
        self.memory, self.sensor_range = memory, sensor_range
        self.size = 1  # rows in use, the never-seen row included
        self.keys = np.zeros(capacity, np.int64)
        self.q = np.zeros((tables, capacity, 5))
        self.visits = np.zeros(capacity, np.int64)  # n(s), for ε_t(s) = 1/sqrt(n_t(s))
        self.updates = np.zeros((tables, capacity, 5), np.int64)  # n(s, a) of each table
        self.slots = np.zeros(2 * capacity, np.int64)  # row per slot, 0 = empty

    def _home(self, keys: np.ndarray) -> np.ndarray:
        shift = np.uint64(64 - (len(self.slots).bit_length() - 1))
        return ((keys.view(np.uint64) * HASH) >> shift).astype(np.int64)

    def _place(self, keys: np.ndarray, rows: np.ndarray) -> None:
        """Put new (absent, distinct) keys with their rows into empty slots."""
        mask = len(self.slots) - 1
        slot, todo = self._home(keys), np.arange(len(keys))
        while len(todo):
            s = slot[todo]
            empty = self.slots[s] == 0
            self.slots[s[empty]] = rows[todo[empty]]  # equal slots: the last write wins
            placed = np.zeros(len(todo), bool)
            placed[empty] = self.slots[s[empty]] == rows[todo[empty]]
            todo = todo[~placed]
            slot[todo] = (slot[todo] + 1) & mask

    def _grow(self, need: int) -> None:
        capacity = len(self.keys)
        while capacity < need:
            capacity *= 2
        if capacity > len(self.keys):
            n = self.size
            for name in ("keys", "visits"):
                old = getattr(self, name)
                setattr(self, name, np.zeros(capacity, old.dtype))
                getattr(self, name)[:n] = old[:n]
            for name in ("q", "updates"):
                old = getattr(self, name)
                setattr(self, name, np.zeros((len(old), capacity, 5), old.dtype))
                getattr(self, name)[:, :n] = old[:, :n]
            self.slots = np.zeros(2 * capacity, np.int64)
            self._place(self.keys[1:n], np.arange(1, n))

    def rows(self, keys: np.ndarray, insert: bool = True) -> np.ndarray:
        """Row of every key; unknown keys get new rows (insert) or row 0."""
        unique, inverse = np.unique(keys, return_inverse=True)
        mask = len(self.slots) - 1
        out = np.zeros(len(unique), np.int64)
        slot, todo = self._home(unique), np.arange(len(unique))
        while len(todo):  # probe until each key meets itself or an empty slot
            row = self.slots[slot[todo]]
            hit = (row > 0) & (self.keys[row] == unique[todo])
            out[todo[hit]] = row[hit]
            todo = todo[(row > 0) & ~hit]
            slot[todo] = (slot[todo] + 1) & mask
        new = np.flatnonzero(out == 0)
        if insert and len(new):
            self._grow(self.size + len(new))
            rows = self.size + np.arange(len(new))
            self.keys[rows] = unique[new]
            self._place(unique[new], rows)
            self.size += len(new)
            out[new] = rows
        return out[inverse]

    def save(self, path: str) -> None:
        """Rows by key (sorted keys compress to about half), Q-values as float32; written to a temporary file
        beside `path` that then replaces it, so a kill or a full disk during the save leaves the old file whole."""
        rows = 1 + np.argsort(self.keys[1:self.size])
        with gridworld.staged_output(path, "model", overwrite=True, flag="--table-path") as tmp:
            np.savez_compressed(tmp, keys=self.keys[rows], q=self.q[:, rows].astype(np.float32),
                                visits=self.visits[rows].astype(np.uint32),
                                updates=self.updates[:, rows].astype(np.uint32),
                                memory=self.memory, sensor_range=self.sensor_range)

    @classmethod
    def load(cls, path: str, memory: int | None = None, sensor_range: int | None = None) -> QTable:
        """A saved table; a table trained with another K or r is an error."""
        if not os.path.isfile(path):
            raise ValueError(f"{path}: no such table")
        if not zipfile.is_zipfile(path):
            raise ValueError(f"{path}: not a tabular_q table (not an .npz file)")
        names = ("keys", "q", "visits", "updates", "memory", "sensor_range")
        try:
            with np.load(path) as data:
                arrays = {k: data[k] for k in names if k in data.files}
            keys, q, visits, updates = (arrays[k] for k in names[:4])
            k, r = int(arrays["memory"]), int(arrays["sensor_range"])
        except KeyError as e:
            raise ValueError(f"{path}: not a tabular_q table (no {e} array)") from None
        except (OSError, ValueError, TypeError, EOFError, zipfile.BadZipFile, zlib.error) as e:
            raise ValueError(f"{path}: not a tabular_q table ({(str(e).splitlines() or [type(e).__name__])[0]})") from None
        n = len(keys) if keys.ndim == 1 else -1
        if (keys.dtype != np.int64 or keys.ndim != 1 or q.ndim != 3 or q.shape[1:] != (n, 5)
                or q.shape[0] not in (1, 2) or visits.shape != (n,) or updates.shape != q.shape
                or len(np.unique(keys)) != n):
            raise ValueError(f"{path}: not a tabular_q table (arrays of inconsistent shapes)")
        if q.dtype.kind != "f" or visits.dtype.kind not in "iu" or updates.dtype.kind not in "iu":
            raise ValueError(f"{path}: not a tabular_q table (Q-values must be floats, counts integers)")
        if k < 1 or r < 1:
            raise ValueError(f"{path}: not a tabular_q table (K = {k}, r = {r}; both must be >= 1)")
        if (visits < 0).any() or (updates < 0).any():
            raise ValueError(f"{path}: not a tabular_q table (negative visit counts)")
        if (memory, sensor_range) != (None, None) and (k, r) != (memory, sensor_range):
            raise ValueError(f"{path}: trained with K = {k}, r = {r}; this run uses K = {memory}, "
                             f"r = {sensor_range}")
        table = cls(k, r, len(q), 1 << max(12, n.bit_length()))
        table.keys[1:n + 1], table.q[:, 1:n + 1] = keys, q
        table.visits[1:n + 1], table.updates[:, 1:n + 1] = visits, updates
        table._place(keys, np.arange(1, n + 1))
        table.size = n + 1
        return table


# ----------------------------------------------------------------------------- policy (§5.3.3)
def choose(table: QTable, rows: np.ndarray, allowed: np.ndarray, rng: np.random.Generator,
           explore: bool) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 5.1 restricted to the allowed actions, ties broken at random; returns the actions and
    whether each is greedy. Rule 3: a never-seen state takes the heuristic, whose step there is
    a uniformly random move of A' (the nearest uncovered cells are the adjacent ones, and the
    heuristic breaks ties at random), or the heuristic itself when A' is empty. ε_t(s) =
    1/sqrt(n_t(s)) with n_t(s) counting this visit (the caller counts it afterwards). Double Q
    ranks by QA + QB, the average's order (§2.3.2)."""
    q = np.where(allowed, table.q[:, rows].sum(0), -np.inf)
    best = q.max(1, keepdims=True)
    greedy = np.argmax((q == best) * rng.random(q.shape), 1)
    uniform = np.argmax(allowed * rng.random(q.shape), 1)
    n = table.visits[rows]
    coin = rng.random(len(rows)) < 1.0 / np.sqrt(n + 1)
    random = (n == 0) | (coin & explore)
    actions = np.where(random, uniform, greedy)
    return actions, q[np.arange(len(rows)), actions] == best[:, 0]


# ----------------------------------------------------------------------------- learning
class Learner:
    """TD updates of one batched step. Several contributions to one table entry in one step
    (worlds in the same state) are averaged and applied with the step of that many sequential
    updates toward their mean, 1 - (1 - α)^k (or with α = 1/n(s, a)), so a batch never
    overshoots where one update would not."""

    def __init__(self, table: QTable, args: Args, num_worlds: int, longest: int, rng: np.random.Generator):
        self.table, self.args, self.rng = table, args, rng
        if args.algorithm == "watkins":  # per-world eligibility traces of the episode so far
            self.trace_rows = np.zeros((num_worlds, longest), np.int64)
            self.trace_actions = np.zeros((num_worlds, longest), np.int64)
            self.trace_values = np.zeros((num_worlds, longest))
            self.trace_length = np.zeros(num_worlds, np.int64)

    def apply(self, which: np.ndarray, rows: np.ndarray, actions: np.ndarray, contributions: np.ndarray) -> None:
        t = self.table
        flat = (which * t.q.shape[1] + rows) * 5 + actions
        unique, inverse, k = np.unique(flat, return_inverse=True, return_counts=True)
        total = np.bincount(inverse, contributions)
        if self.args.alpha_visits:
            step = total / t.updates.reshape(-1)[unique]
        else:
            step = total * (1 - (1 - self.args.alpha) ** k) / k
        t.q.reshape(-1)[unique] += step

    def update(self, worlds, rows, actions, reward, next_rows, next_actions, next_allowed, next_greedy,
               terminated, done) -> None:
        """One transition (s, a, R, s', a') per world of `worlds`; s' is terminal where
        `terminated` (its row, action and allowed set are then ignored)."""
        a, t, g = self.args, self.table, self.args.gamma
        B = len(rows)
        which = np.zeros(B, np.int64)
        if a.algorithm == "double-q":  # Algorithm 5: UPDATE(A) or UPDATE(B) at random
            which = (self.rng.random(B) < 0.5).astype(np.int64)
        np.add.at(t.updates, (which, rows, actions), 1)
        if a.algorithm == "sarsa":  # Algorithm 4, blue line
            value = t.q[0, next_rows, next_actions]
        elif a.algorithm == "double-q":  # a* from the updated table, its value from the other
            own = np.where(next_allowed, t.q[which, next_rows], -np.inf)
            best = np.argmax(own, 1)
            value = t.q[1 - which, next_rows, best]
        else:  # Q-learning and Watkins's Q(λ): the greedy value over the allowed actions
            value = np.where(next_allowed, t.q[0, next_rows], -np.inf).max(1)
        target = reward + g * np.where(terminated, 0.0, value)
        delta = target - t.q[which, rows, actions]
        if a.algorithm != "watkins":
            return self.apply(which, rows, actions, delta)
        # Algorithm 6 (Q(λ)): E(s, a) += 1, every traced pair moves by αδE, then E decays by γλ,
        # or is cut when a' is exploratory (ties with the greedy value count as greedy)
        j = self.trace_length[worlds]
        self.trace_rows[worlds, j], self.trace_actions[worlds, j] = rows, actions
        self.trace_values[worlds, j] = 1.0
        self.trace_length[worlds] += 1
        width = int(self.trace_length[worlds].max())
        live = np.arange(width) < self.trace_length[worlds, None]
        values = self.trace_values[worlds, :width]
        self.apply(np.zeros(int(live.sum()), np.int64), self.trace_rows[worlds, :width][live],
                   self.trace_actions[worlds, :width][live], (delta[:, None] * values)[live])
        self.trace_values[worlds, :width] = values * (g * a.lam)
        self.trace_length[worlds[~next_greedy | done]] = 0


# ----------------------------------------------------------------------------- acting
def say(bar: tqdm | None, line: str) -> None:
    """A log line above a live progress bar, else a plain line flushed at once (logs read as they grow)."""
    if bar is not None and not bar.disable:
        bar.write(line)
    else:
        print(line, flush=True)


def play(core: gridworld.GridWorldCore, table: QTable, encoder: Encoder, rng: np.random.Generator,
         episodes: int, heuristic: bool = True, learner: Learner | None = None, source=None,
         log_every: int = 0, time_limit: float = 0.0, bar: tqdm | None = None,
         record_paths: bool = False, stop=None) -> dict[str, np.ndarray]:
    """Run `episodes` episodes on the core's worlds, new ones starting as others end, acting
    with the table (ε-greedy and learning with a learner, greedy without). `source(k)` gives
    the scenarios of k new episodes (fewer leaves worlds idle; None lets the core draw maps).
    Returns per-episode metrics indexed by episode number (order of starting), `order`, the
    episode numbers in the order they ended, and `finished`, how many ended (fewer than
    `episodes` when `time_limit` seconds ran out first); with record_paths also `paths`, per
    episode the (T+1, 1, 2) [row, col] cells of its agent from the start. `bar` counts the
    episodes that end. `stop()`, when given and true, ends the run early as the time limit does."""
    B, learn = core.B, learner is not None
    history = np.zeros((B, encoder.memory), np.int64)
    rows, actions = np.zeros(B, np.int64), np.zeros(B, np.int64)
    episode = np.full(B, -1)
    idle = np.zeros(B, bool)
    heuristic_steps = np.zeros(B, np.int64)
    out = {k: np.zeros(episodes, d) for k, d in (("steps", np.int64), ("rho", np.float64),
                                                  ("overlap", np.float64), ("time_save", np.float64),
                                                  ("revisits", np.int64), ("completed", bool),
                                                  ("truncated", bool), ("heuristic_steps", np.int64),
                                                  ("order", np.int64))}  # order: episodes as they ended
    if record_paths:  # the battery ends every episode within ceil(factor * H * W) steps
        trail = np.zeros((B, math.ceil(core.config.battery_factor * core.H * core.W) + 1, 2), np.int64)
        length = np.zeros(B, np.int64)
        paths: list[np.ndarray | None] = [None] * episodes
    started = finished = 0
    more = True
    refill = max(1, B // 16)  # a reset costs about as much as a step: restart worlds in groups
    t0, last_log = time.perf_counter(), 0

    def observe(w, moves):
        readings = core.observe_tabular()[w, 0]
        keys = encoder.push(history, w, readings, moves)
        return table.rows(keys, insert=learn), allowed_actions(readings, heuristic)

    def decide(r, allowed):
        chosen = choose(table, r, allowed, rng, explore=learn)
        if learn:
            np.add.at(table.visits, r, 1)
        return chosen

    def begin(w):
        nonlocal started, more
        w = w[:max(0, episodes - started)]
        scenarios = source(len(w)) if source is not None else None
        if scenarios is not None:
            w = w[:len(scenarios)]
        more = started + len(w) < episodes and len(w) > 0
        idle[w] = False
        if len(w) == 0:
            return
        core.reset(w, scenarios=scenarios)
        if record_paths:
            trail[w, 0], length[w] = core.agent_cells()[w, 0], 1
        episode[w] = started + np.arange(len(w))
        started += len(w)
        history[w] = 0
        heuristic_steps[w] = 0
        r, allowed = observe(w, NO_MOVE)
        rows[w] = r
        actions[w] = decide(r, allowed)[0]

    idle[:] = True
    begin(np.arange(B))
    while (finished < episodes and not (time_limit and time.perf_counter() - t0 > time_limit)
           and not (stop and stop())):
        use = actions == HEURISTIC
        moves = actions.copy()
        if use.any():
            moves[use] = gridworld.heuristic_actions(core)[use, 0]
        moves[idle] = gridworld.WAIT
        heuristic_steps += use
        ev = core.step(moves[:, None])
        terminated, done = ev["terminated"], ev["terminated"] | ev["truncated"]
        live = np.flatnonzero(~idle)
        if record_paths:
            trail[live, length[live]] = core.agent_cells()[live, 0]
            length[live] += 1
        go = np.flatnonzero(~idle & ~terminated)  # worlds that act again from s'
        next_rows, next_actions = np.zeros(B, np.int64), np.zeros(B, np.int64)
        next_allowed, next_greedy = np.ones((B, 5), bool), np.ones(B, bool)
        next_rows[go], next_allowed[go] = observe(go, moves[go])
        next_actions[go], next_greedy[go] = decide(next_rows[go], next_allowed[go])
        if learn:
            learner.update(live, rows[live], actions[live], ev["reward"][live, 0].astype(np.float64),
                           next_rows[live], next_actions[live], next_allowed[live], next_greedy[live],
                           terminated[live], done[live])
        rows[go], actions[go] = next_rows[go], next_actions[go]
        ended = np.flatnonzero(done & ~idle)
        if len(ended):
            m = core.metrics()
            e = episode[ended]
            for k in ("steps", "rho", "overlap", "time_save", "revisits", "completed"):
                out[k][e] = m[k][ended]
            out["truncated"][e] = ev["truncated"][ended]
            out["heuristic_steps"][e] = heuristic_steps[ended]
            out["order"][finished:finished + len(ended)] = e
            if record_paths:
                for world, number in zip(ended, e):
                    paths[number] = trail[world, :length[world], None].copy()
            finished += len(ended)
            idle[ended] = True
            if bar is not None:
                bar.update(len(ended))
        if more and (idle.sum() >= refill or idle.all()):
            begin(np.flatnonzero(idle))
        if log_every and finished - last_log >= log_every:
            last_log = finished
            seconds = time.perf_counter() - t0
            recent = out["rho"][out["order"][finished - log_every:finished]]
            say(bar, f"episodes {finished:,}/{episodes:,}  rho {recent.mean():.4f} (last {log_every:,})  "
                     f"states {table.size - 1:,}  {finished / seconds:,.0f} episodes/s  "
                     f"{out['steps'][out['order'][:finished]].sum() / seconds:,.0f} steps/s  {seconds:,.0f} s")
    out["finished"] = np.array(finished)
    if record_paths:
        out["paths"] = paths
    return out


# ----------------------------------------------------------------------------- settings
def env_config(size: int, min_size: int, number_obstacles: int = 0, obstacles_random: bool = False,
               sensor: str = "lidar", sensor_range: int = 3) -> gridworld.EnvConfig:
    """The chapter-5 environment: tabular readings, the §5.3.4 reward, battery 5·h·w steps."""
    return gridworld.EnvConfig(size=size, min_size=min_size, random_size=min_size < size,
                               number_obstacles=number_obstacles, obstacles_random=obstacles_random,
                               sensor=sensor, sensor_range=sensor_range, observation="tabular",
                               reward=gridworld.RewardParams.chapter5())


def corner_source(args: Args, rng: np.random.Generator):
    """New episodes starting in a random corner (§5.4.1), maps drawn 1,024 per corner at a time."""
    pool: list[gridworld.Scenario] = []
    corners = [[0, 0], [0, args.size - 1], [args.size - 1, 0], [args.size - 1, args.size - 1]]

    def source(k: int) -> list[gridworld.Scenario]:
        while len(pool) < k:
            for corner in corners:
                pool.extend(gridworld.generate_scenarios(
                    1024, seed=int(rng.integers(2 ** 62)), size=args.size, number_obstacles=args.number_obstacles,
                    obstacles_random=args.obstacles_random, starting_position=[corner],
                    starting_position_random=False))
            order = rng.permutation(len(pool))
            pool[:] = [pool[i] for i in order]
        taken = pool[-k:]
        del pool[-k:]
        return taken

    return source


def evaluate_table(table: QTable, scenarios: list[gridworld.Scenario], heuristic: bool = True,
                   sensor: str = "lidar", seed: int = 0, num_worlds: int = 256, trajectories: list | None = None,
                   quiet: bool = False) -> dict[str, np.ndarray]:
    """The greedy policy (no exploration, no learning; never-seen states take the heuristic) on
    the given scenarios with their starts; per-scenario metrics in the scenarios' order. A given
    `trajectories` list is extended, in the same order, with each episode's (T+1, 1, 2) int array
    of the agent's [row, col] at every step, T that episode's steps (the start first)."""
    size = max(max(s.obstacles.shape) for s in scenarios)
    core = gridworld.GridWorldCore(env_config(size, size, sensor=sensor, sensor_range=table.sensor_range),
                                   min(num_worlds, len(scenarios)), seed=seed)
    queue = list(scenarios)

    def source(k: int) -> list[gridworld.Scenario]:
        taken = queue[:k]
        del queue[:k]
        return taken

    with tqdm(total=len(scenarios), desc="tabular", unit="episode", disable=quiet or not sys.stdout.isatty()) as bar:
        out = play(core, table, Encoder(table.memory, table.sensor_range), np.random.default_rng(seed),
                   len(scenarios), heuristic, source=source, bar=bar, record_paths=trajectories is not None)
    if trajectories is not None:
        trajectories.extend(out["paths"])
    return {k: v for k, v in out.items() if k not in ("order", "finished", "paths")}


def provenance() -> dict:
    """What made a run (gridworld.provenance: the code's git commit, the machine, the command line) and the date."""
    return gridworld.provenance("tabular_q.py") | {"date": datetime.now(UTC).isoformat(timespec="seconds")}


# ----------------------------------------------------------------------------- training
def main(args: Args) -> dict:
    if args.algorithm not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {args.algorithm!r}; choose from {', '.join(ALGORITHMS)}")
    if not (0 < args.alpha <= 1 and 0 <= args.gamma <= 1 and 0 <= args.lam <= 1):
        raise ValueError("need 0 < alpha <= 1, 0 <= gamma <= 1 and 0 <= lam <= 1")
    for flag, value, least in (("--episodes", args.episodes, 1), ("--num-worlds", args.num_worlds, 1),
                               ("--curve-window", args.curve_window, 1), ("--log-every", args.log_every, 0),
                               ("--time-limit", args.time_limit, 0), ("--memory", args.memory, 1),
                               ("--sensor-range", args.sensor_range, 1), ("--size", args.size, 2),
                               ("--number-obstacles", args.number_obstacles, 0)):
        if value < least:
            raise ValueError(f"{flag} must be >= {least}, got {value}")
    for flag, value in (("--alpha", args.alpha), ("--gamma", args.gamma), ("--lam", args.lam),
                        ("--time-limit", args.time_limit)):
        if not math.isfinite(value):
            raise ValueError(f"{flag} must be a finite number, got {value}")
    if args.size > gridworld.MAX_MAP_SIDE:
        raise ValueError(f"--size must be at most {gridworld.MAX_MAP_SIDE} (gridworld.MAX_MAP_SIDE), got {args.size}")
    min_size = args.size if args.min_size is None else args.min_size
    if not 2 <= min_size <= args.size:
        raise ValueError(f"--min-size must be in 2..{args.size} (--size), got {min_size}")
    if args.corner_starts and min_size != args.size:
        raise ValueError("--corner-starts needs one map size (min_size = size)")
    if args.sensor not in gridworld.SENSORS:
        raise ValueError(f"--sensor must be one of {', '.join(gridworld.SENSORS)}, got {args.sensor!r}")
    run_name = args.run_name or f"{args.exp_name}__{args.seed}__{int(time.time())}"
    if run_name in (".", "..") or os.path.basename(run_name) != run_name or "\\" in run_name:
        raise ValueError(f"--run-name must be a folder name under runs/ (no '/' or '..'), got {run_name!r}")
    if not args.table_path and os.path.exists(os.path.join("runs", run_name, "tabular_q.npz")):
        raise ValueError(f"runs/{run_name} holds a run already: choose another --run-name")
    table_path = args.table_path or os.path.join("runs", run_name, "tabular_q.npz")
    if not table_path.endswith(".npz") or os.path.isdir(table_path):
        raise ValueError(f"--table-path {table_path}: must name an .npz file (its .json goes beside it)")
    check_table_path(table_path, args.overwrite)
    parent = os.path.dirname(os.path.abspath(table_path))
    while not os.path.exists(parent):  # the folders save() would create: can the nearest existing one take them?
        parent = os.path.dirname(parent)
    try:  # a file made there, since os.access lets root write anywhere (/proc too)
        tempfile.TemporaryFile(dir=parent).close()
    except OSError as e:
        raise ValueError(f"--table-path {table_path}: cannot write under {parent} ({e.strerror})") from None
    args = dataclasses.replace(args, run_name=run_name, table_path=table_path)
    encoder = Encoder(args.memory, args.sensor_range)
    tables = 2 if args.algorithm == "double-q" else 1
    if args.init_table:
        table = QTable.load(args.init_table, args.memory, args.sensor_range)
        if len(table.q) != tables:
            raise ValueError(f"{args.init_table}: holds {len(table.q)} Q-table(s), {args.algorithm} uses {tables}")
    else:
        table = QTable(args.memory, args.sensor_range, tables)
    cfg = env_config(args.size, min_size, args.number_obstacles, args.obstacles_random, args.sensor,
                     args.sensor_range)
    core = gridworld.GridWorldCore(cfg, args.num_worlds, seed=args.seed)
    rng = np.random.default_rng(args.seed)
    learner = Learner(table, args, args.num_worlds, math.ceil(cfg.battery_factor * args.size ** 2) + 1, rng)
    source = corner_source(args, rng) if args.corner_starts else None
    made = provenance()
    print(f"{run_name}: {args.algorithm}, {args.episodes:,} episodes on {args.num_worlds} worlds, maps "
          f"{min_size}-{args.size} with up to {args.number_obstacles} obstacle(s) -> {table_path}", flush=True)
    stop = {"signal": 0}  # Ctrl-C and SIGTERM end training as the time limit does: the table so far is saved
    catch = threading.current_thread() is threading.main_thread()
    previous = {s: signal.signal(s, lambda n, _: stop.update(signal=n)) for s in (signal.SIGINT, signal.SIGTERM)} \
        if catch else {}
    try:
        start = time.perf_counter()
        with tqdm(total=args.episodes, desc=args.algorithm, unit="episode",
                  disable=args.quiet or not sys.stdout.isatty()) as bar:
            out = play(core, table, encoder, rng, args.episodes, args.heuristic, learner, source, args.log_every,
                       args.time_limit, bar, stop=lambda: stop["signal"])
        seconds = time.perf_counter() - start
        done = out["order"][:int(out["finished"])]
        if stop["signal"] and not len(done):
            print(f"error: interrupted by {signal.Signals(stop['signal']).name} before any episode ended; nothing "
                  "written", file=sys.stderr)
            raise SystemExit(128 + stop["signal"])
        rho = out["rho"][done]  # in the order the episodes ended
        n = len(rho) // args.curve_window * args.curve_window
        info = dict(args=asdict(args), run_name=run_name, episodes=len(done), states=table.size - 1,
                    steps=int(out["steps"][done].sum()), wall_seconds=round(seconds, 1),
                    episodes_per_second=round(len(done) / seconds, 1),
                    steps_per_second=round(out["steps"][done].sum() / seconds, 1),
                    machine=f"{made['cpu'] or 'CPU'}, {made['cores']} cores (one used), numpy {np.__version__}",
                    **made,
                    final_rho=round(float(rho[-args.curve_window:].mean()), 4) if len(rho) else None,
                    completion=round(float(out["completed"][done].mean()), 4) if len(done) else None,
                    curve_window=args.curve_window,
                    curve_rho=[round(float(x), 4) for x in rho[:n].reshape(-1, args.curve_window).mean(1)])
        if stop["signal"]:
            info["interrupted"] = signal.Signals(stop["signal"]).name
        json_path = os.path.splitext(table_path)[0] + ".json"
        # both staged: the table replaces the old one, then the .json does, each in one os.replace
        with gridworld.staged_output(json_path, "model", overwrite=True, flag="--table-path") as tmp:
            with open(tmp, "w") as f:
                json.dump(info, f, indent=1)
            table.save(table_path)
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    print(f"{args.algorithm}: {len(done):,} episodes in {seconds:.1f} s ({info['episodes_per_second']:,} "
          f"episodes/s), {info['states']:,} states, final rho {info['final_rho']} -> {table_path}")
    if stop["signal"]:  # the shell's convention: 130 for Ctrl-C, 143 for SIGTERM
        print(f"error: interrupted by {signal.Signals(stop['signal']).name} after {len(done):,} of "
              f"{args.episodes:,} episodes; the table so far is saved -> {table_path}", file=sys.stderr)
        raise SystemExit(128 + stop["signal"])
    return info


if __name__ == "__main__":
    with gridworld.cli_errors():
        main(gridworld.cli(Args))

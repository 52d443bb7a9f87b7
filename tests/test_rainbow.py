"""Tests for rainbow_cpp.py (modified Rainbow DQN for single-agent coverage, chapter 6).

Expectations are computed by hand / by plain reference code in this file:

- NoisyLinear (factorised Gaussian, eq. 6.18): W = mu_W + sigma_W * outer(f(eps_out), f(eps_in)),
  b = mu_b + sigma_b * f(eps_out), f(x) = sign(x) sqrt|x|; sigma init sigma0 / sqrt(n_in).
- QNetwork (Fig. 6.8): 3 frames -> 12 map channels; 41 -> 41 (3x3, s1, p1) -> 20 (3x3, s2) -> 9
  (3x3, s2), so 64 * 9 * 9 = 5184 conv features, plus 1 + 3 * (5 + 8) = 40 extras.
  Dueling (eq. 6.17): Q = V + A - mean_a A.
- Replay: one frame per step and world; a stack of k frames ending at frame t of an episode is
  frames max(t - k + 1 .. t, 0) of that episode (the first frame repeated); the n-step return
  of transition t is sum_j g^j r_{t+j} over the m = min(n, to the episode's end, to the newest
  frame) transitions, stopping after a terminal one; bootstrap g^m (0 if it terminated) from
  frame t + m of the same episode.
"""
from __future__ import annotations

import json
import os

import numpy as np
import pytest
import torch
import torch.nn.functional as F

import gridworld as gw
import rainbow_cpp as rc

V = 41


def f_noise(x: torch.Tensor) -> torch.Tensor:
    return torch.sign(x) * torch.sqrt(torch.abs(x))


# ============================================================================ 1. NoisyLinear
def test_noisy_linear_sigma_and_mu_init():
    layer = rc.NoisyLinear(16, 5, sigma0=0.5)
    assert layer.weight_mu.shape == (5, 16) and layer.bias_mu.shape == (5,)
    assert torch.allclose(layer.weight_sigma, torch.full((5, 16), 0.5 / 4.0))  # 0.5 / sqrt(16)
    assert torch.allclose(layer.bias_sigma, torch.full((5,), 0.125))
    assert layer.weight_mu.abs().max() <= 0.25 and layer.bias_mu.abs().max() <= 0.25  # U(-1/sqrt(n_in), ..)
    layer = rc.NoisyLinear(9, 2, sigma0=0.3)
    assert torch.allclose(layer.weight_sigma, torch.full((2, 9), 0.1))  # 0.3 / 3


def test_noisy_linear_noise_off_is_the_mean_layer():
    torch.manual_seed(0)
    layer = rc.NoisyLinear(7, 3, sigma0=0.5)
    layer.reset_noise(True)
    layer.reset_noise(False)
    assert not layer.eps_in.any() and not layer.eps_out.any()
    x = torch.randn(4, 7)
    assert torch.allclose(layer(x), F.linear(x, layer.weight_mu, layer.bias_mu), atol=1e-6)


def test_noisy_linear_factorised_noise():
    torch.manual_seed(0)
    layer = rc.NoisyLinear(6, 3, sigma0=0.5)
    with torch.no_grad():  # distinct sigmas, so that a transposed outer product would show
        layer.weight_sigma.copy_(torch.rand(3, 6) + 0.1)
        layer.bias_sigma.copy_(torch.rand(3) + 0.1)
    torch.manual_seed(123)
    z_in, z_out = torch.randn(6), torch.randn(3)
    torch.manual_seed(123)
    layer.reset_noise()
    assert torch.allclose(layer.eps_in, f_noise(z_in)) and torch.allclose(layer.eps_out, f_noise(z_out))
    # f by hand for a few values: f(4) = 2, f(-9) = -3, f(0) = 0
    assert torch.equal(rc.NoisyLinear._f(torch.tensor([4.0, -9.0, 0.0])), torch.tensor([2.0, -3.0, 0.0]))
    w = layer.weight_mu + layer.weight_sigma * (f_noise(z_out)[:, None] * f_noise(z_in)[None, :])
    b = layer.bias_mu + layer.bias_sigma * f_noise(z_out)
    x = torch.randn(5, 6)
    assert torch.allclose(layer(x), x @ w.T + b, atol=1e-5)
    assert not torch.allclose(layer(x), F.linear(x, layer.weight_mu, layer.bias_mu), atol=1e-3)


def test_noisy_linear_resampling_changes_the_output():
    torch.manual_seed(1)
    layer = rc.NoisyLinear(8, 4, sigma0=0.5)
    x = torch.randn(3, 8)
    layer.reset_noise()
    y1 = layer(x).detach().clone()
    assert torch.equal(layer(x), y1)  # the noise is fixed between resets
    layer.reset_noise()
    assert not torch.allclose(layer(x), y1)


# ============================================================================ 2. QNetwork
def test_qnetwork_shapes_and_feature_count():
    q = rc.QNetwork(frames=3, view=V, hidden=16, sigma0=0.5)
    assert q.value[0].n_in == 5184 + 40 and q.advantage[0].n_in == 5184 + 40
    assert q.conv(torch.zeros(1, 12, V, V)).shape == (1, 5184)
    assert q.value[-1].n_out == 1 and q.advantage[-1].n_out == 4
    maps = torch.randint(0, 256, (2, 12, V, V), dtype=torch.uint8)
    out = q(maps, torch.rand(2, 40))
    assert out.shape == (2, 4) and out.dtype == torch.float32


def test_qnetwork_dueling_combination():
    torch.manual_seed(0)
    q = rc.QNetwork(frames=3, view=V, hidden=16, sigma0=0.5)
    seen = {}
    q.value[-1].register_forward_hook(lambda m, i, o: seen.__setitem__("v", o.detach()))
    q.advantage[-1].register_forward_hook(lambda m, i, o: seen.__setitem__("a", o.detach()))
    maps = torch.randint(0, 256, (3, 12, V, V), dtype=torch.uint8)
    out = q(maps, torch.rand(3, 40)).detach()
    v, a = seen["v"], seen["a"]
    assert v.shape == (3, 1) and a.shape == (3, 4)
    assert torch.allclose(out, v + a - a.mean(1, keepdim=True), atol=1e-5)
    assert torch.allclose((out - v).mean(1), torch.zeros(3), atol=1e-5)
    # a shift of the value output shifts every action's Q equally
    with torch.no_grad():
        q.value[-1].bias_mu += 3.0
    q.reset_noise(False)
    extras = torch.rand(3, 40)
    with torch.no_grad():
        before = q(maps, extras)
        q.value[-1].bias_mu += 2.0
        after = q(maps, extras)
    assert torch.allclose(after - before, torch.full((3, 4), 2.0), atol=1e-4)


def test_qnetwork_reset_noise_reaches_every_noisy_layer():
    q = rc.QNetwork(frames=3, view=V, hidden=16, sigma0=0.5)
    layers = [m for m in q.modules() if isinstance(m, rc.NoisyLinear)]
    assert len(layers) == 6
    q.reset_noise(True)
    assert all(m.eps_in.any() for m in layers)
    q.reset_noise(False)
    assert not any(m.eps_in.any() or m.eps_out.any() for m in layers)


# ============================================================================ 3. SumTree
def check_tree(tree: rc.SumTree):
    t = tree.tree
    for node in range(1, tree.size):
        assert t[node] == pytest.approx(t[2 * node] + t[2 * node + 1], rel=1e-12, abs=1e-12)
    assert tree.total() == pytest.approx(t[tree.size:].sum(), rel=1e-12)


def test_sumtree_total_after_repeated_updates():
    tree = rc.SumTree(13)  # not a power of two
    assert tree.size >= 13
    rng = np.random.default_rng(0)
    ref = np.zeros(13)
    for _ in range(200):
        idx = rng.choice(13, size=rng.integers(1, 6), replace=False)
        p = rng.random(len(idx)) * 10
        tree.update(idx, p)
        ref[idx] = p
        check_tree(tree)
    assert np.allclose(tree.tree[tree.size:tree.size + 13], ref)
    assert tree.total() == pytest.approx(ref.sum())
    tree.update(np.array([3, 3, 3]), np.array([1.0, 2.0, 7.0]))  # duplicates in one call
    check_tree(tree)
    tree.update(np.arange(13), np.zeros(13))
    assert tree.total() == 0


@pytest.mark.parametrize("capacity", [1, 2, 5, 7])
def test_sumtree_small_capacities(capacity):
    tree = rc.SumTree(capacity)
    assert tree.size >= capacity
    tree.update(np.arange(capacity), np.arange(1, capacity + 1, dtype=float))
    check_tree(tree)
    assert tree.total() == pytest.approx(capacity * (capacity + 1) / 2)
    s = tree.sample(100, np.random.default_rng(0))
    assert s.min() >= 0 and s.max() < capacity


def test_sumtree_sampling_is_proportional_and_skips_zeros():
    p = np.array([0.0, 1.0, 2.0, 0.0, 4.0, 0.5, 3.0])  # capacity 7, padded to 8 leaves
    tree = rc.SumTree(7)
    tree.update(np.arange(7), p)
    rng = np.random.default_rng(0)
    draws = np.concatenate([tree.sample(997, rng) for _ in range(60)])
    counts = np.bincount(draws, minlength=tree.size)
    assert counts[[0, 3]].sum() == 0 and counts[7:].sum() == 0
    expected = p / p.sum() * len(draws)
    nz = p > 0
    chi2 = ((counts[:7][nz] - expected[nz]) ** 2 / expected[nz]).sum()
    assert chi2 < 25, (counts, expected)  # df 4: p(chi2 > 25) < 1e-4 for multinomial draws


def test_sumtree_zero_priority_never_sampled_wide_range():
    rng = np.random.default_rng(1)
    cap = 1000
    p = np.exp(rng.normal(0, 5, cap))  # priorities over many orders of magnitude
    p[rng.random(cap) < 0.4] = 0.0
    p[-1] = 0.0
    tree = rc.SumTree(cap)
    tree.update(np.arange(cap), p)
    draws = np.concatenate([tree.sample(32, rng) for _ in range(3000)])
    assert (p[draws] > 0).all()
    assert draws.max() < cap


# ============================================================================ 4. Replay
def single(obs: dict, i: int) -> dict:
    return {k: np.array(v[i]) for k, v in obs.items()}


def expected_stack(frames: list[dict], t: int, k: int):
    """Maps (4k, V, V) and extras (1 + 13k) of frame t of an episode (frames oldest first)."""
    picks = [frames[max(t - j, 0)] for j in range(k - 1, -1, -1)]
    maps = np.concatenate([f["map"] for f in picks], 0)
    extras = np.concatenate([picks[-1]["battery"][:1]] + [
        np.concatenate([f["last_action"], f["out_of_bounds"].reshape(8) / 100]) for f in picks])
    return maps, extras.astype(np.float32)


def assert_stack(got_maps, got_extras, want):
    maps, extras = want
    np.testing.assert_array_equal(got_maps, maps)
    np.testing.assert_allclose(got_extras, extras, atol=1e-3)  # battery and counts stored as fp16


class Driver:
    """Feeds a gridworld core into a Replay the way rainbow_cpp.main() does, and records every
    frame (per world, per episode) with its slot, action, reward and terminal flag."""

    def __init__(self, core, replay, frames=3):
        self.core, self.replay, self.k = core, replay, frames
        B = self.B = core.B
        self.every = np.arange(B)
        obs = gw.observe(core)
        self.stacker = rc.Stacker(B, frames, core.V)
        self.stacker.push(obs, np.ones(B, bool))
        self.slot = replay.add_frames(self.every, obs, np.zeros(B, np.int64), np.zeros(B, bool))
        self.age = np.zeros(B, np.int64)
        # per world: list of episodes; an episode: list of frame records
        self.episodes = [[[self._record(obs, i)]] for i in range(B)]
        self.where = {}  # slot -> (world, episode, t) of the frame last written there
        for i in range(B):
            self.where[int(self.slot[i])] = (i, 0, 0)

    def _record(self, obs, i):
        return dict(obs=single(obs, i), slot=int(self.slot[i]) if hasattr(self, "slot") else None,
                    action=None, reward=None, terminal=None)

    def step(self, action, reward=None, terminal=None, ended=None):
        core, rp, B = self.core, self.replay, self.B
        action = np.asarray(action, np.int64)
        ev = core.step(action[:, None])
        reward = ev["reward"][:, 0] if reward is None else np.asarray(reward, np.float32)
        terminal = ev["terminated"] if terminal is None else np.asarray(terminal, bool)
        ended = terminal.copy() if ended is None else np.asarray(ended, bool)
        rp.set_transition(self.slot, action, reward, terminal)
        for i in range(B):
            rec = self.episodes[i][-1][-1]
            rec.update(action=int(action[i]), reward=float(reward[i]), terminal=bool(terminal[i]))
        obs = gw.observe(core)
        self.slot = rp.add_frames(self.every, obs, self.age + 1, ended)
        self.age += 1
        for i in range(B):
            rec = self._record(obs, i)
            rec["final"] = bool(ended[i])
            self.episodes[i][-1].append(rec)
            self.where[int(self.slot[i])] = (i, len(self.episodes[i]) - 1, len(self.episodes[i][-1]) - 1)
        if ended.any():
            w = np.flatnonzero(ended)
            core.reset(w)
            obs = gw.observe(core)
            self.slot[w] = rp.add_frames(w, {k: v[w] for k, v in obs.items()}, np.zeros(len(w), np.int64),
                                         np.zeros(len(w), bool))
            self.age[w] = 0
            for i in w:
                self.episodes[i].append([dict(obs=single(obs, i), slot=int(self.slot[i]), action=None,
                                              reward=None, terminal=None)])
                self.where[int(self.slot[i])] = (i, len(self.episodes[i]) - 1, 0)
        self.stacker.push(obs, ended)
        return ev

    def frames_of(self, world, episode):
        return [r["obs"] for r in self.episodes[world][episode]]

    def expected_transition(self, slot, n, gamma):
        """(return, bootstrap, (world, episode, t of the next frame)) by the definition."""
        w, e, t = self.where[int(slot)]
        ep = self.episodes[w][e]
        ret, m = 0.0, 0
        boot = 1.0
        while m < n and t + m < len(ep) and ep[t + m]["reward"] is not None:
            ret += gamma ** m * ep[t + m]["reward"]
            m += 1
            if ep[t + m - 1]["terminal"]:
                boot = 0.0
                break
        assert m >= 1
        return ret, boot * gamma ** m, (w, e, t + m)


def small_core(num_worlds=2, seed=0, **kw):
    core = gw.GridWorldCore(gw.EnvConfig(size=5, **kw), num_worlds=num_worlds, seed=seed)
    core.reset()
    return core


def big_corner_core():
    """Two 30x30 worlds, agents near opposite corners, random pre-coverage: the compressed
    edge lines (rows/cols 1 and 39) hold non-binary means."""
    rng = np.random.default_rng(5)
    scen = []
    for start, frac in (((2, 2), 0.3), ((27, 26), 0.6)):
        covered = rng.random((30, 30)) < frac
        covered[start] = True
        scen.append(gw.Scenario(np.zeros((30, 30), bool), np.array([start]), covered))
    core = gw.GridWorldCore(gw.EnvConfig(size=30, load_state=True, load_random=False), num_worlds=2, seed=0)
    core.configure(scenarios=scen)
    core.reset()
    return core


def test_replay_frame_round_trip_with_compressed_edges():
    core = big_corner_core()
    obs = gw.observe(core)
    m = obs["map"]
    assert obs["map"].dtype == np.uint8 and m.shape == (2, 4, V, V)
    odd = (m != 0) & (m != 255)
    assert odd[0][:, V - 2, :].any() and odd[0][:, :, V - 2].any()  # world 0: south/east means
    assert odd[1][:, 1, :].any() and odd[1][:, :, 1].any()  # world 1: north/west means
    assert obs["out_of_bounds"].any()
    rp = rc.Replay(2 * 64, 2, V, 3, 1, 0.99, 0.5)
    d = Driver(core, rp)
    for a in ([1, 0], [3, 2], [1, 2], [4, 0]):  # S/N, E/W, ...; WAIT included
        d.step(a)
    for w in range(2):
        frames = d.frames_of(w, 0)
        for t, rec in enumerate(d.episodes[w][0]):
            maps, extras = rp._frames(np.array([rec["slot"]]))
            assert maps.shape == (1, 12, V, V) and maps.dtype == np.uint8 and extras.shape == (1, 40)
            np.testing.assert_array_equal(maps[0, -4:], rec["obs"]["map"])  # the newest frame, exact
            assert_stack(maps[0], extras[0], expected_stack(frames, t, 3))
        # extras by hand for the newest frame: battery, last action one-hot, out_of_bounds / 100
        rec = d.episodes[w][0][-1]
        _, extras = rp._frames(np.array([rec["slot"]]))
        budget = 5 * 30 * 30
        assert extras[0, 0] == pytest.approx((budget - 4) / budget, abs=1e-3)
        # layout: [battery, (last action one-hot 5, out_of_bounds 8) x frames oldest first]
        assert extras[0, 27:32].tolist() == ([0, 0, 0, 0, 1] if w == 0 else [1, 0, 0, 0, 0])  # WAIT / N
        np.testing.assert_allclose(extras[0, 32:40], rec["obs"]["out_of_bounds"].reshape(8) / 100, atol=1e-4)
        assert extras[0, 14:19].tolist() == ([0, 1, 0, 0, 0] if w == 0 else [0, 0, 1, 0, 0])  # S / W
        assert extras[0, 1:6].tolist() == ([0, 0, 0, 1, 0] if w == 0 else [0, 0, 1, 0, 0])  # E / W


def test_replay_stacks_never_cross_episodes_or_worlds():
    # tiny battery: episodes end by truncation after 5 steps (ended by hand, no partial reset)
    core = small_core(num_worlds=2, seed=3, battery_factor=0.2)
    rp = rc.Replay(2 * 100, 2, V, 3, 1, 0.9, 0.5)
    d = Driver(core, rp)
    rng = np.random.default_rng(0)
    for _ in range(14):
        ev_trunc = core.battery <= 1  # the next step truncates
        ev = d.step(rng.integers(0, 4, 2), terminal=np.zeros(2, bool), ended=ev_trunc)
        assert (ev["truncated"] | ev["terminated"])[ev_trunc].all()
    for w in range(2):
        assert len(d.episodes[w]) >= 3
        for e, ep in enumerate(d.episodes[w]):
            frames = d.frames_of(w, e)
            for t, rec in enumerate(ep):
                maps, extras = rp._frames(np.array([rec["slot"]]))
                assert_stack(maps[0], extras[0], expected_stack(frames, t, 3))
                assert rec["slot"] // rp.cap == w  # each world writes its own segment
            first = rp._frames(np.array([ep[0]["slot"]]))[0][0]
            for j in range(3):  # the first frame of an episode: all k frames are that frame
                np.testing.assert_array_equal(first[4 * j:4 * j + 4], ep[0]["obs"]["map"])
            if len(ep) > 1:
                second = rp._frames(np.array([ep[1]["slot"]]))[0][0]
                np.testing.assert_array_equal(second[0:4], ep[0]["obs"]["map"])
                np.testing.assert_array_equal(second[4:8], ep[0]["obs"]["map"])
                np.testing.assert_array_equal(second[8:12], ep[1]["obs"]["map"])
    # the two worlds differ, so a mixed stack would have shown above
    assert not np.array_equal(d.episodes[0][0][0]["obs"]["map"], d.episodes[1][0][0]["obs"]["map"])


def test_replay_matches_the_acting_stacker():
    core = small_core(num_worlds=3, seed=4, battery_factor=0.3)
    rp = rc.Replay(3 * 64, 3, V, 3, 1, 0.9, 0.5)
    d = Driver(core, rp)
    rng = np.random.default_rng(1)
    for _ in range(20):
        d.step(rng.integers(0, 4, 3), ended=(core.battery <= 1))
        maps, extras = rp._frames(d.slot)
        smaps, sextras = d.stacker.get()
        np.testing.assert_array_equal(maps, smaps)
        np.testing.assert_allclose(extras, sextras, atol=1e-3)


def sample_all(rp, rng, n=64, draws=40, beta=0.4):
    out = [rp.sample(n, beta, rng) for _ in range(draws)]
    return out


def check_samples(d, rp, samples, n_step, gamma):
    for slot, (m, e), a, ret, (nm, ne), boot, weight in samples:
        assert m.shape == (len(slot), 12, V, V) and nm.shape == m.shape and e.shape == (len(slot), 40)
        assert a.dtype == np.int64 and ret.shape == boot.shape == weight.shape == (len(slot),)
        assert (weight > 0).all() and weight.max() == pytest.approx(1.0)
        for i, s in enumerate(slot):
            w, ep, t = d.where[int(s)]
            rec = d.episodes[w][ep][t]
            assert rec["reward"] is not None, "sampled a frame with no transition yet"
            assert a[i] == rec["action"]
            want_ret, want_boot, (nw, nep, nt) = d.expected_transition(s, n_step, gamma)
            assert ret[i] == pytest.approx(want_ret, rel=1e-5, abs=1e-5)
            assert boot[i] == pytest.approx(want_boot, rel=1e-5)
            assert_stack(m[i], e[i], expected_stack(d.frames_of(w, ep), t, 3))
            assert_stack(nm[i], ne[i], expected_stack(d.frames_of(nw, nep), nt, 3))


def test_replay_sample_one_step_next_state_is_the_next_frame():
    core = small_core(num_worlds=2, seed=1)
    rp = rc.Replay(2 * 64, 2, V, 3, 1, 0.9, 0.5)
    d = Driver(core, rp)
    rng = np.random.default_rng(0)
    for _ in range(6):
        d.step(rng.integers(0, 4, 2), reward=rng.normal(size=2), terminal=np.zeros(2, bool))
    samples = sample_all(rp, rng)
    check_samples(d, rp, samples, 1, 0.9)


def test_replay_sample_last_transitions_and_peb():
    """Truncated (PEB, terminal False) vs terminated endings; the last transition of an episode
    bootstraps from the episode's final frame, never from the next episode's first frame."""
    core = small_core(num_worlds=2, seed=2)
    g = 0.9
    rp = rc.Replay(2 * 64, 2, V, 3, 1, g, 0.5)
    d = Driver(core, rp)
    # world 0 is truncated after 3 steps (terminal False), world 1 terminated after 3 steps
    rewards = [[1.0, 10.0], [2.0, 20.0], [3.0, 30.0]]
    for j, r in enumerate(rewards):
        last = j == 2
        d.step([1, 3], reward=r, terminal=[False, last], ended=[last, last])
    d.step([0, 2], reward=[7.0, 70.0], terminal=[False, False])  # the next episodes' first transitions
    d.step([0, 2], reward=[8.0, 80.0], terminal=[False, False])
    for w, term in ((0, False), (1, True)):
        ep = d.episodes[w][0]
        assert len(ep) == 4 and ep[-1]["final"]
        assert rp.tree.tree[rp.tree.size + ep[-1]["slot"]] == 0  # the final frame is not a transition
        ret, (nm, ne), boot = sample_slot(rp, ep[2]["slot"])
        assert ret == pytest.approx(rewards[2][w])
        assert boot == pytest.approx(0.0 if term else g)
        assert_stack(nm, ne, expected_stack(d.frames_of(w, 0), 3, 3))  # the final frame
        assert ne[0] == pytest.approx(122 / 125, abs=1e-3)  # not the next episode's (battery 1)


def sample_slot(rp, slot, n=64):
    """sample() (priorities untouched: the n-step walk reads them) and keep the draw of `slot`:
    (ret, (next maps, next extras), bootstrap) of that transition."""
    idx, _, _, ret, (nm, ne), boot, _ = rp.sample(n, 0.4, np.random.default_rng(0))
    hit = np.flatnonzero(idx == slot)
    assert len(hit), "the slot was not sampled"
    i = hit[0]
    return ret[i], (nm[i], ne[i]), boot[i]


def test_replay_n_step_return_full_window():
    core = small_core(num_worlds=1, seed=0)
    g = 0.5
    rp = rc.Replay(64, 1, V, 3, 3, g, 0.5)
    d = Driver(core, rp)
    rs = [1.0, 2.0, 4.0, 8.0, 16.0, 32.0]
    for r in rs:
        d.step([1], reward=[r], terminal=[False])
    ep = d.episodes[0][0]
    ret, (nm, ne), boot = sample_slot(rp, ep[0]["slot"])
    assert ret == pytest.approx(1 + 0.5 * 2 + 0.25 * 4)  # r0 + g r1 + g^2 r2
    assert boot == pytest.approx(g ** 3)
    assert_stack(nm, ne, expected_stack(d.frames_of(0, 0), 3, 3))  # s_{t+3}


def test_replay_n_step_return_stops_at_the_episode_end():
    core = small_core(num_worlds=1, seed=0)
    g = 0.5
    rp = rc.Replay(64, 1, V, 3, 3, g, 0.5)
    d = Driver(core, rp)
    d.step([1], reward=[1.0], terminal=[False])
    d.step([1], reward=[2.0], terminal=[True], ended=[True])  # terminated inside the window
    d.step([1], reward=[100.0], terminal=[False])  # next episode: must not leak in
    d.step([1], reward=[200.0], terminal=[False])
    ep = d.episodes[0][0]
    ret, (nm, ne), boot = sample_slot(rp, ep[0]["slot"])
    assert ret == pytest.approx(1 + 0.5 * 2)
    assert boot == 0
    assert_stack(nm, ne, expected_stack(d.frames_of(0, 0), 2, 3))
    # truncated (PEB) inside the window: bootstrap g^2 from the final frame
    d2 = Driver(small_core(num_worlds=1, seed=0), rc.Replay(64, 1, V, 3, 3, g, 0.5))
    d2.step([1], reward=[1.0], terminal=[False])
    d2.step([1], reward=[2.0], terminal=[False], ended=[True])
    d2.step([1], reward=[100.0], terminal=[False])
    d2.step([1], reward=[200.0], terminal=[False])
    ret, (nm, ne), boot = sample_slot(d2.replay, d2.episodes[0][0][0]["slot"])
    assert ret == pytest.approx(1 + 0.5 * 2)
    assert boot == pytest.approx(g ** 2)
    assert_stack(nm, ne, expected_stack(d2.frames_of(0, 0), 2, 3))


def test_replay_n_step_return_stops_at_the_newest_frame():
    core = small_core(num_worlds=1, seed=0)
    g = 0.5
    rp = rc.Replay(64, 1, V, 3, 3, g, 0.5)
    d = Driver(core, rp)
    d.step([1], reward=[1.0], terminal=[False])
    d.step([3], reward=[2.0], terminal=[False])  # frame 2 is the newest: no reward yet
    ret, (nm, ne), boot = sample_slot(rp, d.episodes[0][0][0]["slot"])
    assert ret == pytest.approx(2.0)
    assert boot == pytest.approx(g ** 2)
    assert_stack(nm, ne, expected_stack(d.frames_of(0, 0), 2, 3))


def test_replay_never_samples_slots_without_successor():
    core = small_core(num_worlds=3, seed=5, battery_factor=0.3)
    rp = rc.Replay(3 * 64, 3, V, 3, 1, 0.9, 0.5)
    d = Driver(core, rp)
    rng = np.random.default_rng(2)
    newest = set()
    for _step in range(12):
        d.step(rng.integers(0, 4, 3), ended=(core.battery <= 1))
        newest = {int(s) for s in d.slot}
        finals = {r["slot"] for w in range(3) for ep in d.episodes[w] for r in ep if r.get("final")}
        for _ in range(5):
            slot = rp.sample(32, 0.4, rng)[0]
            assert not (set(slot.tolist()) & newest)
            assert not (set(slot.tolist()) & finals)
            for s in slot:
                w, e, t = d.where[int(s)]
                assert d.episodes[w][e][t]["reward"] is not None
    leaves = rp.tree.tree[rp.tree.size:]
    assert all(leaves[s] == 0 for s in newest)


def test_replay_ring_wrap_keeps_samples_consistent():
    core = small_core(num_worlds=2, seed=6, battery_factor=0.4)
    rp = rc.Replay(2 * 16, 2, V, 3, 1, 0.9, 0.5)
    d = Driver(core, rp)
    rng = np.random.default_rng(3)
    for _ in range(45):  # about three times around each 16-slot segment
        d.step(rng.integers(0, 4, 2), ended=(core.battery <= 1))
    # slots whose stack reaches into overwritten frames must not be sampled: checked by content
    check_samples(d, rp, sample_all(rp, rng, n=32, draws=20), 1, 0.9)


def test_replay_ring_wrap_sampled_states_are_current():
    """Like the test above, but checks only the sampled state (not the next state): every
    sampled stack is that of the frame now in the slot, within its episode."""
    core = small_core(num_worlds=2, seed=6, battery_factor=0.4)
    rp = rc.Replay(2 * 16, 2, V, 3, 1, 0.9, 0.5)
    d = Driver(core, rp)
    rng = np.random.default_rng(3)
    for _ in range(45):
        d.step(rng.integers(0, 4, 2), ended=(core.battery <= 1))
    for slot, (m, e), a, *_ in sample_all(rp, rng, n=32, draws=20):
        for i, s in enumerate(slot):
            w, ep, t = d.where[int(s)]
            # the stack must not reach frames that were overwritten
            for j in range(max(0, t - 2), t + 1):
                assert d.where.get(d.episodes[w][ep][j]["slot"]) == (w, ep, j)
            assert a[i] == d.episodes[w][ep][t]["action"]
            assert_stack(m[i], e[i], expected_stack(d.frames_of(w, ep), t, 3))


def test_replay_priorities_and_weights():
    core = small_core(num_worlds=1, seed=0)
    rp = rc.Replay(64, 1, V, 3, 1, 0.9, 0.5)
    d = Driver(core, rp)
    for _ in range(4):
        d.step([1], reward=[0.0], terminal=[False])
    slots = [r["slot"] for r in d.episodes[0][0][:4]]
    leaves = rp.tree.tree[rp.tree.size:]
    assert all(leaves[s] == pytest.approx(1.0) for s in slots)  # max priority 1 ** alpha
    rp.update_priorities(np.array(slots[:2]), np.array([3.0, -8.0]))
    assert leaves[slots[0]] == pytest.approx((3 + 1e-6) ** 0.5)
    assert leaves[slots[1]] == pytest.approx((8 + 1e-6) ** 0.5)
    assert rp.max_priority == pytest.approx(8 + 1e-6)
    d.step([1], reward=[0.0], terminal=[False])  # a new complete transition gets max priority
    assert leaves[slots[-1] + 1] == pytest.approx((8 + 1e-6) ** 0.5)
    # importance weights (N P)^-beta / max with N = sampleable slots
    slot, *_, weight = rp.sample(200, 1.0, np.random.default_rng(0))
    p = leaves[slot] / leaves.sum()
    want = (5 * p) ** -1.0
    np.testing.assert_allclose(weight, want / want.max(), rtol=1e-6)


def test_replay_bytes_per_transition_is_compact():
    rp = rc.Replay(2 * 512, 2, V, 3, 1, 0.99, 0.5)
    per = rp.bytes_per_transition()
    assert per < 2000
    size = rp.cap * rp.worlds
    actual = sum(v.nbytes for v in vars(rp).values() if isinstance(v, np.ndarray) and v.shape[:1] == (size,))
    assert per == actual / size + rp.tree.tree.nbytes / size  # the reported figure is what is stored


def test_replay_single_frame_stack():
    core = small_core(num_worlds=2, seed=0)
    rp = rc.Replay(2 * 64, 2, V, 1, 1, 0.9, 0.5)
    d = Driver(core, rp, frames=1)
    d.step([1, 2])
    maps, extras = rp._frames(d.slot)
    assert maps.shape == (2, 4, V, V) and extras.shape == (2, 14)


# ============================================================================ 5. main() smoke run
def small_args(tmp_path, **kw):
    base = dict(run_name="t", total_steps=600, learning_starts=200, hidden=16, num_envs=4, buffer_size=4096,
                eval_every=400, eval_maps=4, save_every=400, export=str(tmp_path / "m.pt"),
                stage_steps_scale=0.001, replay_ratio=2.0)  # 25 updates: a quick run
    return rc.Args(**{**base, **kw})


def test_main_smoke_resume_export_and_load(tmp_path, monkeypatch, restore_sigint):
    monkeypatch.chdir(tmp_path)
    torch.set_num_threads(2)
    rc.main(small_args(tmp_path))
    ckpt = tmp_path / "runs" / "t" / "checkpoint.pt"
    assert ckpt.exists() and (tmp_path / "m.pt").exists() and (tmp_path / "m.json").exists()
    assert not (tmp_path / "runs" / "t" / "checkpoint.pt.tmp").exists()
    assert any(p.name.startswith("events.out.tfevents") for p in (tmp_path / "runs" / "t").iterdir())
    state = torch.load(ckpt, map_location="cpu", weights_only=False)
    assert state["global_step"] == 600 and state["stage"] == 0
    info = json.loads((tmp_path / "m.json").read_text())
    assert info["global_step"] == 600 and info["args"]["hidden"] == 16

    blob = torch.load(tmp_path / "m.pt", map_location="cpu", weights_only=False)
    assert blob["frames"] == 3 and blob["hidden"] == 16
    assert all(v.dtype == torch.float16 for v in blob["weights"].values())
    assert not any("sigma" in k or "eps" in k for k in blob["weights"])
    for k, v in blob["weights"].items():  # the mean weights of the trained network
        assert torch.allclose(v.float(), state["model"][k], atol=1e-2, rtol=1e-2)

    rc.main(small_args(tmp_path, resume=True, total_steps=800))
    state2 = torch.load(ckpt, map_location="cpu", weights_only=False)
    assert state2["global_step"] == 800 > state["global_step"]
    assert json.loads((tmp_path / "m.json").read_text())["global_step"] == 800
    assert any(not torch.equal(state2["model"][k], state["model"][k]) for k in state["model"])  # it learned on

    q = rc.load_policy(str(tmp_path / "m.pt"))
    assert not q.training
    assert all(not m.eps_in.any() and not m.eps_out.any() for m in q.modules() if isinstance(m, rc.NoisyLinear))
    maps = torch.randint(0, 256, (2, 12, V, V), dtype=torch.uint8)
    extras = torch.rand(2, 40)
    with torch.no_grad():
        y1, y2 = q(maps, extras), q(maps, extras)
    assert torch.equal(y1, y2)
    q_ck = rc.load_policy(str(ckpt))  # a training checkpoint loads too (noise off)
    with torch.no_grad():
        assert torch.allclose(q_ck(maps, extras), y1, atol=5e-2, rtol=5e-2)

    # TensorBoard: CleanRL's episode charts and the held-out evaluation were logged
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    tags = set()
    for p in (tmp_path / "runs" / "t").glob("events.out.tfevents*"):
        acc = EventAccumulator(str(p))
        acc.Reload()
        tags |= set(acc.Tags()["scalars"])
    assert {"charts/episodic_return", "charts/episodic_length", "eval/overlap", "eval/completion",
            "eval/heuristic_share"} <= tags

    # init_from: a new run starts from the exported mean weights (no updates: learning never starts)
    weights = torch.load(tmp_path / "m.pt", map_location="cpu", weights_only=False)["weights"]
    rc.main(small_args(tmp_path, run_name="init", init_from=str(tmp_path / "m.pt"), total_steps=40,
                       learning_starts=10 ** 6, eval_every=0, save_every=0, export=str(tmp_path / "init.pt")))
    model = torch.load(tmp_path / "runs" / "init" / "checkpoint.pt", map_location="cpu", weights_only=False)["model"]
    for k, v in weights.items():
        assert torch.equal(model[k], v.float()), k
    assert torch.allclose(model["value.0.weight_sigma"], torch.full_like(model["value.0.weight_sigma"],
                                                                         0.5 / np.sqrt(5224)))


def test_main_curriculum_moves_to_the_next_stage(tmp_path, monkeypatch, restore_sigint):
    """stage_steps_scale 0.001: stage fi1 ends at 1000 steps; the run goes on in fi2 (10x10)."""
    monkeypatch.chdir(tmp_path)
    rc.main(small_args(tmp_path, run_name="c", total_steps=1040, learning_starts=10 ** 6, eval_every=0,
                       save_every=0))
    state = torch.load(tmp_path / "runs" / "c" / "checkpoint.pt", map_location="cpu", weights_only=False)
    assert state["global_step"] == 1040 and state["stage"] == 1
    assert json.loads((tmp_path / "m.json").read_text())["stage"] == "fi2"


def test_main_rejects_a_buffer_too_small(tmp_path, monkeypatch, restore_sigint):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match="buffer_size"):
        rc.main(small_args(tmp_path, buffer_size=64 * 4 - 1))


def test_resume_without_checkpoint_is_a_value_error(tmp_path, monkeypatch, restore_sigint):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match="nothing to resume"):
        rc.main(small_args(tmp_path, resume=True, run_name="none"))


def test_load_policy_missing_file(tmp_path):
    with pytest.raises(ValueError) as e:
        rc.load_policy(str(tmp_path / "nope.pt"))
    assert "\n" not in str(e.value) and "nope.pt" in str(e.value)


@pytest.mark.parametrize("kind", ["empty", "dict", "npz", "wrong_weights"])
def test_load_policy_rejects_non_models(tmp_path, kind):
    path = tmp_path / "x.pt"
    if kind == "empty":
        path.write_bytes(b"")
    elif kind == "dict":
        torch.save({"foo": 1}, path)
    elif kind == "npz":
        with open(path, "wb") as f:
            np.savez(f, a=np.zeros(3))
    else:
        torch.save({"weights": {"x": torch.zeros(1)}, "frames": 3, "hidden": 16}, path)
    with pytest.raises(ValueError) as e:
        rc.load_policy(str(path))
    assert "\n" not in str(e.value) and str(path) in str(e.value)


@pytest.mark.parametrize("kind", ["text", "tensor", "directory"])
def test_load_policy_rejects_other_files(tmp_path, kind):
    path = tmp_path / "x.pt"
    if kind == "text":
        path.write_text("hello world\n")
    elif kind == "tensor":
        torch.save(torch.zeros(3), path)
    else:
        path.mkdir()
    with pytest.raises(ValueError) as e:
        rc.load_policy(str(path))
    assert "\n" not in str(e.value)


def test_stages_with_two_agents_rejected(tmp_path, monkeypatch, restore_sigint):
    monkeypatch.chdir(tmp_path)
    cfg = tmp_path / "stages.yaml"
    cfg.write_text("s1:\n  size: 5\n  number_agents: 2\n  base_steps: 100\n")
    with pytest.raises(ValueError, match="single-agent"):
        rc.main(small_args(tmp_path, stages=str(cfg)))
    assert not (tmp_path / "runs").exists()


def test_default_curriculum():
    stages = rc.load_stages(rc.Args())
    assert [s.name for s in stages] == [f"fi{i}" for i in range(1, 7)] + [f"camera{i}" for i in range(1, 7)]
    assert sum(s.base_steps for s in stages) == 2 * 31_000_000
    assert [s.size for s in stages[:6]] == [5, 10, 15, 20, 25, 30]
    assert all(s.sensor == "full" and s.random_coverage for s in stages[:6])
    assert all(s.sensor == "camera" and not s.random_coverage for s in stages[6:])
    assert len(rc.load_stages(rc.Args(camera_stages=False))) == 6


def test_evaluate_policy_per_episode():
    scen = [s for s in gw.load_dataset(os.path.join(os.path.dirname(rc.__file__), "maps", "cpp_eval.npz"))
            if s.obstacles.shape[0] <= 6][:3]
    torch.manual_seed(0)
    q = rc.QNetwork(3, V, 16, 0.5)
    m1 = rc.evaluate_policy(q, scen, 3, "full", 3)
    m2 = rc.evaluate_policy(q, scen, 3, "full", 3)
    for k in ("overlap", "completed", "steps", "truncated", "heuristic_steps"):
        assert len(m1[k]) == 3, k
        np.testing.assert_array_equal(m1[k], m2[k])  # noise off, fixed maps and starts: deterministic
    assert (m1["completed"] ^ m1["truncated"]).all()  # every episode ran to its end, one way
    assert ((0 <= m1["heuristic_steps"]) & (m1["heuristic_steps"] <= m1["steps"])).all()
    alone = rc.evaluate_policy(q, scen, 3, "full", 3, heuristic=False)
    assert not alone["heuristic_steps"].any()


# ============================================================================ 6. stuck()
def test_stuck_conditions_by_hand():
    since_new = np.array([10, 11, 11, 5, 4, 5, 6, 0, 30])
    moved = np.array([5, 5, 0, 2, 0, 3, 1, 0, 9])
    size = np.array([10, 10, 10, 10, 10, 10, 10, 10, 30])
    #   10 > 10 no, 5 cells moved -> no; 11 > 10 -> yes (condition 3); 5 steps and <= 2 moved -> yes
    #   4 steps -> too early; 3 moved -> no; 6 steps, 1 moved -> yes; fresh -> no; 30 == M -> no
    want = [False, True, True, True, False, False, True, False, False]
    assert gw.stuck(since_new, moved, size).tolist() == want


def test_stage_smaller_than_the_eval_maps_still_evaluates(tmp_path, monkeypatch, restore_sigint):
    monkeypatch.chdir(tmp_path)
    cfg = tmp_path / "stages.yaml"
    cfg.write_text("tiny:\n  size: 4\n  min_size: 3\n  random_size: true\n  base_steps: 400\n")
    rc.main(small_args(tmp_path, stages=str(cfg), stage_steps_scale=1.0, total_steps=400,
                       eval_every=200, eval_maps=2))  # evaluates on the smallest cpp_eval maps (5x5)
    state = torch.load(tmp_path / "runs" / "t" / "checkpoint.pt", weights_only=False)
    assert state["global_step"] >= 400


# ============================================================================ 6. DQfD margin loss
def test_large_margin_loss_by_hand():
    q_all = torch.tensor([[1.0, 2.0, 0.0, 0.0], [0.0, 0.0, 0.0, 3.0]])
    # row 0: max(1, 2 + .8, .8, .8) - Q(a_E = 0) = 2.8 - 1 = 1.8; row 1: max(.8, .8, .8, 3) - 3 = 0
    assert rc.large_margin_loss(q_all, torch.tensor([0, 3]), 0.8).item() == pytest.approx(0.9)
    assert rc.large_margin_loss(q_all, torch.tensor([0, -1]), 0.8).item() == pytest.approx(1.8)  # unlabelled
    assert rc.large_margin_loss(q_all, torch.tensor([-1, -1]), 0.8).item() == 0.0


def test_replay_labels_skip_wait():
    rp = rc.Replay(64, 2, 9, 3, 1, 0.99, 0.5)
    slot = np.array([0, 32])
    rp.set_transition(slot, np.array([1, 2]), np.zeros(2), np.zeros(2, bool), np.array([3, gw.WAIT]))
    assert rp.label[0] == 3 and rp.label[32] == -1
    rp.set_transition(slot, np.array([1, 2]), np.zeros(2), np.zeros(2, bool))  # no labels: none kept
    assert (rp.label[slot] == -1).all()


def test_margin_loss_teaches_the_heuristic_actions():
    """A small network trained on the margin loss alone picks the heuristic's move in every state."""
    torch.manual_seed(0)
    core = gw.GridWorldCore(gw.EnvConfig(size=5, number_obstacles=3), 8, seed=3)
    core.reset()
    stack = rc.Stacker(8, 3, core.V)
    stack.push(gw.observe(core), np.ones(8, bool))
    label = torch.from_numpy(gw.heuristic_actions(core, False)[:, 0].astype(np.int64))
    q = rc.QNetwork(3, V, 16, 0.0)
    optimizer = torch.optim.Adam(q.parameters(), lr=1e-3)
    maps, extras = gw.to_torch(*stack.get())
    for _ in range(300):
        loss = rc.large_margin_loss(q(maps, extras), label, 0.8)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    assert loss.item() < 1e-3
    assert torch.equal(q(maps, extras).argmax(1), label)


def test_main_with_margin_loss_logs_it(tmp_path, monkeypatch, restore_sigint):
    monkeypatch.chdir(tmp_path)
    rc.main(small_args(tmp_path, run_name="m", total_steps=1200, eval_every=0, save_every=0, margin_loss=1.0))
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    acc = EventAccumulator(str(next((tmp_path / "runs" / "m").glob("events.out.tfevents*"))))
    acc.Reload()
    assert "losses/margin_loss" in acc.Tags()["scalars"]


def test_heuristic_fallback_finishes_maps_for_a_looping_policy():
    """A policy that always moves North never covers a map alone; with the fallback, which keeps
    control one new cell longer each time the agent is stuck, every map is completed."""
    scen = [s for s in gw.load_dataset(os.path.join(os.path.dirname(rc.__file__), "maps", "cpp_eval.npz"))
            if s.obstacles.shape[0] in (8, 12)][::25]
    q = rc.QNetwork(3, V, 16, 0.0)
    with torch.no_grad():
        for p in q.parameters():
            p.zero_()
        q.advantage[-1].bias_mu.copy_(torch.tensor([1.0, 0.0, 0.0, 0.0]))  # always North
    alone = rc.evaluate_policy(q, scen, 3, heuristic=False)
    assert not alone["completed"].any()
    helped = rc.evaluate_policy(q, scen, 3)
    assert helped["completed"].all() and not helped["truncated"].any()
    assert (helped["heuristic_steps"] > 0).all()
    assert (helped["heuristic_steps"] < helped["steps"]).all()  # the agent still acts in between


def test_demonstration_steps_let_the_heuristic_act(tmp_path, monkeypatch, restore_sigint):
    """With demonstration_steps beyond the run, the heuristic acts every episode (none is
    solved by the agent alone), although learning has started."""
    monkeypatch.chdir(tmp_path)
    rc.main(small_args(tmp_path, run_name="d", total_steps=1200, learning_starts=200, eval_every=0,
                       save_every=0, demonstration_steps=10 ** 6, margin_loss=1.0, partial_reset=False))
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    acc = EventAccumulator(str(next((tmp_path / "runs" / "d").glob("events.out.tfevents*"))))
    acc.Reload()
    alone = [e.value for e in acc.Scalars("charts/solved_alone")]
    assert len(alone) > 5 and not any(alone)
    assert "losses/td_loss" in acc.Tags()["scalars"]  # and it learned meanwhile


def test_evaluate_policy_counts_each_worlds_own_steps():
    """Worlds that finish early wait for the others; their steps stop at their own end: an
    empty map swept alone takes as many steps as the heuristic-only walk of the same map."""
    small = gw.Scenario(np.zeros((4, 4), bool), np.array([[0, 0]]))
    large = gw.Scenario(np.zeros((12, 12), bool), np.array([[0, 0]]))
    q = rc.QNetwork(3, V, 16, 0.0)
    both = rc.evaluate_policy(q, [small, large], 3)
    alone = rc.evaluate_policy(q, [small], 3)
    assert both["completed"].all()
    assert both["steps"][0] == alone["steps"][0] < both["steps"][1]
    assert both["time_save"][0] == pytest.approx(alone["steps"][0] / 15)  # 15 cells to cover
    assert both["rho"][0] == pytest.approx(alone["steps"][0] / 16)


@pytest.mark.parametrize("dead_ends, far_first", [(True, False), (False, False), (True, True)])
def test_teacher_and_fallback_use_the_dead_ends_flag(tmp_path, monkeypatch, restore_sigint, heuristic_ties,
                                                     dead_ends, far_first):
    """Every heuristic call of training and of its evaluations breaks ties as --heuristic-dead-ends and
    --heuristic-far-first say."""
    monkeypatch.chdir(tmp_path)
    rc.main(small_args(tmp_path, total_steps=300, learning_starts=100, save_every=0, eval_every=200,
                       margin_loss=1.0, heuristic_dead_ends=dead_ends, heuristic_far_first=far_first))
    assert len(heuristic_ties) > 50 and set(heuristic_ties) == {(dead_ends, far_first)}


# ============================================================================ 7. drifts fixed
def test_losses_are_logged_once_per_1000_steps(tmp_path, monkeypatch, restore_sigint):
    """Four updates a step (batch 8, replay ratio 8, 4 worlds): still one TD-loss point per 1000 steps."""
    monkeypatch.chdir(tmp_path)
    rc.main(small_args(tmp_path, run_name="l", total_steps=1040, learning_starts=960, batch_size=8, replay_ratio=8.0,
                       eval_every=0, save_every=0))
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    acc = EventAccumulator(str(next((tmp_path / "runs" / "l").glob("events.out.tfevents*"))))
    acc.Reload()
    assert [e.step for e in acc.Scalars("losses/td_loss")] == [1000]
    assert [e.step for e in acc.Scalars("losses/q_values")] == [1000]


def test_a_heuristic_without_a_target_leaves_the_agent_its_move(tmp_path, monkeypatch, restore_sigint):
    """When the teacher answers WAIT (no target), the agent's own move is taken and stored: WAIT is no
    action to learn (Q has four outputs), as rainbow_marl does."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(gw, "heuristic_actions", lambda core, *a, **k: np.full((core.B, core.N), gw.WAIT))
    made = []

    class Recorded(rc.Replay):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made.append(self)

    monkeypatch.setattr(rc, "Replay", Recorded)
    rc.main(small_args(tmp_path, total_steps=400, learning_starts=200, imitation=1.0, margin_loss=1.0,
                       eval_every=0, save_every=0))
    stored = made[0].action[made[0].tree.tree[made[0].tree.size:][:len(made[0].action)] > 0]
    assert len(stored) > 50 and (stored < gw.WAIT).all()
    assert (made[0].label == -1).all()  # and no WAIT label to imitate

"""Observation layouts and action decoding, with hand-computed values."""

import math

import jax.numpy as jnp
import numpy as np
from conftest import make_state

from kx.sim import observe
from kx.sim.types import KeepAwayConfig

CFG = KeepAwayConfig()
DIAG = 19 * math.sqrt(2)


def test_fixed_obs_hand_computed():
    # K1 (holder) at (5,5); teammates (8,5) at 3 and (5,9) at 4; takers (5,7) at 2 and (9,9) at sqrt(32)
    s = make_state([(5, 5), (8, 5), (5, 9)], [(9, 9), (5, 7)], holder=0)
    obs = np.asarray(observe.fixed_obs(s, CFG))
    expect = np.array([
        math.hypot(4.5, 4.5), 3, 4, 2, math.sqrt(32),  # dist(K1,C), dist(K1,K2), dist(K1,K3), dist(K1,T1/T2)
        math.hypot(1.5, 4.5), math.hypot(4.5, 0.5),  # dist(K2,C), dist(K3,C)
        math.hypot(4.5, 2.5), math.hypot(0.5, 0.5),  # dist(T1,C), dist(T2,C)
        math.hypot(3, 2), 2,  # min_j dist(K2,Tj), min_j dist(K3,Tj)
    ]) / DIAG
    angles = np.array([0.25, 0.0])  # K2 east vs T2 north-east: 45 deg; K3 north, T1 north: 0
    np.testing.assert_allclose(obs, np.concatenate([expect, angles]), rtol=1e-5, atol=1e-6)
    assert obs.shape == (13,)


def test_full_obs_sizes_and_3v2_equals_fixed():
    s = make_state([(5, 5), (8, 5), (5, 9)], [(9, 9), (5, 7)], holder=0)
    np.testing.assert_allclose(observe.full_obs(s, CFG), observe.fixed_obs(s, CFG))
    for task, n in (("3v2", 13), ("4v3", 19), ("5v3", 23), ("6v4", 29)):
        cfg = KeepAwayConfig.from_task(task)
        k, t = cfg.n_keepers, cfg.n_takers
        st = make_state([(2 * i, 3) for i in range(k)], [(2 * j, 15) for j in range(t)], holder=1)
        assert observe.full_obs(st, cfg).shape == (n,) == (observe.n_inputs("full", cfg),)
        assert observe.fixed_obs(st, cfg).shape == (13,)


def test_orders_and_ranked_decoding():
    s = make_state([(5, 5), (8, 5), (5, 9)], [(9, 9), (5, 7)], holder=0)
    assert np.asarray(observe.teammate_order(s, CFG)).tolist() == [0, 1, 2]
    assert np.asarray(observe.taker_order(s, CFG)).tolist() == [1, 0]
    dec = lambda o: int(observe.decode_ranked(jnp.asarray(o), s, CFG))  # noqa: E731
    assert dec([0.1, 0.5, 0.2]) == 1 and dec([0.1, 0.2, 0.5]) == 2 and dec([0.5, 0.5, 0.0]) == 0
    # holder 2: its nearest teammate is keeper 0 at distance 4 (keeper 1 at 5)
    s2 = make_state([(5, 5), (8, 5), (5, 9)], [(9, 9), (5, 7)], holder=2)
    assert np.asarray(observe.teammate_order(s2, CFG)).tolist() == [2, 0, 1]
    assert int(observe.decode_ranked(jnp.asarray([0.0, 1.0, 0.0]), s2, CFG)) == 0


def test_bev_hand_computed():
    s = make_state([(2, 2), (5, 2), (2, 6)], [(4, 4), (10, 10)], holder=0)
    img = np.asarray(observe.bev_obs(s, CFG)).reshape(20, 20)  # [y, x]
    assert img[2, 2] == 1.0 and img[2, 5] == 1.0 and img[6, 2] == 1.0  # keepers
    assert img[10, 10] == -1.0 and img[4, 4] == -1.0  # takers (the second also on a taker path: clipped)
    np.testing.assert_allclose([img[2, 3], img[2, 4], img[3, 2], img[4, 2], img[5, 2]], 0.3)  # to teammates
    np.testing.assert_allclose(img[3, 3], -0.6)  # on the paths to both takers
    np.testing.assert_allclose([img[5, 5], img[9, 9]], -0.3)  # on the path to the far taker
    assert np.count_nonzero(img) == 5 + 5 + 6  # agents, teammate paths, taker path cells (3,3)..(9,9) but 4,4
    assert observe.bev_obs(s, CFG).shape == (400,)


def test_bev_decoding():
    s = make_state([(2, 2), (5, 2), (2, 6)], [(4, 4), (10, 10)], holder=0)
    out = jnp.zeros(400)
    assert int(observe.decode_bev(out, s, CFG)) == 0  # ties go to hold
    assert int(observe.decode_bev(out.at[2 + 20 * 6].set(1.0), s, CFG)) == 2
    assert int(observe.decode_bev(out.at[2 + 20 * 2].set(2.0).at[5 + 20 * 2].set(1.0), s, CFG)) == 0
    # literal: the layer's maximum at (6, 3) is nearest keeper 1 at (5, 2)
    assert int(observe.decode_bev(out.at[6 + 20 * 3].set(1.0), s, CFG, literal=True)) == 1
    assert int(observe.decode_bev(out.at[1 + 20 * 1].set(1.0), s, CFG, literal=True)) == 0

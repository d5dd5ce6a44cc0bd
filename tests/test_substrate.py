"""The HyperNEAT substrate: hand-set CPPNs give hand-computed weights, expression mask and biases, and the
batched query of a population equals each CPPN's own network evaluated link by link."""

import math
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from kx.hyperneat import substrate as sb
from kx.neat import network
from kx.neat.algorithm import NEAT
from kx.neat.checks import check_genome
from kx.neat.types import BIAS, EMPTY, HIDDEN, INPUT, OUTPUT, Genome, NEATConfig, NEATParams

OPTS = ("identity", "gaussian", "bipolar_sigmoid", "abs", "sine")
CFG = NEATConfig(n_inputs=4, n_outputs=3, population_size=12, max_nodes=8 + 6, max_conns=60, max_genes=30,
                 species_capacity=4, activation_options=OPTS, hidden_activation="gaussian",
                 output_activation="bipolar_sigmoid", random_hidden_activation=True)
X1, Y1, X2, Y2, B, O_W, O_E, O_B, H = range(9)


def bip(x):
    return 2.0 / (1.0 + math.exp(-4.9 * x)) - 1.0


def hand_genome(links, hidden_acts=()):
    """A CPPN genome from ``(src, dst, weight)`` triples (node ids: inputs 0-3, bias 4, outputs 5-7,
    hidden 8...), each hidden node with its activation name."""
    n, c = CFG.max_nodes, CFG.max_conns
    kind = [INPUT] * 4 + [BIAS] + [OUTPUT] * 3 + [HIDDEN] * len(hidden_acts)
    act = [0] * 5 + [OPTS.index("bipolar_sigmoid")] * 3 + [OPTS.index(a) for a in hidden_acts]
    pad = n - len(kind)
    cols = len(links)
    g = Genome(
        node_id=jnp.asarray(list(range(len(kind))) + [-1] * pad, jnp.int32),
        node_kind=jnp.asarray(kind + [EMPTY] * pad, jnp.int32),
        node_act=jnp.asarray(act + [0] * pad, jnp.int32),
        node_valid=jnp.asarray([True] * len(kind) + [False] * pad),
        conn_innov=jnp.asarray(list(range(cols)) + [-1] * (c - cols), jnp.int32),
        conn_src=jnp.asarray([s for s, _, _ in links] + [-1] * (c - cols), jnp.int32),
        conn_dst=jnp.asarray([d for _, d, _ in links] + [-1] * (c - cols), jnp.int32),
        conn_weight=jnp.asarray([w for _, _, w in links] + [0.0] * (c - cols), jnp.float32),
        conn_enabled=jnp.asarray([True] * cols + [False] * (c - cols)),
        conn_valid=jnp.asarray([True] * cols + [False] * (c - cols)),
    )
    assert check_genome(g, CFG) == []
    return g


def test_substrate_coordinates_and_link_order():
    s = sb.Substrate()
    xy = s.coordinates()
    # cell x + 20 y at ((2x + 1) / 20 - 1, (2y + 1) / 20 - 1): -0.95 .. 0.95 in steps of 0.1
    np.testing.assert_allclose(xy[0], [-0.95, -0.95], atol=1e-7)
    np.testing.assert_allclose(xy[19], [0.95, -0.95], atol=1e-7)
    np.testing.assert_allclose(xy[20], [-0.95, -0.85], atol=1e-7)
    np.testing.assert_allclose(xy[3 + 20 * 7], [-0.65, -0.25], atol=1e-6)
    q = s.queries()
    assert q.shape == (4, 160_000)
    # link o * 400 + i: from input cell i = (3, 7) to output cell o = (12, 0)
    np.testing.assert_allclose(q[:, 12 * 400 + 3 + 20 * 7], [-0.65, -0.25, 0.25, -0.95], atol=1e-6)
    d = sb.Substrate(distance_input=True).queries()
    assert d.shape == (5, 160_000)
    np.testing.assert_allclose(d[4, 12 * 400 + 3 + 20 * 7], math.hypot(0.9, 0.7), rtol=1e-6)
    with pytest.raises(ValueError, match="resolution"):
        sb.Substrate(resolution=1)


def test_a_hand_set_cppn_gives_hand_computed_weights_mask_and_biases():
    # weight: bip(2 * gauss(x1 - x2) - 1); expression: bip(y1 - y2 + 0.05) > 0, i.e. y1 >= y2 on the
    # grid; bias: bip(0.5 x2 + 0.25 y2 - 0.1), read at the node's own coordinates
    g = hand_genome([(X1, H, 1.0), (X2, H, -1.0), (H, O_W, 2.0), (B, O_W, -1.0),
                     (Y1, O_E, 1.0), (Y2, O_E, -1.0), (B, O_E, 0.05),
                     (X2, O_B, 0.5), (Y2, O_B, 0.25), (B, O_B, -0.1)], hidden_acts=("gaussian",))
    out = sb.build(jax.tree.map(lambda a: a[None], g), CFG, sb.Substrate())
    w, b = np.asarray(out["w"][0]), np.asarray(out["b"][0])
    assert w.shape == (400, 400) and b.shape == (400,)

    def coord(c):
        return (2 * (c % 20) + 1) / 20 - 1, (2 * (c // 20) + 1) / 20 - 1

    # a few links written out: input cell i -> output cell o
    # (0,0) -> (0,0): x1 = x2, y1 = y2 -> gauss 1 -> bip(1) * 5, expressed
    assert w[0, 0] == pytest.approx(5 * bip(1.0), abs=1e-5)
    assert w[0, 0] == pytest.approx(4.9261, abs=1e-4)
    # (5,3) -> (0,3): x1 - x2 = 0.5 -> gauss e^(-0.625) = 0.5353 -> bip(0.0706) = 0.1711 -> 0.8554
    assert w[0 + 20 * 3, 5 + 20 * 3] == pytest.approx(5 * bip(2 * math.exp(-2.5 * 0.25) - 1), abs=1e-5)
    assert w[0 + 20 * 3, 5 + 20 * 3] == pytest.approx(0.8554, abs=1e-3)
    # (5,2) -> (0,3): y1 < y2: not expressed
    assert w[0 + 20 * 3, 5 + 20 * 2] == 0.0
    # (5,4) -> (0,3): y1 > y2: expressed
    assert w[0 + 20 * 3, 5 + 20 * 4] == pytest.approx(w[0 + 20 * 3, 5 + 20 * 3], abs=1e-6)
    # every link by the formulas
    xy = np.array([coord(c) for c in range(400)])
    x1, y1 = xy[None, :, 0], xy[None, :, 1]  # input cell i on axis 1
    x2, y2 = xy[:, None, 0], xy[:, None, 1]  # output cell o on axis 0
    gauss = np.exp(-2.5 * (x1 - x2) ** 2)
    bipv = np.vectorize(bip)
    expect_w = np.where(bipv(y1 - y2 + 0.05) > 0, 5 * bipv(2 * gauss - 1), 0.0)
    np.testing.assert_allclose(w, expect_w, atol=2e-5)
    assert (w != 0).mean() == pytest.approx(210 / 400)  # y1 >= y2: (1 + ... + 20) / 20^2 of the pairs
    np.testing.assert_allclose(b, 5 * bipv(0.5 * xy[:, 0] + 0.25 * xy[:, 1] - 0.1), atol=2e-5)
    assert b[0] == pytest.approx(5 * bip(0.5 * -0.95 + 0.25 * -0.95 - 0.1), abs=1e-5)


def test_every_activation_and_a_chain_of_hidden_nodes():
    # a chain of hidden nodes sine -> abs -> identity into the weight output; the bias output reads the first two
    g = hand_genome([(X1, H, 2.0), (H, H + 1, -1.5), (Y1, H + 1, 0.5), (H + 1, H + 2, 0.7), (B, H + 2, 0.1),
                     (H + 2, O_W, 1.3), (X2, O_E, 1.0), (B, O_E, 0.5), (H, O_B, 1.0), (H + 1, O_B, -0.2)],
                    hidden_acts=("sine", "abs", "identity"))
    out = sb.build(jax.tree.map(lambda a: a[None], g), CFG, sb.Substrate())
    w, b = np.asarray(out["w"][0]), np.asarray(out["b"][0])
    for i, o in [(0, 0), (17, 233), (399, 5), (123, 321), (250, 250)]:
        x1, y1 = (2 * (i % 20) + 1) / 20 - 1, (2 * (i // 20) + 1) / 20 - 1
        x2 = (2 * (o % 20) + 1) / 20 - 1
        h1 = math.sin(2.0 * x1)
        h2 = abs(-1.5 * h1 + 0.5 * y1)
        h3 = 0.7 * h2 + 0.1
        expected = 5 * bip(1.3 * h3) if bip(x2 + 0.5) > 0 else 0.0
        assert w[o, i] == pytest.approx(expected, abs=2e-5), (i, o)
    for o in (0, 77, 399):
        x, y = (2 * (o % 20) + 1) / 20 - 1, (2 * (o // 20) + 1) / 20 - 1
        h1 = math.sin(2.0 * x)
        h2 = abs(-1.5 * h1 + 0.5 * y)
        assert b[o] == pytest.approx(5 * bip(h1 - 0.2 * h2), abs=2e-5)


@pytest.mark.slow  # ~10 s: the default suite checks the build bit for bit against the reference instead
def test_the_batched_query_equals_each_cppn_network_on_every_link():
    params = NEATParams(add_node_prob=0.4, add_link_prob=0.4, target_species=3, weight_init_range=3.0)
    neat = NEAT(CFG, params)
    state = neat.init(jax.random.key(0))
    for g in range(6):
        state, _ = neat.tell(jax.random.key(g + 1), state.population,
                             jax.random.uniform(jax.random.key(100 + g), (CFG.population_size,)), state)
    pop = state.population
    hidden = np.asarray(jax.vmap(lambda g: (g.node_kind == HIDDEN).sum())(pop))
    assert hidden.max() >= 2 and len(set(np.asarray(pop.node_act[:, 8:]).ravel().tolist())) >= 3
    s = sb.Substrate(distance_input=False)
    out = sb.build(pop, CFG, s)
    nets = neat.networks(pop)
    x = jnp.asarray(s.queries())
    for gi in range(CFG.population_size):
        o = np.asarray(network.forward(jax.tree.map(lambda a: a[gi], nets), x, CFG))
        w = np.where(o[1] > 0, 5 * np.clip(o[0], -1, 1), 0.0).reshape(400, 400)
        got = np.asarray(out["w"][gi])
        # the expression flips only where out_1 is within rounding of 0
        flip = (got != 0) != (w != 0)
        assert np.all(np.abs(o[1].reshape(400, 400)[flip]) < 1e-5)
        np.testing.assert_allclose(np.where(flip, 0, got), np.where(flip, 0, w), atol=2e-5)
        np.testing.assert_allclose(out["b"][gi], 5 * np.clip(np.diagonal(o[2].reshape(400, 400)), -1, 1), atol=2e-5)
    # the query keeping only the hidden rows the population uses (as the run loop builds it) gives the same
    # substrates as reals (a zero's sign at most differs: assert_array_equal counts -0.0 == 0.0)
    rows = sb.hidden_rows(pop, CFG)
    assert hidden.max() <= rows < CFG.n_hidden
    trimmed = sb.build(pop, CFG, s, rows=rows)
    for k in out:
        np.testing.assert_array_equal(np.asarray(trimmed[k]), np.asarray(out[k]), err_msg=k)


def _same_bits(got, ref, keep=slice(None)):
    for k in ("w", "b"):
        np.testing.assert_array_equal(np.asarray(got[k]).view(np.uint32), np.asarray(ref[k]).view(np.uint32)[keep],
                                      err_msg=k)


def _chains():
    """Ten hand-made CPPNs with chains of 0 to 6 hidden nodes (the capacity), each from most inputs and most
    hidden nodes before it, into most outputs, of every activation."""
    rng = np.random.default_rng(7)
    inputs, hidden_ids, outputs = [X1, Y1, X2, Y2, B], list(range(H, H + 6)), [O_W, O_E, O_B]
    counts = (0, 1, 2, 3, 4, 5, 6, 6, 3, 4)  # every segment of the capacity's widths (2, 4, 6)
    genomes = []
    for n_hidden in counts:
        hid = hidden_ids[:n_hidden]
        links = [(s, d, float(rng.normal(0, 2.0))) for d in hid for s in inputs + hid[:hid.index(d)]
                 if rng.random() < 0.8]
        links += [(s, d, float(rng.normal(0, 2.0))) for d in outputs for s in inputs + hid if rng.random() < 0.7]
        genomes.append(hand_genome(links, hidden_acts=tuple(str(a) for a in rng.choice(OPTS, n_hidden))))
    return jax.tree.map(lambda *a: jnp.stack(a), *genomes), np.array(counts)


def check_the_build_against_the_reference() -> None:
    pop, counts = _chains()
    s = sb.Substrate(distance_input=False)
    ref = sb.build(pop, CFG, s, reference=True)
    _same_bits(sb.build(pop, CFG, s), ref)  # every hidden row kept (the capacity, 6)
    few = counts <= 4  # 4 rows, as the run loop builds a population of at most 4
    four = jax.tree.map(lambda a: a[few], pop)
    _same_bits(sb.build(four, CFG, s, rows=4), ref, few)
    _same_bits(sb.build(four, CFG, s, rows=4, reference=True), ref, few)

    from kx.bench.policies import load_fixture

    trainer, trained, _ = load_fixture("hyperneat")
    enc = trainer.encoding
    ref = sb.build(trained, enc.neat_config, enc.substrate, reference=True)
    _same_bits(enc.policy_params(trained), ref)  # as the run loop builds it: 8 rows, over the devices
    rows, n_dev = sb.hidden_rows(trained, enc.neat_config), jax.local_device_count()
    devices = n_dev if len(trained.node_id) % n_dev == 0 else 1  # as policy_params splits it
    _same_bits(sb.build(trained, enc.neat_config, enc.substrate, devices, rows, reference=True), ref)


@pytest.mark.slow  # ~15 s cold: the build against the reference on trained genomes stays in the default suite
def test_the_build_is_bit_for_bit_the_reference_with_every_hidden_row_and_every_bias():
    """:func:`sb.build` against the reference, every bit, under the suite's flags (in this process); the slow set
    repeats it under XLA's default flags, where the run loop compiles (the test after this one)."""
    check_the_build_against_the_reference()


@pytest.mark.slow  # a process of its own compiling at XLA's default level: ~20 s on CI; the test above is the default
def test_the_build_is_bit_for_bit_the_reference_under_xla_default_flags():
    """:func:`sb.build` reads only the hidden rows each node's sum needs (2, 4, then ``rows``) and computes
    the bias output only on the diagonal: every bit of every weight and bias as the reference (every row,
    every output on every link, ``reference=True``; with 4 rows too, as before 2026-12-05), on hand-made
    chains of hidden nodes and on the trained 4v3 CPPNs of ``kx.bench policies``. In a process of its own,
    under XLA's default flags, which the run loop compiles with: there a sum over one row, which XLA fuses
    with the addition after it into one multiply-add, changed 507 of the chains' weights and 9 of the
    trained CPPNs' 60,000 biases, where the suite's flags fuse nothing of it (and the run-directory
    fixture, tests/test_run_dir_fixture.py, checks HyperNEAT's runs under those)."""
    env = {**os.environ, "XLA_FLAGS": ""}
    done = subprocess.run([sys.executable, __file__], env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0 and "the same bits" in done.stdout, done.stdout + done.stderr


if __name__ == "__main__":  # the check under XLA's default flags (the test above runs it so)
    from kx import runtime

    runtime.setup()
    check_the_build_against_the_reference()
    print("the same bits")

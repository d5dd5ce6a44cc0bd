"""CMA-ES as an encoding of the run loop: ``method = "cma_es"``, a fixed-topology network evolved by evosax.

Hansen's CMA-ES as evosax 0.3.2 implements it, with its default parameters (weights, learning rates,
damping), searching the flat parameter vector of a fixed network on the same observation layouts as
NEAT: ``fixed`` (13 inputs, 3 outputs, any team size) or ``full`` (4K + 2T - 3 inputs, K outputs). With
``cma_es.hidden = 0`` (the default) the network is linear, ``outputs = x W + b`` (42 values on the
fixed layout: 13 x 3 weights row-major by input, then 3 biases, the layout of
:func:`kx.sim.policies.linear_params`); with ``hidden = H`` it has one tanh layer of H units
(``W1 [in, H]``, ``b1 [H]``, ``W2 [H, out]``, ``b2 [out]``, in that order). The holder acts on the
largest output (ties to hold).

The population's parameter vectors go to the evaluator as one table ``[P, D]`` that every episode lane
shares, each lane carrying its row index (:mod:`kx.sim.evaluate`'s shared mode).

Config section ``cma_es``: ``sigma_init`` (the initial step size; the mean starts at zero) and
``hidden``. Its configs (``configs/cma_es_3v2.py`` ...) use population 50 and 60 generations, the
evaluation budget of the paper's NEAT source run (150 x 20 = 3000 individuals of 30 trials).
evosax minimises; kx hands it the negated selection score.
"""

from __future__ import annotations

import dataclasses
import functools
import pathlib

import jax
import jax.numpy as jnp
import ml_collections
import numpy as np

from kx.evolve.encoding import Encoding
from kx.evolve.errors import ConfigError, is_int, need
from kx.sim import observe
from kx.sim.policies import Policy
from kx.sim.types import KeepAwayConfig


def _strong(tree):
    return jax.tree.map(lambda a: jax.lax.convert_element_type(a, jnp.asarray(a).dtype), tree)


def n_params(n_in: int, n_out: int, hidden: int) -> int:
    return n_in * n_out + n_out if hidden == 0 else n_in * hidden + hidden + hidden * n_out + n_out


def _unflatten(theta: jax.Array, n_in: int, n_out: int, hidden: int) -> list[jax.Array]:
    """``theta [D, *B]`` (batch-last) as the network's arrays, batch-last."""
    b = theta.shape[1:]
    if hidden == 0:
        return [theta[: n_in * n_out].reshape((n_in, n_out) + b), theta[n_in * n_out:]]
    o = 0
    out = []
    for shape in ((n_in, hidden), (hidden,), (hidden, n_out), (n_out,)):
        size = int(np.prod(shape))
        out.append(theta[o:o + size].reshape(shape + b))
        o += size
    return out


@dataclasses.dataclass(frozen=True)
class _Programs:
    """evosax's CMA-ES of one shape and initial step size, and its jitted functions."""

    es: object
    params: object
    init: object
    ask: object
    tell: object
    init_at: object


@functools.lru_cache(maxsize=None)
def _programs(population_size: int, dim: int, sigma_init: float) -> _Programs:
    """One set of compiled programs per (population size, dimension, initial step size), shared by
    every run of the process: a second run of the same shape compiles nothing (its keys and states are
    traced). evosax's parameters are constants of the programs, as XLA folds them (tracing them instead
    changes the last bits of the updates, and so every run's trajectory). evosax leaves some fields
    weakly typed; strong types keep one program per function (and equal to what a restored checkpoint
    holds)."""
    from evosax.algorithms import CMA_ES

    es = CMA_ES(population_size=population_size, solution=jnp.zeros(dim))
    params = es.default_params.replace(std_init=jnp.asarray(sigma_init, jnp.float32))
    return _Programs(
        es=es, params=params,
        init=jax.jit(lambda key: _strong(es.init(key, jnp.zeros(dim), params))),
        ask=jax.jit(lambda key, state: _strong(es.ask(key, state, params))),
        tell=jax.jit(lambda key, pop, score, state: _strong(es.tell(key, pop, -score, state, params))),
        init_at=jax.jit(lambda key, mean, std: _strong(es.init(key, mean, params).replace(std=std))))


@functools.lru_cache(maxsize=None)
def network_policy(sim: KeepAwayConfig, layout: str, hidden: int) -> Policy:
    """The fixed network of flat parameter vectors, as a shared-table policy: ``params.table [G, D]``,
    ``params.index [*B]`` the row of each lane."""
    obs_fn = {"fixed": observe.fixed_obs, "full": observe.full_obs}[layout]
    n_in, n_out = observe.n_inputs(layout, sim), observe.n_outputs(layout, sim)

    def apply(params, state, key):
        theta = jnp.moveaxis(jnp.take(params.table, params.index, axis=0), -1, 0)  # [D, *B]
        x = obs_fn(state, sim)  # [in, *B]
        arrays = _unflatten(theta, n_in, n_out, hidden)
        if hidden == 0:
            w, out = arrays
            for i in range(n_in):  # unrolled: a short contraction stays elementwise and fuses
                out = out + x[i][None] * w[i]
        else:
            w1, b1, w2, b2 = arrays
            hid = jnp.tanh(jnp.sum(x[:, None] * w1, axis=0) + b1)
            out = jnp.sum(hid[:, None] * w2, axis=0) + b2
        return observe.decode_ranked(out, state, sim)

    return Policy(f"cma_es-{layout}-h{hidden}", apply, shared=True)


class CMAESEncoding(Encoding):
    name = "cma_es"
    # vmapped, evosax's covariance update (matrix products, eigendecomposition) rounds differently in
    # the last bit from one run's: a batched group calls ask and tell run by run (kx.evolve.group.over_runs)
    vmap_exact = frozenset({"policy_params"})
    section = "cma_es"
    layouts = ("fixed", "full")
    metric_fields = ("sigma", "mean_norm")
    plot_field = "sigma"

    @classmethod
    def default_config(cls) -> ml_collections.ConfigDict:
        return ml_collections.ConfigDict({"sigma_init": 1.0, "hidden": 0})

    @classmethod
    def defaults(cls) -> dict:
        return {"population_size": 50, "generations": 60}

    def __init__(self, cfg, sim, sim_params):
        super().__init__(cfg, sim, sim_params)
        c = cfg.cma_es
        need(isinstance(c.sigma_init, float) and 0.0 < c.sigma_init <= 1e4, "cma_es.sigma_init",
             "a number in (0, 10000]", c.sigma_init)
        need(is_int(c.hidden) and 0 <= c.hidden <= 256, "cma_es.hidden", "an integer in [0, 256] (0: a linear network)",
             c.hidden)
        need(cfg.population_size >= 4, "population_size", "at least 4 for cma_es", cfg.population_size)
        try:
            import evosax.algorithms  # noqa: F401
        except ImportError as e:  # pragma: no cover - evosax is a dependency
            raise ConfigError("method: cma_es needs evosax (pip install evosax==0.3.2)") from e
        self.hidden = c.hidden
        self.n_in, self.n_out = observe.n_inputs(self.layout, sim), observe.n_outputs(self.layout, sim)
        self.dim = n_params(self.n_in, self.n_out, self.hidden)
        self._programs = _programs(cfg.population_size, self.dim, float(c.sigma_init))
        self.es, self.es_params = self._programs.es, self._programs.params

    def _init_at(self, key, mean, std):
        return self._programs.init_at(key, jnp.asarray(mean, jnp.float32), jnp.asarray(std, jnp.float32))

    def init(self, key):
        return self._programs.init(key)

    def ask(self, key, state):
        return self._programs.ask(key, state)

    def tell(self, key, population, score, fitness, state):
        state, _ = self._programs.tell(key, population, jnp.asarray(score, jnp.float32), state)
        return state, {"sigma": state.std, "mean_norm": jnp.linalg.norm(state.mean)}

    def policy_for(self, sim):
        n_in, n_out = observe.n_inputs(self.layout, sim), observe.n_outputs(self.layout, sim)
        if (n_in, n_out) != (self.n_in, self.n_out):
            raise ConfigError(f"task: the run's {self.layout}-layout networks have {self.n_in} inputs and "
                              f"{self.n_out} outputs; {sim.name} needs {n_in} and {n_out}")
        return network_policy(sim, self.layout, self.hidden)

    def transfer_problems(self, source, state, seeding):
        out = []
        if seeding == "half":
            out.append("seeding 'half': CMA-ES carries a distribution, not a population; allowed 'population' "
                       "(the source's mean and step size) or 'champion' (the source's champion as the mean)")
        if (source.dim, source.hidden) != (self.dim, self.hidden):
            out.append(f"the source's networks have {source.dim} parameters ({source.n_in} inputs, {source.n_out} "
                       f"outputs, cma_es.hidden {source.hidden}), this run's {self.dim} ({self.n_in} inputs, "
                       f"{self.n_out} outputs, cma_es.hidden {self.hidden}): they do not fit")
        return out

    def transfer(self, key, source, state, seeding, order):
        """The distribution starts at the source's mean (``champion``: at its validated champion) with the
        source's step size; its covariance and evolution paths start afresh, as in a new run."""
        mean = state.learner.mean if seeding == "population" else state.champion
        return self._init_at(key, mean, state.learner.std)

    def check(self, state, champion):
        errs = []
        for name in ("mean", "std", "C", "p_std", "p_c"):
            if not np.all(np.isfinite(np.asarray(getattr(state, name)))):
                errs.append(f"CMA-ES {name} holds non-finite values")
        if not float(state.std) > 0:
            errs.append(f"CMA-ES step size {float(state.std)} is not positive")
        if champion is not None and not np.all(np.isfinite(np.asarray(champion))):
            errs.append("champion: non-finite parameters")
        return errs

    def describe(self) -> str:
        net = "linear" if self.hidden == 0 else f"{self.hidden} tanh hidden units"
        return (f"cma_es ({self.layout} layout: {self.n_in} inputs, {self.n_out} outputs, {net}, "
                f"{self.dim} parameters)")

    def progress(self, row) -> str:
        return f"sigma {float(row['sigma']):.3f}"

    def draw(self, genotype, path: pathlib.Path):
        """The champion's weight matrices as heat maps (inputs by rows, outputs by columns)."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        arrays = [np.asarray(a) for a in _unflatten(jnp.asarray(genotype), self.n_in, self.n_out, self.hidden)]
        mats = [arrays[0]] if self.hidden == 0 else [arrays[0], arrays[2]]
        biases = [arrays[1]] if self.hidden == 0 else [arrays[1], arrays[3]]
        fig, axes = plt.subplots(1, len(mats), figsize=(4 + 3 * len(mats), 5), squeeze=False)
        vmax = max(float(np.abs(np.asarray(genotype)).max()), 1e-6)
        for ax, m, b, name in zip(axes[0], mats, biases, ("inputs -> " + ("outputs" if self.hidden == 0 else "hidden"),
                                                           "hidden -> outputs")):
            im = ax.imshow(np.vstack([m, b[None]]), cmap="RdBu", vmin=-vmax, vmax=vmax, aspect="auto")
            ax.set_title(name)
            ax.set_ylabel("input (last row: bias)")
            ax.set_xlabel("unit")
        fig.colorbar(im, ax=axes[0].tolist())
        path = pathlib.Path(path)
        fig.savefig(path, dpi=100, bbox_inches="tight")
        plt.close(fig)
        return path

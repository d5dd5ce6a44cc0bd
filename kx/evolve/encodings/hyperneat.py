"""HyperNEAT as an encoding of the run loop: ``method = "hyperneat"``, CPPNs that paint a Bird's Eye View
substrate, which plays every keep-away task unchanged.

The learner is kx's NEAT (:mod:`kx.neat`) on CPPN genomes (:func:`kx.hyperneat.presets.cppn`: the
paper's activation set, the authors' HyperNEAT mutation rates). Each generation
:func:`kx.hyperneat.substrate.build` queries every CPPN over the substrate's 160,000 links at once, and
the population's substrates go to the evaluator as one shared table; the holder decides with the Bird's
Eye View policy (:func:`kx.hyperneat.bev.bev_policy`). The substrate's size is the field's, not the
number of players, so a CPPN evolved in 3v2 plays 4v3, 5v3 and 6v4 as it is (``kx.evaluate --task``).

Config section ``hyperneat``: every :class:`~kx.neat.types.NEATParams` field (the CPPN rates), the
CPPN's ``activations`` (the set new hidden nodes draw from) and ``output_activation``, its capacity
(``max_hidden``, ``extra_conns``, ``extra_genes``, ``species_capacity``, ``max_add_links``, bounded as
in the ``neat`` section, except that ``max_add_links = 0``, the default, means ``min(40,
population_size)``: the preset's 40 for 150 CPPNs, see :mod:`kx.hyperneat.presets`), and the substrate
and policy: ``resolution`` (must equal ``sim.field_size``), ``distance_input``, ``image``
(``"authors"`` or ``"paper"``), ``decision`` (``"cells"`` or ``"literal"``) and
``substrate_activation`` (the substrate's output nodes); docs/hyperneat.md gives the defaults and the
measurements behind them. The run's ``layout`` is ``"bev"``.
"""

from __future__ import annotations

import pathlib

import jax
import jax.numpy as jnp
import ml_collections
import numpy as np

from kx.evolve.encodings.neat import NEATEncoding, check_add_links, check_capacity, learner, neat_params_fields
from kx.evolve.errors import ConfigError, is_int, need
from kx.hyperneat.bev import DECISIONS, IMPLS, bev_policy, native_runs
from kx.neat.activations import ACTIVATIONS
from kx.neat.types import NEATError, capacity, initial_conns
from kx.sim.observe import BEV_IMAGES


class HyperNEATEncoding(NEATEncoding):
    name = "hyperneat"
    # vmapped over 10 runs of 150 CPPNs, the substrate query rounds differently in the last bit from one
    # run's (identical at 3 x 12): a batched group builds each run's substrates on its own
    vmap_exact = frozenset({"ask", "tell"})
    section = "hyperneat"
    layouts = ("bev",)

    @classmethod
    def default_config(cls) -> ml_collections.ConfigDict:
        from kx.hyperneat import presets

        ncfg, nparams = presets.cppn()
        c = neat_params_fields(nparams)
        c.update(activations=tuple(ncfg.activation_options), output_activation=ncfg.output_activation,
                 max_hidden=ncfg.n_hidden, species_capacity=ncfg.species_capacity,
                 extra_conns=ncfg.extra_conns, extra_genes=ncfg.extra_genes,
                 max_add_links=0, resolution=20, distance_input=True, image="authors",
                 decision="cells", substrate_activation="bipolar_sigmoid",
                 # how the decision's sums are computed (kx.hyperneat.bev.IMPLS: the same bits whichever):
                 # auto the native kernel (kx.hyperneat.native) where it runs, else the XLA code; xla or native force
                 # one
                 impl="auto")
        return ml_collections.ConfigDict(c)

    @classmethod
    def defaults(cls) -> dict:
        return {"layout": "bev"}

    def __init__(self, cfg, sim, sim_params):
        from kx.hyperneat import presets
        from kx.hyperneat.substrate import CPPN_OUTPUTS, Substrate

        self.cfg, self.sim, self.sim_params = cfg, sim, sim_params
        self.layout = cfg.layout
        self.population_size = cfg.population_size
        n = dict(cfg.hyperneat)
        acts = n["activations"]
        need(isinstance(acts, (tuple, list)) and len(acts) >= 1 and all(isinstance(a, str) and a in ACTIVATIONS
                                                                      for a in acts)
             and len(set(acts)) == len(acts), "hyperneat.activations",
             f"distinct names from {sorted(ACTIVATIONS)}", acts)
        for f in ("output_activation", "substrate_activation"):
            need(isinstance(n[f], str) and n[f] in ACTIVATIONS, f"hyperneat.{f}", f"one of {sorted(ACTIVATIONS)}",
                 n[f])
        need(isinstance(n["image"], str) and n["image"] in BEV_IMAGES, "hyperneat.image", f"one of {BEV_IMAGES}",
             n["image"])
        need(isinstance(n["decision"], str) and n["decision"] in DECISIONS, "hyperneat.decision",
             f"one of {DECISIONS}", n["decision"])
        need(isinstance(n["distance_input"], bool), "hyperneat.distance_input", "true or false", n["distance_input"])
        need(isinstance(n["impl"], str) and n["impl"] in IMPLS, "hyperneat.impl", f"one of {IMPLS}", n["impl"])
        if n["impl"] == "native" and native_runs(n["image"]):
            raise ConfigError(f"hyperneat.impl: 'native' cannot run here ({native_runs(n['image'])}); allowed "
                              f"{IMPLS}, 'auto' or 'xla' for the XLA code (the same results)")
        need(n["resolution"] == sim.field_size and is_int(n["resolution"]), "hyperneat.resolution",
             f"sim.field_size ({sim.field_size}): one substrate node per field cell", n["resolution"])
        self.substrate = Substrate(resolution=n["resolution"], distance_input=n["distance_input"],
                                   weight_range=float(n["weight_range"]))
        self.image, self.decision, self.substrate_activation = n["image"], n["decision"], n["substrate_activation"]
        self.impl = n["impl"]
        check_capacity(n, "hyperneat", cfg.population_size, initial_conns(self.substrate.n_inputs, CPPN_OUTPUTS))
        check_add_links(n["max_add_links"], "hyperneat", cfg.population_size,
                        f"min({presets.MAX_ADD_LINKS}, population_size)")
        opts = tuple(dict.fromkeys(tuple(acts) + (n["output_activation"],)))
        try:
            self.neat_config, _ = presets.cppn(
                n_inputs=self.substrate.n_inputs, n_outputs=CPPN_OUTPUTS, population_size=cfg.population_size,
                **capacity(self.substrate.n_inputs, CPPN_OUTPUTS, n["max_hidden"], n["extra_conns"], n["extra_genes"]),
                species_capacity=n["species_capacity"], activation_options=opts,
                hidden_activation=acts[0], output_activation=n["output_activation"],
                # 0: the preset's 40, which suits 150 CPPNs, or a smaller population's every add-link
                max_add_links=n["max_add_links"] or min(presets.MAX_ADD_LINKS, cfg.population_size))
        except NEATError as e:
            msg = str(e).replace("NEATParams.", "hyperneat.").replace("NEATConfig.", "hyperneat.")
            raise ConfigError(msg) from None
        self.neat_params, self.neat = learner(n, self.neat_config, "hyperneat")

    def _maps(self, source):
        return None  # a CPPN plays every task's substrate: it carries over unchanged (or not at all)

    def policy_for(self, sim):
        if sim.field_size != self.substrate.resolution:
            r = self.substrate.resolution
            raise ConfigError(f"task: the run's substrate has {r} x {r} nodes per layer; {sim.name}'s field is "
                              f"{sim.field_size} x {sim.field_size} cells")
        # skip_idle: no decision where the world reads none (the ball in flight, the episode over); every
        # episode, and so every result, is the same bit for bit, for about a quarter less per live step
        return bev_policy(sim, image=self.image, decision=self.decision, activation=self.substrate_activation,
                          skip_idle=True, impl=self.impl)

    def implementation(self) -> dict:
        """Which code computes the decision's sums in this process (:func:`kx.hyperneat.bev.native_runs`)."""
        why = "" if self.impl == "xla" else native_runs(self.image)
        if self.impl != "xla" and not why:
            from kx.hyperneat import native

            return {"decision_sums": "native", "chosen": self.impl, "library": str(native.library_path())}
        return {"decision_sums": "xla", "chosen": self.impl, **({"why_not_native": why} if why else {})}

    policy_params_leading_axes = False  # its own policy_params: the substrate query, mapped over runs

    def policy_params(self, population):
        """The population's substrates (:func:`kx.hyperneat.substrate.build`), built where the evaluator plays
        them: their rows split over the devices when they divide evenly (kx.sim.lanes.rows_split), so that no
        device needs a copy of the whole table (96 MB for 150 CPPNs); each CPPN's query keeps only the hidden
        rows the population uses (read on the host: call it outside ``jit`` and ``vmap``). The same
        substrates as reals (a zero's sign at most), so the same decisions, either way."""
        from kx.hyperneat.substrate import build, hidden_rows

        n_dev = jax.local_device_count()
        devices = n_dev if population.node_id.shape[0] % n_dev == 0 else 1
        return build(population, self.neat_config, self.substrate, devices=devices,
                     rows=hidden_rows(population, self.neat_config))

    def describe(self) -> str:
        c, s = self.neat_config, self.substrate
        return (f"hyperneat (CPPN {c.n_inputs} inputs {s.input_names}, 3 outputs; substrate {s.resolution}x"
                f"{s.resolution} -> {s.resolution}x{s.resolution}, {s.n_cells ** 2} links; image {self.image}, "
                f"decision {self.decision})")

    def draw(self, genotype, path: pathlib.Path):
        """The champion's substrate (``champion.png``) and its CPPN (``champion_cppn.png`` beside it)."""
        from kx.hyperneat.draw import draw_substrate
        from kx.neat.draw import draw_genome

        path = pathlib.Path(path)
        g = jax.device_get(genotype)
        draw_genome(g, self.neat_config, path.with_name(path.stem + "_cppn.png"),
                    input_names=list(self.substrate.input_names) + ["bias"], output_names=["weight", "expr", "bias"],
                    title="CPPN")
        table = self.policy_params(jax.tree.map(lambda a: jnp.asarray(a)[None], g))
        return draw_substrate({k: np.asarray(v[0]) for k, v in table.items()}, self, path)

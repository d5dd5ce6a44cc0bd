"""NEAT (Stanley & Miikkulainen, "Evolving Neural Networks through Augmenting Topologies", 2002) on
fixed-capacity JAX tensors, knowing nothing of keep-away.

* :mod:`kx.neat.types`: the static shapes (:class:`~kx.neat.types.NEATConfig`), the traced rates
  (:class:`~kx.neat.types.NEATParams`), the genome tensors and the run state;
* :mod:`kx.neat.genome`: pure single-genome operators (mutations, crossover, distance);
  :mod:`kx.neat.innovation`: innovation numbers shared across a generation; :mod:`kx.neat.checks`:
  host-side invariant checks;
* :mod:`kx.neat.network`: genomes as networks that evaluate batch-last; :mod:`kx.neat.activations`;
* :mod:`kx.neat.algorithm`: ``init``/``ask``/``tell`` (the generation step) and the
  :class:`~kx.neat.algorithm.NEAT` learner;
* :mod:`kx.neat.presets`: the published parameter sets (XOR, Table 2's keep-away readings);
  :mod:`kx.neat.xor`: XOR, the example task; :mod:`kx.neat.transfer`: the paper's Algorithm 1;
  :mod:`kx.neat.draw`: a genome's network as a PNG.

The submodules are imported where they are used (``from kx.neat import presets``); importing
``kx.neat`` itself loads none of them.
"""

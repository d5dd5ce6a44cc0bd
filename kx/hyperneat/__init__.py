"""HyperNEAT with the Bird's Eye View substrate (Verbancsics & Stanley 2010; the paper, section 3.2).

A user of :mod:`kx.neat`, like XOR and keep-away: CPPNs are NEAT genomes whose hidden nodes carry an
activation from the paper's set (:mod:`kx.hyperneat.presets`); :mod:`kx.hyperneat.substrate` queries
every CPPN of a population over the links of the 20 x 20 -> 20 x 20 substrate at once; and
:mod:`kx.hyperneat.bev` is the Bird's Eye View policy the evaluator plays, reading a generation's
substrates from one shared table.
"""

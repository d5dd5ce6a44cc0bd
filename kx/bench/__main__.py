"""Benchmarks: ``python -m kx.bench NAME``.

Each prints its figures and ends with one line ``name: value unit (ratio X vs BASELINE)``, where the
baseline is measured in the same run (these machines are shared and noisy).

* ``sim``: live episode-steps per second (steps of episodes still running) of the batched evaluator
  on 4500 episodes of 3v2, with the heuristic policy and with a small neural policy on the 13-input
  layout (150 random networks x 30 trials), against the plain-Python reference on the same rules.
* ``neat_xor``: 100 XOR runs of kx's NEAT, vectorised, against neat-python 2.0.0 (optional ``bench``
  extra) with its standard XOR configuration, both judged by neat-python's criterion (4 - SSE >= 3.9):
  solved runs, evaluations, hidden nodes, wall time with and without kx's compilation, and a check of
  neat-python's first 20 runs against SPEC §2's anchor.
* ``generation``: seconds per generation of ``python -m kx.train``'s default config, split into
  evaluation and evolution, with the share of executed simulator steps that were live.
* ``learning``: the validated champions of the default config (NEAT) and of HyperNEAT over 10 seeds on
  1000 test states, beside the same budget of CMA-ES (evosax, ``configs/cma_es_3v2.py``) on a linear
  policy of the 13/3 layout, and of PPO (flax, optax; ``configs/ppo_3v2.py``) at the same 90,000
  episodes, through the same run loop; and the same 3v2 champions zero-shot on 4v3, 5v3 and 6v4.
* ``hyperneat``: seconds per generation of HyperNEAT and of NEAT (3v2, 150 x 30) on the same start
  states in one run, split into building the policies (the substrates), evaluation, evolution and
  validation.
* ``novelty``: the novelty hybrid's generation step (k-NN over the population and a full archive,
  archive update, hybrid score) against evaluating the population on 30 trials.
* ``transfer``: for NEAT and HyperNEAT over 5 seeds, the first-generation champion of a 4v3, 5v3 and 6v4
  run seeded with a 3v2 run's final population against that of a fresh run, on the same held-out
  test states of the target.
* ``runs``: R = 1, 4 and 16 runs of the default config (20 generations) trained as one batched group
  (``kx.train --seeds``) against the same runs one after another in one process, in ``--rounds`` rounds
  taken in turn: runs per hour, warm and with compilation, and the ratio (warm: the median of the rounds').
* ``policies``: the cost per live step of the heuristic's whole step, NEAT's and HyperNEAT's on trained 4v3
  populations (committed fixtures, ``scripts/make_policy_fixtures.py``), each a ratio to the heuristic's
  measured in the same run, and each decision alone.
* ``protocol``: a fixed small slice of the Table 3 protocol run by one process and by several
  (``--processes 1 2``; kx.experiments.processes): runs per hour for each, the same results checked.
* ``neat_generation``: one NEAT generation step (speciate and reproduce) against evaluating the same
  population of 150 networks on 30 keep-away trials, over a real 3v2 run.
* ``platform``: whether this machine plays the shipped CPU digest's heuristic episodes bit for bit (checksums
  of the world's integer state, stage by stage, on the default backend and, beside an accelerator, on the host
  CPU backend, each in a process of its own), the first entry that differs where one does, and the digest's
  seconds warm and with compilation; the ratio is the share of stages that match.
"""

from __future__ import annotations

import argparse

from kx import runtime
from kx.bench import (
    generation,
    hyperneat,
    learning,
    neat_generation,
    neat_xor,
    novelty,
    platform,
    policies,
    ppo,
    protocol,
    runs,
    sim,
    transfer,
)

# Each benchmark is a module whose run(args) prints its figures; they import JAX inside run, after
# kx.runtime.setup() has set up the devices.
BENCHES = {"sim": sim.run, "neat_generation": neat_generation.run, "neat_xor": neat_xor.run,
           "generation": generation.run, "learning": learning.run, "hyperneat": hyperneat.run,
           "novelty": novelty.run, "transfer": transfer.run, "runs": runs.run, "policies": policies.run,
           "protocol": protocol.run, "ppo": ppo.run, "platform": platform.run}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(prog="python -m kx.bench", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("name", choices=sorted(BENCHES))
    p.add_argument("--episodes", type=int, default=4500, help="sim, platform: start states of 3v2")
    p.add_argument("--repeats", type=int, default=5, help="sim, policies: samples per figure (the median is reported)")
    p.add_argument("--sample-seconds", type=float, default=2.0,
                   help="sim, policies: the least work per sample, in seconds")
    p.add_argument("--reference-seconds", type=float, default=5.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--generations", type=int, default=20,
                   help="neat_generation, generation, hyperneat: generations to run")
    p.add_argument("--config", default=None, help="generation, runs: the config file (default: configs/neat_3v2.py); "
                   "ppo: the PPO config, of method ppo or ppo_entity in 4v3 (default: configs/ppo_4v3.py)")
    p.add_argument("--group-sizes", default="1,4,16", help="runs: the group sizes R (seeds 0..R-1)")
    p.add_argument("--rounds", type=int, default=1,
                   help="runs: rounds in turn per R (the group, then its seeds alone); the median ratio is reported")
    p.add_argument("--runs", type=int, default=100, help="neat_xor: independent runs")
    p.add_argument("--width", type=int, default=1, help="neat_xor: populations evolved side by side per device")
    p.add_argument("--devices", type=int, default=0,
                   help="neat_xor: devices the runs are dealt out to (0: all; kx.runtime makes one per CPU core)")
    p.add_argument("--no-neat-python", action="store_true", help="neat_xor: skip the neat-python baseline")
    p.add_argument("--seeds", type=int, default=None,
                   help="learning, transfer: seeds 0..N-1 of each learner (default 10 for learning, 5 for transfer)")
    p.add_argument("--first-seed", type=int, default=0,
                   help="learning: the first seed (seeds FIRST..FIRST+N-1; to split the seeds over processes)")
    p.add_argument("--objective", default="fitness", help="transfer: the objective of the source and target runs")
    p.add_argument("--test-trials", type=int, default=1000, help="learning: test states every champion plays")
    p.add_argument("--methods", default="NEAT,HyperNEAT,CMA-ES,PPO",
                   help="learning: the learners to run, comma-separated, of NEAT, HyperNEAT, CMA-ES, PPO, PPO-2dev "
                        "(PPO data-parallel over two devices), PPO-smdp (PPO's older SMDP shape) and PPO-entity "
                        "(default: the first four; the summary line needs NEAT and CMA-ES; a PPO method's wall time "
                        "is set against NEAT's warm run)")
    p.add_argument("--ppo-warmup", type=int, default=150,
                   help="ppo: updates that train the network before the samples (a fresh one loses the ball at once)")
    p.add_argument("--skip", type=int, default=5,
                   help="neat_generation, generation, hyperneat: first generations left out (they compile)")
    p.add_argument("--processes", type=int, nargs="+", default=[1, 2],
                   help="protocol: the process counts to compare (default 1 2)")
    p.add_argument("--protocol-runs", type=int, default=4, help="protocol: runs a cell of the slice")
    p.add_argument("--protocol-generations", type=int, default=5, help="protocol: generations a run of the slice")
    p.add_argument("--backends", default=None,
                   help="platform: comma-separated, of default, cpu, gpu, tpu (default: the default backend, and "
                        "cpu too where the default is an accelerator)")
    p.add_argument("--out", default=None, help="platform: write this platform's digest to this JSON file")
    p.add_argument("--reference", default=None,
                   help="platform: the digest to compare with (default: the shipped CPU digest, "
                        "kx/bench/data/platform_digest_cpu.json)")
    args = p.parse_args(argv)
    if args.seeds is None:
        args.seeds = 5 if args.name == "transfer" else 10
    runtime.setup()
    BENCHES[args.name](args)


if __name__ == "__main__":
    main()

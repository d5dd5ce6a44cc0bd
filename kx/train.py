"""Evolve keep-away teams: ``python -m kx.train``.

With no arguments it runs the paper's source task (3v2, NEAT, population 150, 30 trials, 20
generations; ``configs/neat_3v2.py``) into a new run directory under ``runs/``::

    python -m kx.train
    python -m kx.train --config configs/cma_es_3v2.py                 # CMA-ES (evosax) on a fixed network
    python -m kx.train --config configs/neat_4v3.py --config.population_size=50 --workdir runs/small
    python -m kx.train --workdir runs/small --resume              # continue from the last checkpoint
    python -m kx.train --workdir runs/small --resume --step 10    # ... or from checkpoint 10
    python -m kx.train --workdir runs/small --resume --config.generations=40   # ... and run longer

Overrides name any config field (``--config.seed=3``, ``--config.neat.add_node_prob=0.05``,
``--config.sim.max_iterations=1000``); they are parsed by ml_collections' ``config_flags``. A true/false
field may stand alone (``--config.gif`` is ``--config.gif=true``); a value never starts with ``--`` (in
``--config.gif --resume``, ``--resume`` is an option of its own). An unknown field or a value out of
range is refused before anything runs; so is an existing run directory, unless ``--resume`` or
``--overwrite``, and one another process is writing (``run.lock``). A resumed run must keep every field
but ``generations``, ``checkpoint_every``, ``keep_checkpoints``, ``gif`` and ``gif_frames``; it ends bit
for bit where the uninterrupted run would have (and with nothing left to do, it writes nothing).
``--resume --step N`` continues from checkpoint N; the later checkpoints are moved to ``abandoned/`` in
the run directory, never deleted.

``--seeds`` trains several runs of the config at once, differing only in seed, as one batched program
(:mod:`kx.evolve.group`), with one progress line per generation for the group; each run gets its own
run directory ``<workdir>/seed<s>``, the same, bit for bit but for the timings, as ``--config.seed=<s>``
alone writes, and resumable alone or as the group (``--resume`` without ``--config``: each run from its
own config.json, a transferred run with its own source)::

    python -m kx.train --seeds 0-15 --workdir runs/neat16          # runs/neat16/seed0 ... seed15
    python -m kx.train --seeds 0-15 --workdir runs/neat16 --resume
    python -m kx.train --config configs/neat_4v3.py --seeds 0-15 --workdir runs/t16 \
        --config.transfer.source=runs/neat16/seed{seed}               # each target from its own source
"""

from __future__ import annotations

import argparse
import datetime
import pathlib
import sys

from kx import runtime


def parse(argv: list[str]) -> tuple[argparse.Namespace, list[str]]:
    p = argparse.ArgumentParser(prog="python -m kx.train", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", default=None, help="config file (default: configs/neat_3v2.py; on --resume: "
                   "the run's own config)")
    p.add_argument("--workdir", default=None, help="run directory (default: runs/<config>-s<seed>-<time>)")
    p.add_argument("--resume", action="store_true", help="continue the run in --workdir from its last checkpoint")
    p.add_argument("--step", type=int, default=None, help="with --resume: continue from this checkpoint")
    p.add_argument("--overwrite", action="store_true", help="delete the run in --workdir and start again")
    p.add_argument("--seeds", default=None, help="train these seeds at once as one batched group: 0-15, 0,3,7 or "
                   "a mix; each run in <workdir>/seed<s> ({seed} in transfer.source names each run's source)")
    overrides, rest, i = [], [], 0
    while i < len(argv):
        a = argv[i]
        if a.startswith("--config."):
            # --config.seed 3; but never an option as a value: --config.gif --resume is a bare --config.gif
            if "=" not in a and i + 1 < len(argv) and not argv[i + 1].startswith("--"):
                a, i = f"{a}={argv[i + 1]}", i + 1
            overrides.append(a[len("--config."):])  # "field=value", or a bare "field" (resolve_bare)
        else:
            rest.append(a)
        i += 1
    return p.parse_args(rest), overrides


def resolve_bare(cfg, overrides: list[str]) -> list[str]:
    """Overrides with each bare field (``--config.gif``, no value) resolved against ``cfg``: a true/false
    field means true; any other field needs a value (``ConfigError`` naming it); a name that is no
    field is left to :func:`kx.evolve.config.apply_overrides` to refuse."""
    import ml_collections

    from kx.evolve.errors import ConfigError

    out = []
    for item in overrides:
        if "=" in item:
            out.append(item)
            continue
        node, found = cfg, True
        for part in item.split("."):
            if isinstance(node, ml_collections.ConfigDict) and part in node:
                node = node[part]
            else:
                found = False
                break
        if found and not isinstance(node, ml_collections.ConfigDict) and not isinstance(node, bool):
            raise ConfigError(f"--config.{item}: needs a value (--config.{item}=<value>); only a true/false "
                                      "field may stand alone, and a value never starts with --")
        out.append(f"{item}=true")
    return out


def workdir_of(args, tag: str) -> pathlib.Path:
    """``--workdir``, or by default ``runs/<config name>-<tag>-<time>``."""
    if args.workdir:
        return pathlib.Path(args.workdir)
    from kx.evolve import config as cfg_lib

    name = pathlib.Path(args.config).stem if args.config else cfg_lib.DEFAULT_CONFIG.stem
    return pathlib.Path("runs") / f"{name}-{tag}-{datetime.datetime.now().strftime('%Y%m%d-%H%M%S')}"


def load_config(args, overrides: list[str], run_dir: pathlib.Path):
    """The config of the command: on ``--resume`` with no ``--config``, the run's own (``run_dir``'s
    config.json) with this command's overrides (e.g. more generations); else ``--config`` (default
    ``configs/neat_3v2.py``) with them."""
    from kx.evolve import config as cfg_lib
    from kx.evolve.errors import RunError

    if args.resume and args.config is None:
        saved = run_dir / "config.json"
        if not saved.is_file():
            raise RunError(f"--resume: {run_dir} holds no run to resume (no config.json)")
        base = cfg_lib.read_run_config(saved)
        cfg = cfg_lib.apply_overrides(base, resolve_bare(base, overrides))
        cfg.lock()
        return cfg
    if any("=" not in o for o in overrides):
        overrides = resolve_bare(cfg_lib.load(args.config), overrides)
    return cfg_lib.load(args.config, overrides)


def parse_seeds(text: str) -> list[int]:
    """``--seeds``: :func:`kx.evolve.config.parse_seeds` (``"0-3,7"`` -> ``[0, 1, 2, 3, 7]``; a ``ConfigError``
    naming ``--seeds`` and the allowed forms otherwise), imported here, after the runtime's set-up."""
    from kx.evolve import config as cfg_lib

    return cfg_lib.parse_seeds(text)


def group_configs(cfg, seeds: list[int]) -> list:
    """One config per seed: ``cfg`` with ``seed`` and, when ``transfer.source`` holds ``{seed}``, that
    seed's source."""
    out = []
    for s in seeds:
        c = cfg.copy_and_resolve_references()
        c.unlock()
        c.seed = s
        if "{seed}" in c.transfer.source:
            c.transfer.source = c.transfer.source.replace("{seed}", str(s))
        c.lock()
        out.append(c)
    return out


def train_group(args, overrides) -> None:
    """``--seeds``: the runs of a batched group (:func:`kx.evolve.group.train_group`)."""
    from kx.evolve import config as cfg_lib
    from kx.evolve import group as group_lib
    from kx.evolve import trainer as trainer_lib
    from kx.evolve.errors import RunError

    seeds = parse_seeds(args.seeds)
    if args.step is not None:
        raise RunError("--step: not with --seeds (resume one run with its own --workdir)")
    if args.resume and not args.workdir:
        raise RunError("--resume: name the group with --workdir")
    if args.resume and args.config is None:  # each run from its own config.json (its own source, ...)
        cfgs = [group_configs(load_config(args, overrides, pathlib.Path(args.workdir) / f"seed{s}"), [s])[0]
                for s in seeds]
    else:
        cfgs = group_configs(load_config(args, overrides, pathlib.Path(args.workdir or ".") / f"seed{seeds[0]}"),
                             seeds)
    for c in cfgs:
        cfg_lib.validate(c)
    trainer_lib.check_group(cfgs)
    workdir = workdir_of(args, f"seeds{seeds[0]}-{seeds[-1]}")
    dirs = [workdir / f"seed{s}" for s in seeds]
    for d in dirs:
        refuse_taken(d, args)
    # every refusal above comes before any compute
    group_lib.train_group(cfgs, dirs, resume=args.resume, overwrite=args.overwrite,
                          log=lambda s: print(s, flush=True))


def refuse_taken(run_dir: pathlib.Path, args) -> None:
    """Refuses ``run_dir`` now, before JAX computes: one that another process is writing (run.lock), or,
    without ``--overwrite``, an existing run directory (``--resume`` takes one)."""
    from kx.evolve import run as run_lib

    if run_dir.is_dir():
        run_lib.RunLock(run_dir).check()
    if not args.overwrite:
        run_lib.prepare_run_dir(run_dir, args.resume, False)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args, overrides = parse(argv)
    # first: a config's validation may touch JAX (CMA-ES and HyperNEAT build arrays), and JAX's devices
    # are fixed when it first does
    runtime.setup()
    from kx.evolve.errors import ConfigError, RunError

    try:
        if args.seeds is not None:
            train_group(args, overrides)
        else:
            train_one(args, overrides)
    except (ConfigError, RunError) as e:
        print(f"kx.train: error: {e}", file=sys.stderr)
        return 2
    return 0


def train_one(args, overrides) -> None:
    """One run (:func:`kx.evolve.run.train`)."""
    from kx.evolve import config as cfg_lib
    from kx.evolve import run as run_lib
    from kx.evolve.errors import RunError

    if args.resume and not args.workdir:
        raise RunError("--resume: name the run with --workdir")
    if args.step is not None and not args.resume:
        raise RunError("--step: only with --resume")
    cfg = load_config(args, overrides, pathlib.Path(args.workdir or "."))
    cfg_lib.validate(cfg)
    workdir = workdir_of(args, f"s{cfg.seed}")
    refuse_taken(workdir, args)
    # every refusal above comes before any compute
    run_lib.train(cfg, workdir, resume=args.resume, overwrite=args.overwrite, step=args.step,
                  log=lambda s: print(s, flush=True))


if __name__ == "__main__":
    sys.exit(main())

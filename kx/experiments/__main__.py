"""Experiments: ``python -m kx.experiments {table3,confirm,novelty,report,sweep,zeroshot}``.

    python -m kx.experiments table3 --runs 20 --out runs/table3            # the paper's protocol (SPEC section 6)
    python -m kx.experiments table3 --runs 5 --methods neat --targets 4v3 --out runs/t3   # a part of it
    python -m kx.experiments novelty --out docs/novelty                   # the hybrid's readings
    python -m kx.experiments confirm --basis docs/table3 --out runs/confirm # a confirmatory replication
    python -m kx.experiments report runs/table3                            # report.md + PNGs from results.csv
    python -m kx.experiments sweep --config configs/hyperneat_3v2.py \\
        --grid hyperneat.image=paper,authors --seeds 0-4 --out runs/image  # an ablation sweep
    python -m kx.experiments zeroshot --out docs/zeroshot                 # every learner's 3v2 champions, zero-shot
    python -m kx.experiments zeroshot --out docs/zeroshot --merge runs/zs # the rows of the same study run elsewhere
    python -m kx.experiments zeroshot --out runs/zs --learners ppo --seeds 0-2 \
        --config-of ppo=configs/ppo_3v2_smdp.py                           # a part of it, another config of PPO

``zeroshot`` trains each learner (``--learners``, of neat, hyperneat, cma_es, ppo, ppo_entity, ppo_entity_mix) on 3v2
over ``--seeds`` and plays its validated champion, unchanged, on the test states of 3v2, 4v3, 5v3 and 6v4 (by default
Table 3's: ``--test-seed 0``, ``--test-trials 1000``), beside the hand-coded policies; its report sets each score
against the same learner trained in the target (docs/table3's no-transfer cells) and against NEAT evolved 50
generations in the target (kx.experiments.zeroshot, docs/experiments.md).

``table3``, ``novelty``, ``sweep`` and ``zeroshot`` are resumable: run the same command again after a kill;
finished runs are never redone, a run killed half-way resumes from its checkpoint, and the same folder accumulates
parts of one protocol. Each writes its report when it finishes.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys

from kx import runtime


def _list(text: str) -> tuple[str, ...]:
    return tuple(v for v in text.split(",") if v)


def _processes_args(p: argparse.ArgumentParser) -> None:
    """The options of a command that runs under several processes (kx.experiments.processes, docs/cluster.md)."""
    g = p.add_argument_group("several processes (docs/cluster.md)")
    g.add_argument("--processes", type=int, default=1,
                   help="start this many local processes of the command, its runs dealt among them (testing)")
    g.add_argument("--distributed", action="store_true",
                   help="one of the processes a cluster launcher started (SLURM's srun, Open MPI's or MPICH's "
                        "mpirun): its id and the count from the launcher's environment")
    g.add_argument("--num-processes", type=int, default=None, help="the count (plain hosts, with --process-id)")
    g.add_argument("--process-id", type=int, default=None, help="this process's id, 0 to count - 1")
    g.add_argument("--start-timeout", type=float, default=300.0,
                   help="seconds to wait for the other processes to meet in --out's folder (default 300)")


def _without_processes(argv: list[str]) -> list[str]:
    out, skip = [], False
    for a in argv:
        if skip:
            skip = False
        elif a == "--processes":
            skip = True
        elif not a.startswith("--processes="):
            out.append(a)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m kx.experiments", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True)
    t = sub.add_parser("table3", help="the paper's protocol: sources, targets, both measures, results.csv, report")
    t.add_argument("--out", required=True, help="the protocol's folder (results.csv, report.md, runs/)")
    t.add_argument("--runs", type=int, default=20, help="runs per cell (default 20)")
    t.add_argument("--methods", type=_list, default=("neat", "hyperneat", "cma_es", "ppo"))
    t.add_argument("--targets", type=_list, default=("4v3", "5v3", "6v4"))
    t.add_argument("--setups", type=_list, default=("none", "fitness", "hybrid", "none_hybrid"),
                   help="of none, fitness, hybrid, none_hybrid (the old novelty, none_novelty read as the last two)")
    t.add_argument("--seed", type=int, default=0, help="the protocol seed (every run's seed and the test states)")
    t.add_argument("--test-trials", type=int, default=1000)
    t.add_argument("--source-generations", type=int, default=20)
    t.add_argument("--target-generations", type=int, default=50)
    t.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="a config override for every run (population_size=50, trials=10, ...); repeatable")
    t.add_argument("--batch", type=int, default=16,
                   help="runs of one cell trained as one batched group (kx.evolve.group), at most; 1: one by one")
    c = sub.add_parser("confirm", help="a confirmatory replication of Table 3: a source of its own per target run, "
                                       "runs a cell fixed in advance from an earlier folder's power, one look")
    c.add_argument("--out", required=True, help="the confirmatory folder (protocol.json, results.csv, report.md)")
    c.add_argument("--basis", default=None,
                   help="the earlier protocol folder whose observed effects fix the runs a cell (a new folder only)")
    c.add_argument("--seed", type=int, default=1, help="the protocol seed (default 1; docs/table3's is 0)")
    c.add_argument("--batch", type=int, default=16, help="run indices a round, and runs a batched group (default 16)")
    c.add_argument("--design-only", action="store_true",
                   help="write protocol.json with the design and stop (commit it before the first run)")
    n = sub.add_parser("novelty", help="the novelty hybrid's readings over seeds (docs/novelty.md)")
    n.add_argument("--out", required=True, help="the sweep's folder (one table3 folder per arm, report.md)")
    n.add_argument("--arms", type=_list, default=None, help="the arms to run (default: every one)")
    n.add_argument("--methods", type=_list, default=("neat", "hyperneat"))
    n.add_argument("--phases", type=_list, default=("source", "target"))
    n.add_argument("--runs", type=int, default=10, help="sources per arm and method (default 10)")
    n.add_argument("--target-runs", type=_list, default=("neat=10", "hyperneat=5"), metavar="METHOD=N,...",
                   help="4v3 transfers per arm and method (default neat=10,hyperneat=5)")
    n.add_argument("--table3", default=None, help="the Table 3 folder (default: OUT/../table3)")
    n.add_argument("--batch", type=int, default=16)
    for q in (t, n):
        _processes_args(q)
    q = sub.add_parser("reproduce", help="train chosen runs of a protocol folder again and compare their rows with "
                                         "the committed ones (default: one run of each method)")
    q.add_argument("dir", help="a table3 or confirmatory folder (protocol.json, results.csv)")
    q.add_argument("--row", action="append", default=None, metavar="METHOD,SETUP,PHASE,TARGET,RUN",
                   help="a row to reproduce (repeatable; default: run 0 of each method's cheapest cell)")
    q.add_argument("--work", default=None, help="the scratch folder (default: a temporary one, removed after)")
    r = sub.add_parser("report", help="report.md and its PNGs from DIR/results.csv alone")
    r.add_argument("dir")
    s = sub.add_parser("sweep", help="every combination of a grid x seeds")
    s.add_argument("--config", default=None, help="the config file (or a --grid config=FILE1,FILE2 dimension)")
    s.add_argument("--grid", action="append", default=[], metavar="FIELD=V1,V2", required=True)
    s.add_argument("--seeds", default="0-4")
    s.add_argument("--out", required=True)
    s.add_argument("--test-trials", type=int, default=1000)
    s.add_argument("--test-seed", type=int, default=0)
    s.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE")
    s.add_argument("--batch", type=int, default=16,
                   help="seeds of one combination trained as one batched group, at most; 1: one by one")
    _processes_args(s)
    z = sub.add_parser("zeroshot", help="every learner trained on 3v2, its champions zero-shot on 4v3, 5v3, 6v4")
    z.add_argument("--out", required=True, help="the study's folder (zeroshot.json, results.csv, report.md, runs/)")
    z.add_argument("--learners", type=_list, default=None,
                   help="of neat, hyperneat, cma_es, ppo, ppo_entity, ppo_entity_mix (default: every one)")
    z.add_argument("--seeds", default="0-9", help="each learner's seeds (default 0-9)")
    z.add_argument("--test-trials", type=int, default=1000, help="test states a task (default 1000, Table 3's)")
    z.add_argument("--test-seed", type=int, default=0, help="the test stream's seed (default 0, Table 3's)")
    z.add_argument("--config-of", action="append", default=[], metavar="LEARNER=FILE",
                   help="train LEARNER with FILE instead of its shipped config; repeatable")
    z.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="a config override for every learner's runs; repeatable")
    z.add_argument("--table3", default="docs/table3",
                   help="the Table 3 folder whose no-transfer cells the report divides by (default docs/table3)")
    z.add_argument("--batch", type=int, default=16, help="seeds of one learner trained as one batched group, at most")
    z.add_argument("--report-only", action="store_true", help="write report.md from the folder's files and stop")
    z.add_argument("--merge", default=None, metavar="OTHER",
                   help="join the rows of the study folder OTHER (the same study run elsewhere) to --out's, write the "
                        "report and stop (trains nothing)")
    args = p.parse_args(argv)

    from kx.experiments import processes

    shard = processes.ALONE
    if args.command not in ("report", "confirm", "reproduce", "zeroshot"):
        if args.processes < 1:
            print(f"python -m kx.experiments {args.command}: --processes: allowed an integer >= 1, got "
                  f"{args.processes}", file=sys.stderr)
            return 2
        if args.processes > 1 and processes.ENV_ID not in os.environ:
            if args.distributed or args.num_processes is not None or args.process_id is not None:
                print(f"python -m kx.experiments {args.command}: --processes starts local processes; a launcher's "
                      "(--distributed) or explicit --num-processes and --process-id start them elsewhere: use one",
                      file=sys.stderr)
                return 2
            return processes.launch_local("kx.experiments", _without_processes(list(sys.argv[1:] if argv is None
                                                                                  else argv)), args.processes)
        try:
            shard = processes.initialize(args.out, args.num_processes, args.process_id, args.distributed,
                                         args.start_timeout)
        except processes.ProcessError as e:
            print(f"python -m kx.experiments {args.command}: {e}", file=sys.stderr)
            return 2
    try:
        status = _command(args, shard)
    except BaseException as e:  # the others stop at their next barrier rather than wait for this process
        if shard.meeting is not None:
            shard.meeting.fail(f"{type(e).__name__}: {e}")
        raise
    if shard.meeting is not None:
        if status:
            shard.meeting.fail(f"exit status {status}")
        shard.meeting.close()
    return status


def _command(args: argparse.Namespace, shard) -> int:
    """The command of ``args``, in process ``shard``; its exit status."""
    from kx.evolve.config import ConfigError
    from kx.evolve.errors import RunError
    from kx.experiments.processes import ProcessError

    try:
        if args.command == "report":
            d = pathlib.Path(args.dir)
            if (d / "zeroshot.json").is_file():
                from kx.experiments import zeroshot
                print(zeroshot.write_report(d))
            elif (d / "novelty.json").is_file():
                from kx.experiments import novelty
                print(novelty.write_report(d))
            elif (d / "sweep.json").is_file():
                from kx.experiments import sweep
                print(sweep.write_report(d))
            else:
                from kx.experiments import report
                print(report.write(d))
            return 0
        if args.command == "reproduce":
            from kx.experiments import reproduce
            keys = None if args.row is None else [reproduce.parse_key(t) for t in args.row]
            diffs = reproduce.reproduce(args.dir, keys, args.work)
            for key, diff in diffs.items():
                print(f"{','.join(map(str, key))}: " + ("reproduced (every column but the times)" if not diff
                                                        else "DIFFERS: " + "; ".join(diff)))
            print(f"reproduce: {sum(not d for d in diffs.values())} of {len(diffs)} rows reproduced")
            return 0 if not any(diffs.values()) else 1
        if args.command == "confirm":
            from kx.experiments import confirm, report
            from kx.experiments import table3 as t3
            confirm.run(args.out, t3.Protocol(seed=args.seed, sources="per_target"), args.basis, batch=args.batch,
                        design_only=args.design_only)
            if not args.design_only:
                print(report.write(args.out))
            return 0
        if args.command == "novelty":
            from kx.experiments import novelty
            targets = {}
            for item in args.target_runs:
                m, _, v = item.partition("=")
                if not v.isdigit():
                    raise ValueError(f"--target-runs: allowed METHOD=N,..., got {item!r}")
                targets[m] = int(v)
            novelty.run(args.out, tuple(novelty.ARMS) if args.arms is None else args.arms, args.methods, args.phases,
                        args.runs, targets, args.table3, batch=args.batch, shard=shard)
            if shard.leader:
                print(novelty.write_report(args.out))
            return 0
        if args.command == "zeroshot":
            from kx.evolve.config import parse_seeds
            from kx.experiments import zeroshot
            if args.merge is not None:
                zeroshot.merge(args.out, args.merge)
            elif not args.report_only:
                study = zeroshot.Study(
                    learners=tuple(zeroshot.LEARNERS) if args.learners is None else args.learners,
                    seeds=tuple(parse_seeds(args.seeds)), test_trials=args.test_trials, test_seed=args.test_seed,
                    configs=zeroshot.parse_config_of(args.config_of), overrides=tuple(args.set), table3=args.table3)
                zeroshot.run(args.out, study, batch=args.batch)
            print(zeroshot.write_report(args.out))
            return 0
        for name in ("test_trials",) + (("runs", "source_generations", "target_generations")
                                        if args.command == "table3" else ()):
            if getattr(args, name) < 1:
                raise ValueError(f"--{name.replace('_', '-')}: allowed an integer >= 1, got {getattr(args, name)}")
        if args.command == "table3":
            from kx.experiments import report
            from kx.experiments import table3 as t3
            protocol = t3.Protocol(seed=args.seed, test_trials=args.test_trials,
                                   source_generations=args.source_generations,
                                   target_generations=args.target_generations, overrides=tuple(args.set))
            specs = t3.plan(args.methods, args.targets, args.setups, args.runs)
            try:
                t3.run(args.out, protocol, specs, batch=args.batch, shard=shard)
            except t3.Waiting:  # the runs that could run ran: their rows reported, then the refusal
                if shard.leader:
                    print(report.write(args.out))
                raise
            if shard.leader:
                print(report.write(args.out))
        else:
            from kx.evolve.config import parse_seeds
            from kx.experiments import sweep
            sw = sweep.Sweep(config=args.config, grid=sweep.parse_grid(args.grid), seeds=tuple(parse_seeds(args.seeds)),
                             test_trials=args.test_trials, test_seed=args.test_seed, overrides=tuple(args.set))
            sweep.run(args.out, sw, batch=args.batch, shard=shard)
            if shard.leader:
                print(sweep.write_report(args.out))
        return 0
    except (ValueError, ConfigError, RunError, ProcessError) as e:
        print(f"python -m kx.experiments {args.command}: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    runtime.setup()
    sys.exit(main())

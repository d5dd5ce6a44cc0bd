"""Several processes, one experiment: the protocol and the sweeps dealt over processes that share a folder
(docs/cluster.md).

The same command runs once per process. Each process learns its id and the process count (from explicit
``--num-processes`` and ``--process-id``; from :func:`launch_local`, which starts N local processes for
testing; or, with ``--distributed``, from a cluster launcher's environment: SLURM, Open MPI, MPICH/PMI), and
is then one :class:`Shard` of the experiment: it trains the runs it owns (a run's index modulo the number
of processes, so that a transfer run and its source, which share their index, are in the same process
and no process waits for another's runs), each in its own run directories, and writes their rows to a
results file of its own. Process 0 merges those files into the experiment's one results file
(atomically) at the end, and at the start after a kill, and writes the report.

The processes meet only in the experiment's folder, which they must all see (on a cluster, a shared
filesystem): :class:`Meeting` there gives them a start-up handshake and the few barriers of the protocol's
start and end, as files. No JAX coordination service is involved, so each process's JAX is a one-process
JAX (``jax.process_count() == 1``) and orbax writes each run's checkpoints as it does alone.

Runs are assigned whole rather than sharded along the run axis of one global mesh: a batched group's
runs are already independent programs' worth of work (they share no arithmetic), so a shard of the
group per process computes exactly what a group of those runs computes in one process, with no
collective in the generation step (a global mesh would add one per generation, and a straggler would
hold up every process).
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import os
import pathlib
import secrets
import shutil
import signal
import subprocess
import sys
import threading
import time
from typing import Callable, Sequence

#: the local launcher's environment for its processes (:func:`launch_local`)
ENV_COUNT, ENV_ID = "KX_NUM_PROCESSES", "KX_PROCESS_ID"
#: how many processes the local launcher started on this machine, dealing its cores among them
ENV_LOCAL = "KX_LOCAL_PROCESSES"
#: the cluster launchers whose environment gives a process its id and the count (``--distributed``)
LAUNCHERS = (("SLURM", "SLURM_PROCID", "SLURM_NTASKS"), ("Open MPI", "OMPI_COMM_WORLD_RANK", "OMPI_COMM_WORLD_SIZE"),
             ("MPICH/PMI", "PMI_RANK", "PMI_SIZE"))
#: how long a process waits for the others at start-up (``--start-timeout``), and at a barrier
START_TIMEOUT_S = 300
BARRIER_TIMEOUT_S = 7 * 24 * 3600  # a barrier waits for the slowest process's share of the experiment
#: a process whose heartbeat has not moved for this long (by the waiting process's own clock) is taken as dead
HEARTBEAT_S, DEAD_AFTER_S = 5.0, 120.0
#: the meeting's folder inside the experiment's folder
MEETING_DIR = ".processes"


class ProcessError(RuntimeError):
    """The processes of an experiment could not be brought together (a clear reason, no hang)."""


def _write(path: pathlib.Path, text: str) -> None:
    """``text`` into ``path`` atomically (a reader sees the old file or the new one, whole)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def _read(path: pathlib.Path) -> str | None:
    try:
        return path.read_text()
    except (FileNotFoundError, NotADirectoryError):
        return None


class Meeting:
    """``count`` processes of one experiment meeting as files in ``folder/.processes`` (a folder they all see).

    :meth:`join` is the start-up handshake. Each process other than 0 writes ``join/<id>`` with a nonce of
    its own; process 0 draws a fresh session token, waits for every join file and writes ``session``, the
    token and the nonces it read; a process goes on once ``session`` holds its own nonce, and acknowledges
    with ``ack/<id>``; process 0 goes on once every acknowledgement names its token and the nonce of the
    current join file (it rewrites ``session`` when a join file changes under it). Files an earlier, killed
    attempt left cannot pass for this one's: a nonce and the token are new each time. Process 0 then removes
    the earlier sessions' barrier folders.

    :meth:`wait` is a barrier: ``<token>/<n> <name>/<id>`` per process, passed once all ``count`` exist. Each
    process beats a heartbeat file while it is joined, and writes ``failed/<id>`` when it stops on an error
    (:meth:`fail`); a waiting process raises :class:`ProcessError` at once on a failure file of this session,
    or when a process's heartbeat has not moved for ``dead_after_s`` of its own clock (no clocks are
    compared across hosts)."""

    def __init__(self, folder: str | pathlib.Path, count: int, index: int, *, poll_s: float = 0.2,
                 heartbeat_s: float = HEARTBEAT_S, dead_after_s: float = DEAD_AFTER_S):
        self.dir = pathlib.Path(folder).absolute() / MEETING_DIR
        self.count, self.index = count, index
        self.poll_s, self.heartbeat_s, self.dead_after_s = poll_s, heartbeat_s, dead_after_s
        self.token: str | None = None
        self._numbers = itertools.count()
        self._stop = threading.Event()
        self._beats: dict[int, tuple[str | None, float]] = {}

    # ------------------------------------------------------------------------------------------- start-up
    def join(self, timeout_s: float = START_TIMEOUT_S) -> None:
        """The handshake (see the class); raises :class:`ProcessError` naming the processes that did not
        come within ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        if self.index == 0:
            self._join_as_leader(deadline, timeout_s)
        else:
            self._join_as_member(deadline, timeout_s)
        threading.Thread(target=self._beat, daemon=True, name="kx heartbeat").start()
        if self.index == 0:  # the barriers of earlier attempts: nobody of this session reads them
            for old in self.dir.iterdir():
                if old.is_dir() and old.name.startswith("s-") and old.name != self.token:
                    shutil.rmtree(old, ignore_errors=True)

    def _missing(self, what: str, ids, timeout_s: float) -> ProcessError:
        return ProcessError(f"process {self.index} of {self.count}: {what} {', '.join(map(str, ids))} did not come "
                            f"within {timeout_s:.0f} s (are they running, with --out {self.dir.parent}, a folder "
                            "they all see?)")

    def _join_as_leader(self, deadline: float, timeout_s: float) -> None:
        self.token = f"s-{secrets.token_hex(8)}"
        written = None
        while True:
            nonces = {i: _read(self.dir / "join" / str(i)) for i in range(1, self.count)}
            if all(nonces.values()):
                if nonces != written:
                    _write(self.dir / "session", json.dumps({"token": self.token, "count": self.count,
                                                              "nonces": {str(i): n for i, n in nonces.items()}}))
                    written = nonces
                acks = {i: _read(self.dir / "ack" / str(i)) for i in range(1, self.count)}
                if all(a == f"{self.token} {nonces[i]}" for i, a in acks.items()):
                    return
            elif not self.dir.is_dir():
                self.dir.mkdir(parents=True, exist_ok=True)
            if time.monotonic() > deadline:
                waiting = [i for i in range(1, self.count) if not nonces[i]] or list(range(1, self.count))
                raise self._missing("processes", waiting, timeout_s)
            time.sleep(self.poll_s)

    def _join_as_member(self, deadline: float, timeout_s: float) -> None:
        nonce = secrets.token_hex(8)
        _write(self.dir / "join" / str(self.index), nonce)
        while True:
            text = _read(self.dir / "session")
            if text:
                try:
                    session = json.loads(text)
                except json.JSONDecodeError:
                    session = {}
                if session.get("nonces", {}).get(str(self.index)) == nonce:
                    if session["count"] != self.count:
                        raise ProcessError(f"process {self.index}: process 0 runs with {session['count']} processes, "
                                           f"this one with {self.count} (--num-processes)")
                    self.token = session["token"]
                    _write(self.dir / "ack" / str(self.index), f"{self.token} {nonce}")
                    return
            if time.monotonic() > deadline:
                raise self._missing("process", [0], timeout_s)
            time.sleep(self.poll_s)

    # ------------------------------------------------------------------------------------------- liveness
    def _beat(self) -> None:
        path, n = self.dir / self.token / "alive" / str(self.index), 0
        while not self._stop.is_set():
            _write(path, str(n))
            n += 1
            self._stop.wait(self.heartbeat_s)

    def _check_others(self, arrived: set[str], name: str) -> None:
        self._check_failed()
        now = time.monotonic()
        for i in range(self.count):
            if i == self.index or str(i) in arrived:
                continue
            if (self.dir / self.token / "done" / str(i)).exists():
                self._check_failed()  # a process that fails writes failed/<id> before done/<id>
                raise ProcessError(f"process {i} of {self.count} finished without reaching the barrier {name!r} "
                                   "(the processes ran different commands?)")
            beat = _read(self.dir / self.token / "alive" / str(i))
            last, since = self._beats.get(i, (None, now))
            if beat != last:
                self._beats[i] = (beat, now)
            elif now - since > self.dead_after_s:
                raise ProcessError(f"process {i} of {self.count}: no sign of life for {self.dead_after_s:g} s "
                                   "(killed, or its host lost): stop the others and start the command again")

    def _check_failed(self) -> None:
        failed = self.dir / self.token / "failed"
        if failed.is_dir():
            for f in sorted(failed.iterdir()):
                if not f.name.startswith("."):
                    raise ProcessError(f"process {f.name} of {self.count} stopped: {_read(f) or 'no reason given'}")

    # ------------------------------------------------------------------------------------------- barriers
    def wait(self, name: str, timeout_s: float = BARRIER_TIMEOUT_S) -> None:
        """Waits until every process reaches the barrier ``name`` (every process calls the same barriers in
        the same order: numbered, each used once)."""
        if self.token is None:
            raise ProcessError("a barrier before the processes joined (Meeting.join)")
        here = self.dir / self.token / f"{next(self._numbers)} {name}"
        _write(here / str(self.index), "")
        deadline = time.monotonic() + timeout_s
        while True:
            arrived = {p.name for p in here.iterdir() if not p.name.startswith(".")}
            if len(arrived) >= self.count:
                return
            self._check_others(arrived, name)
            if time.monotonic() > deadline:
                missing = sorted(set(map(str, range(self.count))) - arrived, key=int)
                raise self._missing(f"at barrier {name!r}, processes", missing, timeout_s)
            time.sleep(self.poll_s)

    def fail(self, reason: str) -> None:
        """Tells the others this process stopped on an error (they raise at their next barrier)."""
        if self.token is not None:
            _write(self.dir / self.token / "failed" / str(self.index), reason)
        self.close()

    def close(self) -> None:
        """This process has finished: its heartbeat stops, and nobody takes its silence for death."""
        if self.token is not None and not self._stop.is_set():
            _write(self.dir / self.token / "done" / str(self.index), "")
        self._stop.set()


@dataclasses.dataclass(frozen=True)
class Shard:
    """This process's place among ``count`` processes of one experiment (``index`` 0 is the leader), and
    the :class:`Meeting` it waits at."""

    index: int = 0
    count: int = 1
    meeting: Meeting | None = dataclasses.field(default=None, compare=False, repr=False)

    def owns(self, run: int) -> bool:
        """Whether this process trains the runs of index ``run`` (of every cell: a target and its source)."""
        return run % self.count == self.index

    @property
    def leader(self) -> bool:
        return self.index == 0

    def barrier(self, name: str, timeout_s: float = BARRIER_TIMEOUT_S) -> None:
        """Waits until every process of the experiment reaches the barrier ``name`` (nothing with one process)."""
        if self.count > 1:
            self.meeting.wait(name, timeout_s)

    def describe(self) -> str:
        return f"process {self.index} of {self.count}"


ALONE = Shard()


def from_environment(from_launcher: bool = False) -> tuple[int, int] | None:
    """(count, index) from the local launcher's environment, else, with ``from_launcher``, from a cluster
    launcher's (:data:`LAUNCHERS`); None when neither applies."""
    env = os.environ
    found = [(ENV_ID, ENV_COUNT)] if ENV_ID in env else []
    if not found and from_launcher:
        found = [(rank, size) for _, rank, size in LAUNCHERS if rank in env and size in env][:1]
        if not found:
            names = ", ".join(f"{who} ({rank}, {size})" for who, rank, size in LAUNCHERS)
            raise ProcessError(f"--distributed: no launcher's environment found (read: {names}); elsewhere give "
                               "--num-processes and --process-id")
    if not found:
        return None
    rank, size = found[0]
    if not env[rank].isdigit() or not env[size].isdigit():
        raise ProcessError(f"{rank}, {size}: allowed integers, got {env[rank]!r}, {env[size]!r}")
    return int(env[size]), int(env[rank])


def initialize(folder: str | pathlib.Path, count: int | None = None, index: int | None = None,
               from_launcher: bool = False, timeout_s: float = START_TIMEOUT_S,
               log: Callable[[str], None] = print) -> Shard:
    """Joins the processes of the experiment in ``folder`` and returns this process's :class:`Shard`.
    Explicit ``count`` and ``index``; else the local launcher's environment; else, with ``from_launcher``, a
    cluster launcher's; else one process alone. Raises :class:`ProcessError` with a clear reason on bad
    values, or when the others do not come within ``timeout_s``."""
    if count is None and index is None:
        found = from_environment(from_launcher)
        if found is None:
            return ALONE
        count, index = found
    if count is None or index is None or not (isinstance(count, int) and count >= 1 and 0 <= index < count):
        raise ProcessError(f"--num-processes, --process-id: allowed an integer >= 1 and one in [0, count), got "
                           f"{count} and {index}")
    if count == 1:
        return ALONE
    meeting = Meeting(folder, count, index)
    log(f"kx: process {index} of {count}: meeting the others in {meeting.dir} (every process must start "
        f"within {timeout_s:.0f} s)")
    meeting.join(timeout_s)
    return Shard(index, count, meeting)


def machine_sharers() -> int:
    """How many processes of this experiment share this machine's cores: the local launcher's ``n``
    (:func:`launch_local` deals the cores among them), else 1 (one process alone, or a cluster's processes,
    each on cores of its own)."""
    value = os.environ.get(ENV_LOCAL, "1")
    if not value.isdigit() or int(value) < 1:
        raise ProcessError(f"{ENV_LOCAL}: allowed an integer >= 1, got {value!r}")
    return int(value)


def launch_local(module: str, argv: Sequence[str], n: int, log: Callable[[str], None] = print) -> int:
    """Runs ``python -m module argv`` as ``n`` local processes of one experiment (this machine's cores dealt
    evenly into their host devices), their output prefixed with
    their process id. If one fails, the others are stopped. Returns the first non-zero exit status, or 0."""
    if n < 1:
        raise ProcessError(f"--processes: allowed an integer >= 1, got {n}")
    devices = max(1, (os.cpu_count() or 1) // n)
    procs = []
    for k in range(n):
        flags = [f for f in os.environ.get("XLA_FLAGS", "").split() if "xla_force_host_platform_device_count" not in f]
        env = {**os.environ, ENV_COUNT: str(n), ENV_ID: str(k), ENV_LOCAL: str(n),
               "XLA_FLAGS": " ".join([*flags, f"--xla_force_host_platform_device_count={devices}"])}
        procs.append(subprocess.Popen([sys.executable, "-u", "-m", module, *argv], env=env, stdout=subprocess.PIPE,
                                      stderr=subprocess.STDOUT, text=True, start_new_session=True))
    log(f"kx: {n} local processes ({devices} host device(s) each): "
        f"pids {', '.join(str(p.pid) for p in procs)}")

    def relay(k, p):
        for line in p.stdout:
            log(f"[process {k}] {line.rstrip()}")

    threads = [threading.Thread(target=relay, args=(k, p), daemon=True) for k, p in enumerate(procs)]
    for t in threads:
        t.start()
    status = 0
    try:
        while any(p.poll() is None for p in procs):
            failed = [p for p in procs if p.poll() not in (None, 0)]
            if failed and not status:
                status = failed[0].returncode
                log(f"kx: a process exited with status {status}: stopping the others")
                for p in procs:
                    if p.poll() is None:
                        os.killpg(p.pid, signal.SIGTERM)
            time.sleep(0.2)
    except KeyboardInterrupt:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        raise
    for t in threads:
        t.join(timeout=5)
    return status or next((p.returncode for p in procs if p.returncode), 0)

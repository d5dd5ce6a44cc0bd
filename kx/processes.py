"""Several processes, one experiment: JAX's multi-controller runtime (``jax.distributed``) for the protocol
and the sweeps (docs/cluster.md).

The same command runs once per process. Each process initialises ``jax.distributed`` (from a launcher's
environment: SLURM, Open MPI, Kubernetes, which JAX detects itself; from an explicit coordinator address,
process count and id; or from :func:`launch_local`, which starts N local processes for testing), and is
then one :class:`Shard` of the experiment: it trains the runs it owns (a run's index modulo the number
of processes, so that a transfer run and its source, which share their index, are in the same process
and no process waits for another's runs), each in its own run directories, and writes their rows to a
results file of its own. Process 0 merges those files into the experiment's one results file
(atomically) at the end, and at the start after a kill, and writes the report.

Runs are assigned whole rather than sharded along the run axis of one global mesh: a batched group's
runs are already independent programs' worth of work (they share no arithmetic), so a shard of the
group per process computes exactly what a group of those runs computes in one process, with no
collective in the generation step (a global mesh would add one per generation, and a straggler would
hold up every process). On a cluster the experiment's folder must be on a filesystem every process sees.
"""

from __future__ import annotations

import dataclasses
import itertools
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from typing import Callable, Sequence

#: the local launcher's environment for its processes (:func:`launch_local`)
ENV_COORDINATOR, ENV_COUNT, ENV_ID = "KX_COORDINATOR", "KX_NUM_PROCESSES", "KX_PROCESS_ID"
#: how many processes the local launcher started on this machine, dealing its cores among them
ENV_LOCAL = "KX_LOCAL_PROCESSES"
#: how long a process waits for the coordinator and the others at start-up, and at a barrier
START_TIMEOUT_S = 300
BARRIER_TIMEOUT_S = 7 * 24 * 3600  # a barrier waits for the slowest process's share of the experiment


class ProcessError(RuntimeError):
    """The processes of an experiment could not be brought together (a clear reason, no hang)."""


@dataclasses.dataclass(frozen=True)
class Shard:
    """This process's place among ``count`` processes of one experiment (``index`` 0 is the leader)."""

    index: int = 0
    count: int = 1

    def owns(self, run: int) -> bool:
        """Whether this process trains the runs of index ``run`` (of every cell: a target and its source)."""
        return run % self.count == self.index

    @property
    def leader(self) -> bool:
        return self.index == 0

    def barrier(self, name: str, timeout_s: float = BARRIER_TIMEOUT_S) -> None:
        """Waits until every process of the experiment reaches the barrier ``name`` (nothing with one process)."""
        if self.count == 1:
            return
        from jax._src import distributed  # the coordination service's client (jax has no public barrier
        # with a timeout, and multihost_utils.sync_global_devices is a collective of a multi-process mesh)

        # every process calls the same barriers in the same order: numbered, each id is used once
        distributed.global_state.client.wait_at_barrier(f"kx {next(_BARRIERS)}: {name}", int(timeout_s * 1000))

    def describe(self) -> str:
        return f"process {self.index} of {self.count}"


ALONE = Shard()
_BARRIERS = itertools.count()


def _reachable(address: str, timeout_s: float) -> bool:
    host, _, port = address.rpartition(":")
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            with socket.create_connection((host.strip("[]"), int(port)), timeout=2):
                return True
        except OSError:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.5)


def initialize(coordinator: str | None = None, count: int | None = None, index: int | None = None,
               from_launcher: bool = False, timeout_s: float = START_TIMEOUT_S,
               log: Callable[[str], None] = print) -> Shard:
    """Joins the experiment's processes and returns this process's :class:`Shard` (call before JAX's
    backends start). Explicit ``coordinator`` (``host:port``), ``count`` and ``index``; else the local
    launcher's environment (:data:`ENV_COORDINATOR`, ...); else, with ``from_launcher``, a cluster launcher's
    (SLURM, Open MPI, Kubernetes: ``jax.distributed.initialize()`` detects them); else one process alone.
    A process other than the coordinator that cannot reach it within ``timeout_s`` raises
    :class:`ProcessError` naming the address (JAX itself would abort the process with an RPC deadline)."""
    env = os.environ
    if coordinator is None and ENV_COORDINATOR in env:
        coordinator, count, index = env[ENV_COORDINATOR], int(env[ENV_COUNT]), int(env[ENV_ID])
    if coordinator is None and not from_launcher:
        return ALONE
    import jax
    from jax._src import distributed

    # The coordination service joins the processes and gives them barriers; their computations stay their
    # own. So the backends start first, as one process's: jax.distributed.initialize() would start them as
    # one multi-process mesh (jax.process_count() > 1), and orbax then writes every checkpoint as a
    # collective of all processes, which independent runs cannot be (it refuses a process's own arrays,
    # and leaves the arrays of every process but 0 unwritten).
    jax.local_devices()
    kwargs = {"initialization_timeout": int(timeout_s), "shutdown_timeout_seconds": 30}
    if coordinator is not None:
        if count is None or index is None or not (0 <= index < count):
            raise ProcessError(f"--process-id: allowed an integer in [0, --num-processes), got {index} of {count}")
        if ":" not in coordinator or not coordinator.rpartition(":")[2].isdigit():
            raise ProcessError(f"--coordinator: allowed HOST:PORT, got {coordinator!r}")
        log(f"kx: process {index} of {count}: joining the coordinator at {coordinator} (every process must start "
            f"within {timeout_s:.0f} s)")
        if index != 0 and not _reachable(coordinator, timeout_s):
            raise ProcessError(f"process {index} of {count}: the coordinator at {coordinator} did not answer within "
                               f"{timeout_s:.0f} s (is process 0 running there, and the port open to this host?)")
        distributed.global_state.initialize(coordinator, count, index, **kwargs)
    else:
        log("kx: joining the processes of the cluster launcher (its environment, as jax.distributed reads it)")
        distributed.global_state.initialize(**kwargs)
    state = distributed.global_state
    return Shard(int(state.process_id), int(state.num_processes))


def machine_sharers() -> int:
    """How many processes of this experiment share this machine's cores: the local launcher's ``n``
    (:func:`launch_local` deals the cores among them), else 1 (one process alone, or a cluster's processes,
    each on cores of its own)."""
    value = os.environ.get(ENV_LOCAL, "1")
    if not value.isdigit() or int(value) < 1:
        raise ProcessError(f"{ENV_LOCAL}: allowed an integer >= 1, got {value!r}")
    return int(value)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def launch_local(module: str, argv: Sequence[str], n: int, log: Callable[[str], None] = print) -> int:
    """Runs ``python -m module argv`` as ``n`` local processes of one experiment (a coordinator on a free
    local port, this machine's cores dealt evenly into their host devices), their output prefixed with
    their process id. If one fails, the others are stopped. Returns the first non-zero exit status, or 0."""
    if n < 1:
        raise ProcessError(f"--processes: allowed an integer >= 1, got {n}")
    devices = max(1, (os.cpu_count() or 1) // n)
    address = f"127.0.0.1:{_free_port()}"
    procs = []
    for k in range(n):
        flags = [f for f in os.environ.get("XLA_FLAGS", "").split() if "xla_force_host_platform_device_count" not in f]
        env = {**os.environ, ENV_COORDINATOR: address, ENV_COUNT: str(n), ENV_ID: str(k), ENV_LOCAL: str(n),
               "XLA_FLAGS": " ".join([*flags, f"--xla_force_host_platform_device_count={devices}"])}
        procs.append(subprocess.Popen([sys.executable, "-u", "-m", module, *argv], env=env, stdout=subprocess.PIPE,
                                      stderr=subprocess.STDOUT, text=True, start_new_session=True))
    log(f"kx: {n} local processes ({devices} host device(s) each), coordinator {address}: "
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

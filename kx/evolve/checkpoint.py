"""Run checkpoints: the whole run state as one orbax checkpoint, with a format version, refused with a reason.

A checkpoint ``checkpoints/<n>/`` holds, after ``n`` generations:

* ``state``: the :class:`RunState` pytree (the learner's state, the objective's state, the validated
  champion and the run's counters), written by orbax's ``StandardSave``;
* ``meta``: JSON with the checkpoint format (:data:`FORMAT`), the method (the encoding's name), the
  resolved config, the generation and the figures the preservation policy reads.

orbax writes each checkpoint to a temporary directory (``<n>.orbax-checkpoint-tmp-<time>``) and renames
it when complete, so a kill leaves the whole checkpoint or none, and perhaps the temporary directory:
never read as a checkpoint, and removed when the run is resumed (:func:`clean_tmp`). The last
``keep_checkpoints`` are kept, and the one of the generation whose champion validated best.
:func:`restore` refuses, with the reason, a checkpoint that is missing,
unreadable, of another format, of another method, of other shapes, or whose genotypes break the
encoding's invariants.

:class:`RunLock` keeps a run directory to one writer at a time (``run.lock``).
"""

from __future__ import annotations

import datetime
import fcntl
import json
import os
import pathlib
import shutil
import socket
import time
from typing import Any, Callable

import jax
import numpy as np
from flax import struct

from kx.evolve.errors import RunError

#: the checkpoint format this kx writes and reads; 1 was the NEAT-only layout (no ``format`` in meta), 2
#: had no run key in the run state (``RunState.key``)
FORMAT = 3


@struct.dataclass
class RunState:
    """What a run carries from one generation to the next, checkpointed whole."""

    learner: Any  # the encoding's learner state (NEAT's species and population, CMA-ES's distribution)
    objective: Any  # the objective's state (empty for fitness; the novelty archive later)
    champion: Any  # the validated champion's genotype: the generation champion that validated best
    champion_validation: jax.Array  # float32 its mean fitness on the validation states (-inf before any)
    champion_generation: jax.Array  # int32 the generation it was evaluated in (-1 before any)
    generation: jax.Array  # int32 generations done
    best_so_far: jax.Array  # float32 best training fitness so far (-inf before any)
    key: jax.Array  # uint32[2] the run key (kx.evolve.streams.run_key of the seed): every stream derives from it


#: the lock file of a run directory (:class:`RunLock`)
LOCK_NAME = "run.lock"


class RunLock:
    """One writer per run directory: ``run.lock`` in it, held with ``fcntl.flock`` by the process that
    writes the run, and naming that process (pid, host, start time).

    The kernel drops the lock when its process ends, however it ends, so a lock file that a killed run
    left behind is stale: the next run takes it over, and says whose it was. :meth:`acquire` refuses,
    with a :class:`RunError` naming the holder's pid and host, a lock another process holds (on this
    host, or on another that shares the file system, where ``flock`` reaches it). :meth:`release`
    (or leaving the ``with`` block, also on an exception) removes the file; a directory that
    :meth:`acquire` created and that is still empty is removed too, so a run refused before it wrote
    anything leaves nothing behind."""

    def __init__(self, run_dir, log: Callable[[str], None] | None = None):
        self.run_dir = pathlib.Path(run_dir)
        self.path = self.run_dir / LOCK_NAME
        self.log = log if log is not None else (lambda s: None)
        self._fd: int | None = None
        self._made_dir = False

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()
        return False

    def check(self) -> None:
        """Refuses (:class:`RunError`) a lock another process holds now; takes nothing, creates nothing."""
        try:
            fd = os.open(self.path, os.O_RDONLY)
        except FileNotFoundError:
            return
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise RunError(self._held(fd)) from None
        finally:
            os.close(fd)  # (drops the lock if it was taken here)

    def acquire(self) -> RunLock:
        if self._fd is not None:
            return self
        if not self.run_dir.is_dir():
            self.run_dir.mkdir(parents=True)
            self._made_dir = True
        try:
            while True:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except BlockingIOError:
                    msg = self._held(fd)
                    os.close(fd)
                    raise RunError(msg) from None
                try:  # the holder may have removed the file between our open and our flock: then again
                    if os.fstat(fd).st_ino == os.stat(self.path).st_ino:
                        break
                except FileNotFoundError:
                    pass
                os.close(fd)
        except BaseException:
            self._remove_made_dir()
            raise
        stale = _read_holder(fd)
        me = {"pid": os.getpid(), "host": socket.gethostname(),
              "started": datetime.datetime.now().isoformat(timespec="seconds")}
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(me) + "\n").encode(), 0)
        os.fsync(fd)
        self._fd = fd
        if stale:
            self.log(f"{self.path}: the lock of pid {stale.get('pid', '?')} on {stale.get('host', '?')} (since "
                     f"{stale.get('started', '?')}) was left behind by a process that no longer holds it "
                     "(killed?): taking it over")
        return self

    def release(self) -> None:
        if self._fd is None:
            return
        try:
            os.unlink(self.path)  # while still holding it: whoever opens the path next makes a new file
        except FileNotFoundError:
            pass
        os.close(self._fd)
        self._fd = None
        self._remove_made_dir()

    def _remove_made_dir(self):
        if self._made_dir:
            self._made_dir = False
            try:
                self.run_dir.rmdir()  # only if nothing was written into it
            except OSError:
                pass

    def _held(self, fd: int) -> str:
        holder = {}
        for _ in range(20):  # the holder writes its name just after it takes the lock
            holder = _read_holder(fd)
            if holder:
                break
            time.sleep(0.05)
        who = (f"pid {holder.get('pid', '?')} on host {holder.get('host', '?')} (since {holder.get('started', '?')})"
               if holder else "a process that has not written its pid yet")
        return (f"{self.run_dir} is being written by another process: {who} holds its lock {self.path}; "
                "a run directory takes one process at a time: wait for that one to end, or stop it")


def _read_holder(fd: int) -> dict:
    try:
        d = json.loads(os.pread(fd, 4096, 0).decode() or "{}")
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return {}
    return d if isinstance(d, dict) else {}


#: what orbax's temporary checkpoint directories have in their names (``3.orbax-checkpoint-tmp-<time>``)
TMP_MARK = ".orbax-checkpoint-tmp"


def clean_tmp(run_dir: pathlib.Path) -> list[str]:
    """Removes the temporary directories a kill left in ``checkpoints/`` (orbax's
    ``*.orbax-checkpoint-tmp*``: a checkpoint being written, never complete); returns their names.
    Only with the run directory's lock held: a running writer's temporary directory is its checkpoint."""
    ckpt_dir = pathlib.Path(run_dir) / "checkpoints"
    if not ckpt_dir.is_dir():
        return []
    gone = sorted(p.name for p in ckpt_dir.iterdir() if TMP_MARK in p.name)
    for name in gone:
        p = ckpt_dir / name
        shutil.rmtree(p) if p.is_dir() and not p.is_symlink() else p.unlink()
    return gone


def manager(ckpt_dir: pathlib.Path, keep: int, create: bool = True):
    import orbax.checkpoint as ocp
    from orbax.checkpoint import checkpoint_managers as cm

    policy = cm.AnyPreservationPolicy([
        cm.LatestN(n=keep),
        # the best champion's checkpoint, the earliest on ties (as the run's champion is chosen): orbax
        # keeps the last of a stable ascending sort, so equal scores rank by the negated step
        cm.BestN(get_metric_fn=lambda m: (m["champion_validation"], -m.get("step", 0)), reverse=False, n=1),
    ])
    options = ocp.CheckpointManagerOptions(preservation_policy=policy, create=create,
                                           enable_async_checkpointing=False)
    return ocp.CheckpointManager(pathlib.Path(ckpt_dir).absolute(), options=options, item_names=("state", "meta"))


def steps(run_dir: pathlib.Path) -> list[int]:
    """The complete checkpoints of a run directory, ascending (none: ``[]``)."""
    ckpt_dir = pathlib.Path(run_dir).absolute() / "checkpoints"
    if not ckpt_dir.is_dir():
        return []
    # orbax reads no temporary directory (``<n>.orbax-checkpoint-tmp-...``) as a step; the names are
    # checked again here, so that a half-written checkpoint is never offered to resume from
    complete = {int(p.name) for p in ckpt_dir.iterdir() if p.name.isdigit()}
    return sorted(s for s in manager(ckpt_dir, keep=1_000_000, create=False).all_steps() if s in complete)


def save(mgr, step: int, state: RunState, meta: dict) -> None:
    """Writes checkpoint ``step`` (``meta`` gains the format version) and waits until it is complete."""
    import orbax.checkpoint as ocp

    meta = {"format": FORMAT, **meta}
    mgr.save(step, args=ocp.args.Composite(state=ocp.args.StandardSave(state), meta=ocp.args.JsonSave(meta)),
             metrics={"champion_validation": float(meta["champion_validation"]), "step": int(step)})
    mgr.wait_until_finished()


def _damaged(step: int, ckpt_dir: pathlib.Path, what: str, err: Exception, all_steps: list[int]) -> RunError:
    earlier = [s for s in all_steps if s < step]
    hint = (f"; earlier checkpoints: {earlier} (continue from one with --resume --step {earlier[-1]})" if earlier
            else "; there is no earlier checkpoint")
    return RunError(f"checkpoint {step} in {ckpt_dir} is damaged or unreadable ({what}: {type(err).__name__}: "
                    f"{str(err)[:300]}){hint}")


def restore(run_dir: pathlib.Path, template: RunState, method: str, step: int | None = None,
            check: Callable[[RunState], list[str]] | None = None) -> tuple[int, RunState, dict]:
    """``(step, state, meta)`` of checkpoint ``step`` (default: the latest) of a run directory.

    ``template`` is the run state's shape (``jax.eval_shape`` of the trainer's ``init``); ``method``
    the encoding the caller expects; ``check`` the encoding's invariants of a restored state. Raises
    :class:`RunError` with the reason for anything that cannot be used.
    """
    import orbax.checkpoint as ocp

    ckpt_dir = pathlib.Path(run_dir).absolute() / "checkpoints"
    if not ckpt_dir.is_dir():
        raise RunError(f"{run_dir}: no checkpoints/ directory (not a kx run directory?)")
    mgr = manager(ckpt_dir, keep=1_000_000, create=False)
    all_steps = sorted(mgr.all_steps())
    if not all_steps:
        raise RunError(f"{ckpt_dir}: holds no complete checkpoint")
    step = all_steps[-1] if step is None else step
    if step not in all_steps:
        raise RunError(f"--step {step}: {ckpt_dir} has no checkpoint {step} (there are {all_steps})")
    try:
        meta = mgr.restore(step, args=ocp.args.Composite(meta=ocp.args.JsonRestore()))["meta"]
    except Exception as e:  # noqa: BLE001 - orbax raises many kinds; all mean the same to the user
        raise _damaged(step, ckpt_dir, "its metadata", e, all_steps) from None
    if not isinstance(meta, dict) or "config" not in meta or "generation" not in meta:
        raise RunError(f"checkpoint {step} in {ckpt_dir} is not a kx checkpoint (its metadata has no config)")
    fmt = meta.get("format", 1)
    if fmt != FORMAT:
        raise RunError(f"checkpoint {step} in {ckpt_dir} has checkpoint format {fmt}; this kx reads format "
                       f"{FORMAT} ({'written by an older kx' if fmt < FORMAT else 'written by a newer kx'}); "
                       "start a new run, or use the kx that wrote it")
    saved_method = meta["config"].get("method") if isinstance(meta["config"], dict) else None
    if saved_method != method:
        raise RunError(f"checkpoint {step} in {ckpt_dir} holds a {saved_method!r} run state; this config's "
                       f"method is {method!r}")
    abstract = jax.tree.map(lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype), template)
    try:
        state = mgr.restore(step, args=ocp.args.Composite(state=ocp.args.StandardRestore(abstract)))["state"]
    except Exception as e:  # noqa: BLE001
        if "shape" in str(e).lower() or "structure" in str(e).lower():
            raise RunError(f"checkpoint {step} in {ckpt_dir} does not match this config's shapes: "
                           f"{type(e).__name__}: {str(e)[:500]}") from None
        raise _damaged(step, ckpt_dir, "its run state", e, all_steps) from None
    for path, a, b in zip(jax.tree_util.tree_flatten_with_path(abstract)[0], jax.tree.leaves(abstract),
                          jax.tree.leaves(state)):
        if a.shape != b.shape or a.dtype != b.dtype:
            raise RunError(f"checkpoint {step} in {ckpt_dir}: {jax.tree_util.keystr(path[0])} is "
                           f"{b.dtype}{list(b.shape)}, this config needs {a.dtype}{list(a.shape)}")
    if int(state.generation) != int(meta["generation"]):
        raise RunError(f"checkpoint {step} in {ckpt_dir} is damaged: its state is after generation "
                       f"{int(state.generation)}, its metadata says {meta['generation']}")
    if check is not None:
        errs = check(state)
        if errs:
            raise RunError(f"checkpoint {step} in {ckpt_dir} holds invalid genotypes ({len(errs)} problems; the "
                           f"first: {errs[0]}): damaged, or written by a kx with another genome layout")
    # orbax hands back arrays committed to a device, a fresh run's are not: as they are, the first
    # generation after a resume would compile every program again
    state = jax.tree.map(lambda a: a if jax.dtypes.issubdtype(a.dtype, jax.dtypes.prng_key)
                         else jax.numpy.asarray(np.asarray(a)), state)
    return step, state, meta


def set_aside_after(run_dir: pathlib.Path, step: int) -> pathlib.Path | None:
    """Moves the checkpoints after ``step`` (and the metrics file) to ``abandoned/<time>/`` so that a
    run continued from checkpoint ``step`` can write its own; nothing is deleted. Returns the folder."""
    run_dir = pathlib.Path(run_dir)
    ckpt_dir = run_dir / "checkpoints"
    later = [p for p in ckpt_dir.iterdir() if p.name.isdigit() and int(p.name) > step] if ckpt_dir.is_dir() else []
    if not later:
        return None
    dest = run_dir / "abandoned" / time.strftime("%Y%m%d-%H%M%S")
    (dest / "checkpoints").mkdir(parents=True, exist_ok=True)
    for p in sorted(later):
        shutil.move(str(p), str(dest / "checkpoints" / p.name))
    if (run_dir / "metrics.csv").is_file():
        shutil.copy2(run_dir / "metrics.csv", dest / "metrics.csv")
    return dest

"""The results file every experiment runs into (Table 3's protocol, the novelty study through it, a sweep): one
row per finished run, resumable after a kill, shared by one or several processes.

An experiment opens its :class:`Ledger`, learns from it what is finished, trains the rest in batched groups
(:func:`kx.experiments.measure.train_and_measure`) and appends each finished run's row. Alone, a row goes
straight into ``results.csv`` (written atomically: a kill leaves the file before or after the row). Under
several processes (:mod:`kx.experiments.processes`) each process writes the rows of the runs it owns to a
file of its own beside it (``results.process<k>.csv``), and the leader merges them: at the start, what a
killed run left, and at the end, everyone's, in the experiment's order: the same rows one process writes.
"""

from __future__ import annotations

import dataclasses
import pathlib
from typing import Callable

from kx.experiments import csvfile, processes


@dataclasses.dataclass
class Ledger:
    """``path``'s rows (``fields``; ``what`` names the file in errors), each run once by ``key``, merged from
    the process files in ``order``, under ``shard``. :meth:`start`, then :meth:`open`, :meth:`append` per
    finished run, then :meth:`finish`; ``name`` labels its barriers."""

    path: pathlib.Path
    fields: tuple[str, ...]
    what: str
    key: Callable[[dict], tuple]
    order: Callable[[dict], tuple]
    name: str
    shard: processes.Shard = processes.ALONE
    aliases: dict | None = None  # {column: {old name: name}}: a file written before a rename (csvfile.read)
    rows: list[dict] = dataclasses.field(default_factory=list, init=False)
    _own: list[dict] = dataclasses.field(default_factory=list, init=False)

    def read(self) -> list[dict]:
        return csvfile.read(self.path, self.fields, self.what, self.aliases)

    def merge(self) -> list[dict]:
        """The process files beside the results file merged into it (:func:`csvfile.merge`)."""
        return csvfile.merge(self.path, self.fields, self.what, self.key, self.order, self.aliases)

    def start(self) -> None:
        """The leader merges what a killed run of several processes left; every process waits for it."""
        if self.shard.leader and self.path.parent.is_dir():
            self.merge()
        self.shard.barrier(f"{self.name} start")

    def open(self) -> list[dict]:
        """The finished rows (the list :meth:`append` extends); this process's rows go to its own file."""
        self.rows = self.read()
        self._own = self.rows if self.shard.count == 1 else []
        return self.rows

    @property
    def own_path(self) -> pathlib.Path:
        return self.path if self.shard.count == 1 else csvfile.process_path(self.path, self.shard.index)

    def append(self, row: dict) -> None:
        """A finished run's row, written at once (atomically) to this process's file."""
        if self._own is not self.rows:
            self._own.append(row)
        self.rows.append(row)
        csvfile.write(self.own_path, self.fields, self._own)

    def finish(self) -> list[dict]:
        """Every process's rows: under several processes, once all have finished, the leader merges their files
        and every process reads the merged file."""
        if self.shard.count > 1:
            self.shard.barrier(f"{self.name} end")
            if self.shard.leader:
                self.merge()
            self.shard.barrier(f"{self.name} merged")
            self.rows = self.read()
        return self.rows

"""The results files of ``kx.experiments`` (one row per finished run): read with their columns checked,
written atomically (a temporary file renamed over the old one, so a kill leaves one or the other)."""

from __future__ import annotations

import csv
import io
import pathlib
from typing import Callable

from kx.evolve import outputs as run_outputs
from kx.evolve.errors import RunError


def cell_text(v) -> str:
    """A value as results files write it (a float in 9 significant digits, float32's round trip)."""
    return format(v, ".9g") if isinstance(v, float) else str(v)  # float32 values round-trip in 9 digits


#: columns added to a results file's format after files were written without them, and the value an older
#: file's rows read in them: ``platform`` (where a run was made, :func:`kx.runtime.platform_label`), recorded
#: from 2026-12-07 on; the rows before it were made on AVX-512 Intel Xeons (docs/experiments.md)
ADDED = {"platform": ""}
#: what the reports say of the rows with no ``platform``
UNRECORDED = "before platforms were recorded (2026-12-07; AVX-512 Intel Xeon CPUs)"


def read(path: str | pathlib.Path, fields: tuple[str, ...], what: str, aliases: dict | None = None) -> list[dict]:
    """The rows (strings) of ``path`` in file order, [] when there is no file; ``RunError`` when its
    columns are not ``fields`` (not a ``what``); a file written before a column of :data:`ADDED` reads with its
    value there. ``aliases``: ``{column: {old value: value}}``, the names a file
    written before a rename holds, read as today's."""
    path = pathlib.Path(path)
    if not path.is_file():
        return []
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        have = tuple(reader.fieldnames or ())
        older = have == tuple(f for f in fields if f not in ADDED) != tuple(fields)  # a file from before ADDED's
        if have != tuple(fields) and not older:
            raise RunError(f"{path}: not a {what} (columns {reader.fieldnames}, expected {list(fields)})")
        rows = list(reader)
    if older:
        rows = [{k: r[k] if k in r else ADDED[k] for k in fields} for r in rows]
    for column, names in (aliases or {}).items():
        for r in rows:
            r[column] = names.get(r[column], r[column])
    return rows


def write(path: str | pathlib.Path, fields: tuple[str, ...], rows: list[dict]) -> None:
    """All ``rows`` (their ``fields``) to ``path``, atomically."""
    path = pathlib.Path(path)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: cell_text(r[k] if k in r or k not in ADDED else ADDED[k]) for k in fields})
    run_outputs.write_text(path, buf.getvalue())


# ------------------------------------------------------------------------------------ several processes
#
# Under several processes (kx.experiments.processes) each writes the rows of the runs it trains to a results file of its
# own beside the experiment's (results.process<k>.csv); the leader merges them into the one file.

def process_path(path: str | pathlib.Path, index: int) -> pathlib.Path:
    """The results file process ``index`` writes beside ``path``."""
    path = pathlib.Path(path)
    return path.with_name(f"{path.stem}.process{index}{path.suffix}")


def process_files(path: str | pathlib.Path) -> list[pathlib.Path]:
    path = pathlib.Path(path)
    return sorted(path.parent.glob(f"{path.stem}.process*{path.suffix}"),
                  key=lambda p: int(p.stem.rpartition("process")[2] or 0))


def read_all(path: str | pathlib.Path, fields: tuple[str, ...], what: str, key: Callable[[dict], tuple],
             aliases: dict | None = None) -> list[dict]:
    """The rows of ``path`` and of the process files beside it not yet merged (each run once, the main file's
    first): what every process of an experiment takes as finished."""
    rows = read(path, fields, what, aliases)
    seen = {key(r) for r in rows}
    for p in process_files(path):
        for r in read(p, fields, what, aliases):
            if key(r) not in seen:
                seen.add(key(r))
                rows.append(r)
    return rows


def merge(path: str | pathlib.Path, fields: tuple[str, ...], what: str, key: Callable[[dict], tuple],
          order: Callable[[dict], tuple], aliases: dict | None = None) -> list[dict]:
    """Merges the process files beside ``path`` into it: its rows, then the others' new rows in ``order``,
    written atomically, and only then the process files removed (a kill in between merges them again,
    each run once). Returns the merged rows."""
    path = pathlib.Path(path)
    files = process_files(path)
    rows = read(path, fields, what, aliases)
    if not files:
        return rows
    seen = {key(r) for r in rows}
    new = [r for p in files for r in read(p, fields, what, aliases)]
    added = []
    for r in sorted(new, key=order):
        if key(r) not in seen:
            seen.add(key(r))
            added.append(r)
    write(path, fields, rows + added)
    for p in files:
        p.unlink()
    return rows + added

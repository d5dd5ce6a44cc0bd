"""The results files of ``kx.experiments`` (one row per finished run): read with their columns checked,
written atomically (a temporary file renamed over the old one, so a kill leaves one or the other)."""

from __future__ import annotations

import csv
import io
import pathlib

from kx.evolve import outputs as run_outputs
from kx.evolve.errors import RunError


def cell_text(v) -> str:
    """A value as results files write it (a float in 9 significant digits, float32's round trip)."""
    return format(v, ".9g") if isinstance(v, float) else str(v)  # float32 values round-trip in 9 digits


def read(path: str | pathlib.Path, fields: tuple[str, ...], what: str) -> list[dict]:
    """The rows (strings) of ``path`` in file order, [] when there is no file; ``RunError`` when its
    columns are not ``fields`` (not a ``what``)."""
    path = pathlib.Path(path)
    if not path.is_file():
        return []
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        if tuple(reader.fieldnames or ()) != tuple(fields):
            raise RunError(f"{path}: not a {what} (columns {reader.fieldnames}, expected {list(fields)})")
        return list(reader)


def write(path: str | pathlib.Path, fields: tuple[str, ...], rows: list[dict]) -> None:
    """All ``rows`` (their ``fields``) to ``path``, atomically."""
    path = pathlib.Path(path)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: cell_text(r[k]) for k in fields})
    run_outputs.write_text(path, buf.getvalue())

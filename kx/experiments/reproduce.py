"""Does a committed protocol folder's row come out again? ``python -m kx.experiments reproduce DIR`` trains
chosen runs of ``DIR`` (a table3 or confirmatory folder) again, in a scratch folder that holds DIR's
protocol.json and its results.csv without those rows, through the protocol's own run loop
(:func:`kx.experiments.table3.run`), and compares each new row with the committed one in every column but
the times (:data:`kx.experiments.table3.REPRODUCED`). A transfer run's source, whose run directory the
scratch folder lacks, is trained again first and must reproduce its own row, or the run loop stops there.

By default it takes one run of each method in the folder: run 0 of the method's cheapest recorded cell (a
3v2 source where the method has one, else a no-transfer target). Runs are deterministic on one machine
(docs/training.md); another machine or another JAX may give other rows, and this says which columns differ.
"""

from __future__ import annotations

import pathlib
import shutil
import tempfile
from typing import Callable

from kx import runtime
from kx.evolve.errors import RunError
from kx.experiments import csvfile
from kx.experiments import table3 as t3


def default_keys(rows: list[dict]) -> list[tuple]:
    """One row key per method of ``rows``: run 0 of its first 3v2 source cell, else of its first no-transfer
    target cell, else its first row."""
    keys = []
    for method in dict.fromkeys(r["method"] for r in rows):
        mine = [t3.row_key(r) for r in rows if r["method"] == method]
        pick = ([k for k in mine if k[2] == "source" and k[4] == 0]
                or [k for k in mine if k[2] == "target" and k[1] == "none" and k[4] == 0] or mine)
        keys.append(pick[0])
    return keys


def parse_key(text: str) -> tuple:
    """``"neat,fitness,source,3v2,0"`` (method, setup, phase, target, run) as a row key."""
    parts = [p.strip() for p in text.split(",")]
    if len(parts) != 5 or not parts[4].isdigit():
        raise ValueError(f"--row: allowed METHOD,SETUP,PHASE,TARGET,RUN (neat,fitness,source,3v2,0), got {text!r}")
    return (*parts[:4], int(parts[4]))


def reproduce(folder: str | pathlib.Path, keys: list[tuple] | None = None, work: str | pathlib.Path | None = None,
              log: Callable[[str], None] = print) -> dict[tuple, list[str]]:
    """Trains the runs of ``keys`` (default :func:`default_keys`) of ``folder`` again in ``work`` (default a
    temporary folder, removed after) and returns, per key, the columns where the new row differs from the
    committed one (empty: reproduced; else ending with the platform the row was made on and this one's).
    Raises :class:`RunError` for a key the folder has no row of, or when a source trained again to seed a target
    does not reproduce its row."""
    folder = pathlib.Path(folder)
    protocol = t3.Protocol.read(folder / "protocol.json")
    rows = t3.read_results(folder / "results.csv")
    committed = {t3.row_key(r): r for r in rows}
    keys = default_keys(rows) if keys is None else [tuple(k) for k in keys]
    unknown = [k for k in keys if k not in committed]
    if unknown:
        raise RunError(f"{folder}/results.csv has no row {unknown[0]} (method, setup, phase, target, run)")
    scratch = pathlib.Path(tempfile.mkdtemp(prefix="kx-reproduce-")) if work is None else pathlib.Path(work)
    try:
        if (scratch / "results.csv").exists():
            raise RunError(f"{scratch}: holds a results.csv already (a scratch folder of its own, please)")
        scratch.mkdir(parents=True, exist_ok=True)
        shutil.copy(folder / "protocol.json", scratch / "protocol.json")
        csvfile.write(scratch / "results.csv", t3.FIELDS, [r for r in rows if t3.row_key(r) not in keys])
        log(f"kx reproduce: {len(keys)} runs of {folder} trained again in {scratch}: "
            + "; ".join(t3.RunSpec(*k).describe() for k in keys))
        specs = [t3.RunSpec(*k) for k in keys]
        new = {t3.row_key(r): r for r in t3.run(scratch, protocol, specs, log=log, batch=1,
                                                design_record=_design(folder))}
        here = runtime.platform_label()
        diffs = {k: t3.differences(committed[k], new[k], t3.REPRODUCED) for k in keys}
        for k, d in diffs.items():  # where the rows were made: another platform is a likely cause
            if d:
                d.append(f"the row was made on {committed[k]['platform'] or 'a platform not recorded (before '}"
                         f"{'' if committed[k]['platform'] else '2026-12-07: AVX-512 Intel Xeons)'}, this machine is "
                         f"{here}")
        return diffs
    finally:
        if work is None:
            shutil.rmtree(scratch, ignore_errors=True)


def _design(folder: pathlib.Path) -> dict | None:
    """The design record ``folder``'s protocol.json carries (the run loop checks a folder against it)."""
    import json

    return json.loads((folder / "protocol.json").read_text()).get("design")

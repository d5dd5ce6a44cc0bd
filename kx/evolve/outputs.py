"""What a run writes for its user (a run directory's outputs, not a report): metrics.csv rows, the
progress line, progress.png and atomic JSON files.

Every file is written atomically (a temporary file renamed into place) or appended one fsynced row at
a time, so a kill leaves the old file or the new one. The columns of metrics.csv are the run loop's
(:data:`LOOP_FIELDS`, the same for every method) followed by the encoding's ``metric_fields``.
"""

from __future__ import annotations

import csv
import json
import os
import pathlib

LOOP_FIELDS = (
    "generation", "best_fitness", "mean_fitness", "median_fitness", "best_so_far", "best_score", "mean_score",
    "mean_passes", "mean_dispersion", "mean_ball_centre", "behaviour_spread", "champion_passes", "champion_validation",
    "best_validation", "best_validation_generation", "live_fraction", "live_steps", "eval_seconds",
    "evolve_seconds", "validation_seconds", "generation_seconds")
TIMING_FIELDS = ("eval_seconds", "evolve_seconds", "validation_seconds", "generation_seconds")
#: the columns that describe how a generation was executed, not what it computed: the timings and the
#: live share of the evaluator's lane-steps (a batched group's runs, kx.evolve.group, share one evaluation
#: and its narrowing, so these differ from the same run alone; everything else is the same bit for bit)
EXECUTION_FIELDS = ("live_fraction",) + TIMING_FIELDS


def csv_fields(encoding, objective=None) -> tuple[str, ...]:
    """metrics.csv's columns: the run loop's, the encoding's ``metric_fields``, then the objective's."""
    extra = tuple(encoding.metric_fields) + tuple(getattr(objective, "metric_fields", ()))
    return LOOP_FIELDS + tuple(dict.fromkeys(f for f in extra if f not in LOOP_FIELDS))


def write_json(path: pathlib.Path, obj) -> None:
    """Atomically: a temporary file beside ``path``, flushed to disk, then renamed over it (``os.replace``),
    so a kill or a failure leaves the old file or the new one, never half of one (nor the temporary)."""
    write_text(path, json.dumps(obj, indent=2, sort_keys=True) + "\n")  # dumps first: it may raise


def write_text(path: pathlib.Path, text: str) -> None:
    """``text`` to ``path`` atomically, as :func:`write_json`."""
    path = pathlib.Path(path)
    tmp = path.with_suffix(path.suffix + ".tmp")
    try:
        with tmp.open("w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def read_rows(path: pathlib.Path, below: int) -> list[dict]:
    """The rows of generations before ``below`` (as strings, the way csv reads them)."""
    if not path.is_file():
        return []
    with path.open() as f:
        return [r for r in csv.DictReader(f) if int(r["generation"]) < below]


def write_rows(path: pathlib.Path, rows: list[dict], fields) -> None:
    tmp = path.with_suffix(".csv.tmp")
    with tmp.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        w.writeheader()
        w.writerows(rows)
    os.replace(tmp, path)


def append_row(path: pathlib.Path, row: dict, fields) -> None:
    with path.open("a", newline="") as f:
        csv.DictWriter(f, fieldnames=fields).writerow(row)
        f.flush()
        os.fsync(f.fileno())


class GenerationClock:
    """A run's seconds per generation for its ETA: the mean over the last ``window`` generations this process
    ran, the first excluded (it compiles). Not the mean since the first: a run's episodes lengthen as its
    teams learn to hold the ball, so early generations are short and an average over all of them
    underestimates what is left (a 20-generation run printed "ETA 4 s" at generation 10 while taking
    0.75 s a generation)."""

    def __init__(self, window: int = 5):
        self.window, self.stamps = window, []

    def tick(self, now: float) -> float | None:
        """Records the end of a generation at ``now``; the seconds per generation, or ``None`` after the first."""
        self.stamps = (self.stamps + [now])[-(self.window + 1):]
        if len(self.stamps) < 2:
            return None
        return (self.stamps[-1] - self.stamps[0]) / (len(self.stamps) - 1)


def format_seconds(s: float) -> str:
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.1f} min" if s < 7200 else f"{s / 3600:.1f} h"


def progress_line(row: dict, total: int, eta: float | None, encoding=None) -> str:
    """Generation, best / mean / median training fitness, the validated champion, the encoding's own
    figures (species for NEAT, step size for CMA-ES), the live share of lane-steps and the time."""
    eta_text = "" if eta is None else f"  ETA {format_seconds(eta)}"
    own = encoding.progress(row) if encoding is not None else ""
    if "mean_novelty" in row:  # the novelty hybrid's figures
        nov = (f"novelty {float(row['mean_novelty']):.3f}  archive {int(row['archive_size'])} "
               f"(+{int(row['archive_added'])})")
        own = f"{own}  {nov}" if own else nov
    return (f"gen {int(row['generation']) + 1:3d}/{total}  best {float(row['best_fitness']):.4f}"
            f"  mean {float(row['mean_fitness']):.4f}  median {float(row['median_fitness']):.4f}"
            f"  validation {float(row['champion_validation']):.4f} (best {float(row['best_validation']):.4f}, gen "
            f"{int(row['best_validation_generation']) + 1}){'  ' + own if own else ''}"
            f"  live {float(row['live_fraction']):.0%}  {float(row['generation_seconds']):.2f} s/gen (eval "
            f"{float(row['eval_seconds']):.2f}, evolve {float(row['evolve_seconds']):.3f}){eta_text}")


def plot_progress(rows: list[dict], path: pathlib.Path, title: str, baselines: dict | None = None,
                  lower: str | None = "n_species") -> None:
    """Best, mean and median training fitness, the best so far, each generation's champion on the
    validation states and the run's validated champion, the random and heuristic policies on those
    states, and (below) the encoding's ``lower`` metric (NEAT's species count, CMA-ES's step size)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    g = [int(r["generation"]) + 1 for r in rows]
    col = lambda k: [float(r[k]) for r in rows]  # noqa: E731
    if lower is not None:
        fig, (ax, ax2) = plt.subplots(2, 1, figsize=(7, 6), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    else:
        fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.plot(g, col("best_fitness"), label="best (training trials)", color="C0")
    ax.plot(g, col("best_so_far"), label="best so far (training trials)", color="C0", linestyle="--")
    ax.plot(g, col("mean_fitness"), label="mean", color="C1")
    ax.plot(g, col("median_fitness"), label="median", color="C2")
    ax.plot(g, col("champion_validation"), label="generation champion, validation states", color="C4",
            marker=".", linestyle=":")
    ax.plot(g, col("best_validation"), label="validated champion", color="C4", linewidth=2)
    for i, name in enumerate(("random", "heuristic")):
        if baselines and name in baselines:
            ax.axhline(baselines[name], color="0.5", linestyle=(0, (1, 1 + 2 * i)), linewidth=1,
                       label=f"{name} policy, validation states")
    ax.set_yscale("log")  # random play holds about 0.003, the heuristic about 0.02, a perfect team 1
    ax.set_ylabel("fitness (portion of max hold time, log scale)")
    ax.set_title(title)
    ax.legend(loc="lower right", fontsize="small")
    ax.grid(alpha=0.3)
    if lower is not None:
        ax2.plot(g, col(lower), color="C3")
        ax2.set_ylabel(lower.replace("_", " "))
        ax2.grid(alpha=0.3)
        ax2.set_xlabel("generation")
    else:
        ax.set_xlabel("generation")
    fig.tight_layout()
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=100)
    plt.close(fig)
    os.replace(tmp, path)

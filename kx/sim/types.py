"""Types of the keep-away world: static task shape, traced parameters, episode state.

The split follows gymnax/jumanji: :class:`KeepAwayConfig` fixes every shape (team sizes, field size,
speeds, which unroll loops) and is a hashable static argument; :class:`KeepAwayParams` holds values that
set no shape, traced inside the compiled step (the evaluator takes them from the host: see the class);
:class:`State` is the episode state as a pytree.

Every array of the state is *batch-last*: a per-agent field has shape ``[n, *batch]`` and a per-episode
field ``[*batch]``. A single episode has ``batch == ()``. All rule code is written against this
layout, so the same functions run one episode or thousands without ``vmap`` (vmap works too; the tests
check that both agree).
"""

from __future__ import annotations

import dataclasses
import enum

import jax
import numpy as np
from flax import struct

# Hard limits: the largest team the observation layouts, the integer accumulators and the tests cover.
MAX_KEEPERS = 8
MAX_TAKERS = 8
MIN_FIELD, MAX_FIELD = 8, 40
MAX_ITERATIONS_LIMIT = 100_000
MAX_KICK_NOISE_DEG = 29.0
# Kick noise rotates a pass by atan(s / NOISE_DENOM); its exact integer arithmetic stays inside int32
# only on fields up to this size.
NOISE_DENOM = 16
MAX_NOISE_FIELD = 20
MAX_START_CLEARANCE = 4
MAX_TACKLE_ITERATIONS = 100
# Fixed-point scale of the accumulated distance statistics (integers, so that sums are exact and
# independent of reduction order): distances are stored as round(DIST_SCALE * distance).
DIST_SCALE = 32


class Reason(enum.IntEnum):
    """Why an episode ended (``RUNNING`` while it has not)."""

    RUNNING = 0
    INTERCEPTED = 1  # a taker stood on the ball's cell during a pass
    TACKLED = 2  # a taker contested the holder for tackle_iterations consecutive held iterations
    OUT_OF_FIELD = 3  # a pass left the field
    TIME_LIMIT = 4  # the episode ran max_iterations iterations


class KeepAwayError(ValueError):
    """A task or parameter value out of its allowed range."""


@dataclasses.dataclass(frozen=True)
class KeepAwayConfig:
    """What sets shapes and unrolls loops: a static, hashable argument of every jitted function.

    Attributes:
      n_keepers: keepers K (3..8).
      n_takers: takers T (2..8).
      field_size: the field is ``field_size x field_size`` cells with integer coordinates.
      agent_speed: king moves an agent makes per iteration.
      ball_speed: unit sub-steps the ball advances per iteration.
      n_chasers: takers nearest the ball that chase it; the others mark passing lanes.
    """

    n_keepers: int = 3
    n_takers: int = 2
    field_size: int = 20
    agent_speed: int = 1
    ball_speed: int = 2
    n_chasers: int = 2

    def __post_init__(self) -> None:
        validate_config(self)

    @property
    def name(self) -> str:
        return f"{self.n_keepers}v{self.n_takers}"

    @property
    def n_agents(self) -> int:
        return self.n_keepers + self.n_takers

    @classmethod
    def from_task(cls, task: str, **kwargs) -> "KeepAwayConfig":
        """``KeepAwayConfig.from_task("4v3")``."""
        try:
            k, t = (int(p) for p in task.lower().split("v"))
        except ValueError:
            raise KeepAwayError(
                f"task: {task!r} is not of the form '<keepers>v<takers>' such as '3v2', '4v3', '5v3', '6v4'"
            ) from None
        return cls(n_keepers=k, n_takers=t, **kwargs)


def _check_int(name: str, value, lo: int, hi: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int):
        raise KeepAwayError(f"{name}: must be an integer in [{lo}, {hi}], got {value!r}")
    if not lo <= value <= hi:
        raise KeepAwayError(f"{name}: must be in [{lo}, {hi}], got {value}")


def validate_config(c: KeepAwayConfig) -> None:
    _check_int("n_keepers", c.n_keepers, 3, MAX_KEEPERS)
    _check_int("n_takers", c.n_takers, 2, MAX_TAKERS)
    _check_int("field_size", c.field_size, MIN_FIELD, MAX_FIELD)
    _check_int("agent_speed", c.agent_speed, 1, 4)
    _check_int("ball_speed", c.ball_speed, 1, 8)
    _check_int("n_chasers", c.n_chasers, 1, c.n_takers)
    # Reset needs K distinct keeper cells, then T distinct taker cells outside the holder's clearance
    # square (at most (2*MAX_CLEARANCE+1)^2 cells) and off the keepers.
    free = c.field_size**2 - c.n_keepers - (2 * MAX_START_CLEARANCE + 1) ** 2
    if free < c.n_takers:
        need = c.n_keepers + c.n_takers + (2 * MAX_START_CLEARANCE + 1) ** 2
        raise KeepAwayError(
            f"field_size: {c.field_size}x{c.field_size} is too small to place {c.n_keepers} keepers and "
            f"{c.n_takers} takers with the start clearance; needs at least {need} cells"
        )



@struct.dataclass
class KeepAwayParams:
    """Values that set no shape: the rules (:func:`kx.sim.env.reset`, :func:`kx.sim.env.transition`) read
    them as traced values: a compiled function that takes them as an argument is not recompiled for new values.

    :func:`kx.sim.evaluate.evaluate` takes them as host values: it validates them and packs them, each field
    by its declared type (``int`` as an int32, ``float`` as a float32's bits; :func:`kx.sim.lanes.scalar_fields`,
    which refuses any other type), into the small int32 array its compiled calls read. They must therefore
    be concrete there (not traced, not batched: ``evaluate`` cannot be vmapped over them), and one
    evaluation plays one set of values; a sweep evaluates each value in its own call, reusing the same
    compiled calls. A new field must be declared ``int`` or ``float`` (``| jax.Array`` allowed), whatever
    its default.

    Attributes:
      max_iterations: iterations per trial (the paper: 4500).
      start_clearance: at reset no taker is within this Chebyshev distance of the holder (0..4).
      kick_noise_deg: the largest random rotation of a pass's direction, in degrees (0 = off, <= 29;
        default 10). The rotation is drawn uniformly from the angles atan(s/16), s integer,
        |atan(s/16)| <= this: with 10 degrees, s in -2..2 (0, +-3.6, +-7.1 degrees).
      tackle_iterations: possession is lost once a taker has contested the ball, that is stood on the
        holder's cell at the end of an iteration, for this many consecutive iterations in which a keeper
        held the ball (RoboCup keep-away's turnover counter; default 3). An iteration in which the
        holder is not contested resets the count; while a pass flies it is kept. 1 = the instant tackle
        of the first kx versions.
      taker_reaction_delay: 1 = in the iteration of a kick the takers still go for the kicker's cell and
        react to the pass from the next iteration; 0 = they react at once (then no calibrated
        baseline keeps the ball; see docs/calibration.md).
    """

    max_iterations: int | jax.Array = 4500
    start_clearance: int | jax.Array = 4
    kick_noise_deg: float | jax.Array = 10.0
    taker_reaction_delay: int | jax.Array = 1
    tackle_iterations: int | jax.Array = 3

    @property
    def max_steps_in_episode(self):
        """gymnax's name for an episode's limit: ``max_iterations`` (iterations of the world; an SMDP step of
        :mod:`kx.sim.gym` spans one or more)."""
        return self.max_iterations

    def validate(self) -> "KeepAwayParams":
        """Raises :class:`KeepAwayError` naming the field if a concrete value is out of range."""
        try:
            mi, sc, kn, rd, ti = (float(np.asarray(v)) for v in (
                self.max_iterations, self.start_clearance, self.kick_noise_deg, self.taker_reaction_delay,
                self.tackle_iterations))
        except (TypeError, jax.errors.ConcretizationTypeError, jax.errors.TracerArrayConversionError):
            return self  # traced: validated by the caller that built it
        if mi != int(mi) or not 1 <= mi <= MAX_ITERATIONS_LIMIT:
            raise KeepAwayError(f"max_iterations: must be an integer in [1, {MAX_ITERATIONS_LIMIT}], got {mi:g}")
        if sc != int(sc) or not 0 <= sc <= MAX_START_CLEARANCE:
            raise KeepAwayError(f"start_clearance: must be an integer in [0, {MAX_START_CLEARANCE}], got {sc:g}")
        if rd not in (0.0, 1.0):
            raise KeepAwayError(f"taker_reaction_delay: must be 0 or 1, got {rd:g}")
        if ti != int(ti) or not 1 <= ti <= MAX_TACKLE_ITERATIONS:
            raise KeepAwayError(f"tackle_iterations: must be an integer in [1, {MAX_TACKLE_ITERATIONS}], got {ti:g}")
        if not 0.0 <= kn <= MAX_KICK_NOISE_DEG:
            raise KeepAwayError(f"kick_noise_deg: must be in [0, {MAX_KICK_NOISE_DEG}], got {kn:g}")
        return self


@struct.dataclass
class State:
    """One episode (or a batch, on trailing axes) of keep-away. All integers are int32.

    The ball is either held (``holder >= 0``, the ball on the holder's cell) or in flight. In flight,
    its exact real position is ``origin + substep * dir / |dir|`` (``dir`` an integer vector), and
    ``ball_x, ball_y`` is that position rounded to a cell; see :mod:`kx.sim.geometry`.
    """

    keeper_x: jax.Array  # [K, *B]
    keeper_y: jax.Array  # [K, *B]
    taker_x: jax.Array  # [T, *B]
    taker_y: jax.Array  # [T, *B]
    holder: jax.Array  # [*B] keeper index holding the ball, -1 while in flight
    ball_x: jax.Array  # [*B] ball cell
    ball_y: jax.Array  # [*B]
    origin_x: jax.Array  # [*B] cell the current pass was kicked from
    origin_y: jax.Array  # [*B]
    dir_x: jax.Array  # [*B] integer direction of the current pass
    dir_y: jax.Array  # [*B]
    substep: jax.Array  # [*B] unit sub-steps the current pass has travelled
    kicker: jax.Array  # [*B] keeper who kicked the current pass, -1 if none
    t: jax.Array  # [*B] iterations executed
    done: jax.Array  # [*B] bool
    reason: jax.Array  # [*B] Reason
    passes: jax.Array  # [*B] completed passes
    contest: jax.Array  # [*B] consecutive held iterations a taker has contested the ball (see tackle_iterations)
    dispersion_sum: jax.Array  # [*B] sum over iterations of the sum over keeper pairs of DIST_SCALE*dist
    ball_centre_sum: jax.Array  # [*B] sum over iterations of DIST_SCALE * dist(ball cell, field centre)
    decisions: jax.Array  # [*B] live iterations that began with a keeper holding the ball (its decision)

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return self.holder.shape


@struct.dataclass
class EpisodeStats:
    """What a finished episode reports (all ``[*B]``)."""

    fitness: jax.Array  # iterations survived / max_iterations, in [0, 1]
    iterations: jax.Array  # iterations executed
    reason: jax.Array  # Reason
    passes: jax.Array  # completed passes
    behaviour: jax.Array  # [3, *B] normalised (passes, keeper dispersion, ball distance from centre)
    decisions: jax.Array  # the holders' decisions (live iterations that began with the ball held)

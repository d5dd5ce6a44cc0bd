"""The errors of kx.evolve and the value checks that raise them, one copy for every module.

* :class:`ConfigError`: a config field that does not exist or holds a value out of range (the message
  names the field and what it allows);
* :class:`RunError`: a run directory or checkpoint that cannot be used, with the reason;
* :class:`ObjectiveError`: an objective's config field out of range (:mod:`kx.evolve.objective`; the
  config's validation reports it as a :class:`ConfigError`).

:func:`need` raises the message every field check gives, ``<field>: allowed <what>, got <value>``;
:func:`is_int` and :func:`is_number` are the type checks the config sections use.
"""

from __future__ import annotations

import math
from typing import Any


class ConfigError(ValueError):
    """A config field that does not exist or holds a value out of range."""


class RunError(RuntimeError):
    """A run directory or checkpoint that cannot be used, with the reason."""


class ObjectiveError(ValueError):
    """A config field of an objective out of range (the message names the field)."""


def need(ok: bool, field: str, allowed: str, value: Any, error: type[Exception] = ConfigError) -> None:
    """Raises ``error("<field>: allowed <allowed>, got <value!r>")`` unless ``ok``."""
    if not ok:
        raise error(f"{field}: allowed {allowed}, got {value!r}")


def is_int(v) -> bool:
    """An integer, not a bool."""
    return isinstance(v, int) and not isinstance(v, bool)


def is_number(v) -> bool:
    """A finite int or float, not a bool."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

"""The registry of encodings: which :class:`~kx.evolve.encoding.Encoding` runs ``method = <name>``.

The built-in encodings (:mod:`kx.evolve.encodings`: ``neat``, ``hyperneat``, ``cma_es``, ``ppo``, ``ppo_entity``) are
registered the first time the registry is asked (:func:`get`, :func:`names`); another one is a class and
``register(cls)`` (``tests/test_run_loop.py`` trains one defined in the test file).
"""

from __future__ import annotations

from kx.evolve.encoding import Encoding

ENCODINGS: dict[str, type[Encoding]] = {}

BUILTIN = ("neat", "hyperneat", "cma_es", "ppo", "ppo_entity")


def register(cls: type[Encoding]) -> type[Encoding]:
    """Make ``cls`` available as ``method = cls.name`` in configs (usable as a class decorator)."""
    if not (isinstance(cls.name, str) and cls.name.isidentifier()):
        raise ValueError(f"Encoding.name: allowed a Python identifier, got {cls.name!r}")
    ENCODINGS[cls.name] = cls
    return cls


def get(name: str) -> type[Encoding]:
    """The registered encoding class of ``method = name`` (KeyError if none)."""
    load_builtin()
    return ENCODINGS[name]


def names() -> tuple[str, ...]:
    """The registered methods: the built-in ones first, then any others in registration order."""
    load_builtin()
    return tuple(n for n in BUILTIN if n in ENCODINGS) + tuple(n for n in ENCODINGS if n not in BUILTIN)


_loaded = False


def load_builtin() -> None:
    """Registers the built-in encodings, once (on the first call)."""
    global _loaded
    if _loaded:
        return
    from kx.evolve.encodings.cma_es import CMAESEncoding
    from kx.evolve.encodings.hyperneat import HyperNEATEncoding
    from kx.evolve.encodings.neat import NEATEncoding
    from kx.evolve.encodings.ppo import EntityEncoding, PPOEncoding

    for cls in (CMAESEncoding, NEATEncoding, HyperNEATEncoding, PPOEncoding, EntityEncoding):
        register(cls)
    _loaded = True

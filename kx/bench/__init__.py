"""Benchmarks, one module each: ``python -m kx.bench NAME`` (:mod:`kx.bench.__main__` lists them)."""

"""kx's import graph, read from the source with ``ast`` (nothing is imported, jax least of all).

* No cycle among kx's modules, counting every import: at module level and inside functions (a
  function-level import is still an edge: the modules cannot be understood or moved apart). ``from a
  import b`` counts as importing ``a.b`` when ``a.b`` is a module, else as importing ``a``; relative
  imports are resolved.
* No module uses another kx module's private names (``_x``, not ``__x__``): neither ``from kx.a import
  _x`` nor ``m._x`` where ``m`` names an imported kx module (``import kx.a as m``, ``from kx import a``,
  ``kx.a._x`` after ``import kx.a``).
"""

from __future__ import annotations

import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = "kx"


def _modules() -> dict[str, pathlib.Path]:
    """Every module of kx: its dotted name -> its file (a package is its ``__init__.py``)."""
    out = {}
    for path in sorted((ROOT / PACKAGE).rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _is_package(name: str) -> bool:
    return MODULES[name].name == "__init__.py"


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _resolve(module: str, node: ast.ImportFrom) -> str:
    """The absolute module name of ``node``'s ``from`` part, inside ``module``."""
    if not node.level:
        return node.module or ""
    base = module.split(".") if _is_package(module) else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _kx(name: str) -> bool:
    return name == PACKAGE or name.startswith(PACKAGE + ".")


class _Scan(ast.NodeVisitor):
    """One module's imports of kx modules and its uses of other kx modules' private names."""

    def __init__(self, module: str):
        self.module = module
        self.edges: dict[str, int] = {}  # imported kx module -> first line
        self.private: list[str] = []
        self.aliases: dict[str, str] = {}  # a local name bound to a kx module -> the module

    def _edge(self, target: str, line: int) -> None:
        if target in MODULES and target != self.module:
            self.edges.setdefault(target, line)

    def visit_Import(self, node: ast.Import) -> None:
        for a in node.names:
            if not _kx(a.name):
                continue
            self._edge(a.name, node.lineno)
            if a.asname:
                self.aliases[a.asname] = a.name
            else:  # ``import kx.a.b`` binds ``kx``; ``kx.a.b._x`` is resolved along the attribute chain
                self.aliases[a.name.split(".")[0]] = a.name.split(".")[0]

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        source = _resolve(self.module, node)
        if not _kx(source):
            return
        for a in node.names:
            sub = f"{source}.{a.name}"
            if sub in MODULES:  # ``from kx.a import b``, b a module: importing kx.a.b
                self._edge(sub, node.lineno)
                self.aliases[a.asname or a.name] = sub
            else:
                self._edge(source, node.lineno)
            if _private(a.name) and source != self.module:
                self.private.append(f"{self.module} line {node.lineno}: from {source} import {a.name}")

    def visit_Attribute(self, node: ast.Attribute) -> None:
        chain, n = [], node
        while isinstance(n, ast.Attribute):
            chain.append(n.attr)
            n = n.value
        if isinstance(n, ast.Name) and n.id in self.aliases:
            names = [self.aliases[n.id]] + chain[::-1]
            # the longest prefix that is a module; the name after it is an attribute of that module
            for i in range(len(names), 0, -1):
                mod = ".".join(names[:i])
                if mod in MODULES and i < len(names):
                    attr = names[i]
                    if _private(attr) and mod != self.module:
                        self.private.append(f"{self.module} line {node.lineno}: {mod}.{attr}")
                    break
        # the inner attributes of this chain are the same expression: do not visit them again
        if not isinstance(n, ast.Attribute):
            self.visit(n)


def _scan() -> dict[str, _Scan]:
    out = {}
    for name, path in MODULES.items():
        scan = _Scan(name)
        scan.visit(ast.parse(path.read_text(), filename=str(path)))
        out[name] = scan
    return out


SCANS = _scan()


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Each strongly connected component of more than one module (Tarjan), sorted, with one cycle
    through it."""
    index, low, stack, on, comps = {}, {}, [], set(), []
    counter = [0]

    def connect(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                comps.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            connect(v)
    return sorted(comps)


def _a_cycle(graph: dict[str, set[str]], comp: list[str]) -> list[str]:
    """A shortest cycle through the component's first module (breadth first inside the component)."""
    start, members = comp[0], set(comp)
    prev, frontier = {start: None}, [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(graph[v] & members):
                if w == start:
                    path = [v]
                    while prev[path[-1]] is not None:
                        path.append(prev[path[-1]])
                    return path[::-1] + [start]
                if w not in prev:
                    prev[w] = v
                    nxt.append(w)
        frontier = nxt
    return comp


def test_the_scan_sees_every_kind_of_import():
    # the scanner itself, on a hand-written module: relative, function-level and aliased imports
    src = ("import kx.sim.env\nfrom . import observe as o\nfrom ..neat import presets\n"
           "def f():\n    from kx.sim.evaluate import _advance\n    return o._x, kx.sim.env._y, presets.__doc__\n")
    scan = _Scan("kx.sim.policies")
    scan.visit(ast.parse(src))
    assert set(scan.edges) == {"kx.sim.env", "kx.sim.observe", "kx.neat.presets", "kx.sim.evaluate"}
    assert [p.split(": ")[1] for p in scan.private] == [
        "from kx.sim.evaluate import _advance", "kx.sim.observe._x", "kx.sim.env._y"]


def test_no_import_cycle():
    graph = {m: set(s.edges) for m, s in SCANS.items()}
    comps = _cycles(graph)
    if comps:
        lines = []
        for comp in comps:
            cycle = _a_cycle(graph, comp)
            steps = " -> ".join(f"{a} (line {SCANS[a].edges[b]})" for a, b in zip(cycle, cycle[1:]))
            inside = "; ".join(f"{a} -> {b} (line {SCANS[a].edges[b]})" for a in comp for b in sorted(graph[a])
                               if b in comp)
            lines.append(f"{len(comp)} modules in a cycle: {', '.join(comp)}\n  e.g. {steps} -> {cycle[-1]}\n"
                         f"  its imports: {inside}")
        pytest.fail("import cycles among kx's modules (function-level imports included):\n" + "\n".join(lines))


def test_no_private_names_of_other_modules():
    used = [p for s in SCANS.values() for p in s.private]
    assert not used, "private names of other kx modules used:\n" + "\n".join(used)

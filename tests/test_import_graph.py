"""The package's import graph, read from its source: no cycles, no import of
the package's own modules hidden inside a function, no private name taken from
another module."""

import ast
from pathlib import Path

import ase_spin

PACKAGE = Path(ase_spin.__file__).parent


def _modules():
    """module name -> (path, is a package)."""
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        package = parts[-1] == "__init__"
        if package:
            parts = parts[:-1]
        out[".".join(parts)] = (path, package)
    return out


MODULES = _modules()


def _target(name, package, node):
    if node.level == 0:
        return node.module
    base = name.split(".") if package else name.split(".")[:-1]
    base = base[:len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def imports(name):
    """(imported ase_spin module, imported names, line, at module level) of one module."""
    path, package = MODULES[name]
    tree = ast.parse(path.read_text())
    top = set(map(id, tree.body))
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            target = _target(name, package, node)
            if not (target or "").startswith("ase_spin"):
                continue
            names = [a.name for a in node.names]
            # `from . import x` of a submodule imports the submodule
            subs = [f"{target}.{n}" for n in names if f"{target}.{n}" in MODULES]
            for module in subs or [target]:
                yield module, [] if subs else names, node.lineno, id(node) in top
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("ase_spin"):
                    yield a.name, [], node.lineno, id(node) in top


def graph():
    """module -> the ase_spin modules it imports (a package's import of a
    submodule runs the package's __init__ first: an edge to each parent)."""
    edges = {}
    for name in MODULES:
        out = set()
        for module, _, _, _ in imports(name):
            parts = module.split(".")
            for k in range(1, len(parts) + 1):
                parent = ".".join(parts[:k])
                if parent in MODULES and parent != name and not name.startswith(parent + "."):
                    out.add(parent)
        edges[name] = out
    return edges


def cycles(edges):
    """Every strongly connected set of more than one module (Tarjan)."""
    index, low, stack, on, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                found.append(sorted(group))

    for v in edges:
        if v not in index:
            visit(v)
    return found


def test_no_import_cycles():
    assert cycles(graph()) == []


def test_the_cycle_finder_finds_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_own_module_imported_inside_a_function():
    hidden = [f"{name}:{line} imports {module}" for name in MODULES
              for module, _, line, top in imports(name) if not top]
    assert hidden == []


def _private(n):
    return n.startswith("_") and not n.startswith("__")


def private_uses(name):
    """``from m import _x`` and ``m._x`` (m a module of the package imported by
    name) in one module."""
    for module, names, line, _ in imports(name):
        for n in names:
            if _private(n):
                yield f"{name}:{line} takes {module}.{n}"
    path, package = MODULES[name]
    tree = ast.parse(path.read_text())
    aliases = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            target = _target(name, package, node)
            for a in node.names:
                if f"{target}.{a.name}" in MODULES:
                    aliases[a.asname or a.name] = f"{target}.{a.name}"
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                and node.value.id in aliases and _private(node.attr)):
            yield f"{name}:{node.lineno} uses {aliases[node.value.id]}.{node.attr}"


def test_no_private_name_taken_from_another_module():
    assert [use for name in MODULES for use in private_uses(name)] == []

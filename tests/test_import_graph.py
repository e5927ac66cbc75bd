"""No import circle among the project's modules: the graph of which module imports which (read with ast, imports
inside functions and `if` blocks counted) has no cycle. And envs/ keeps its imports at module top but for a few, each
for a heavy or optional dependency (JAX, MuJoCo, Brax, gymnasium, MuJoCo Playground, dm_control) that a module
loading without it imports only when asked."""

import ast
import os

ROOT = os.path.join(os.path.dirname(__file__), "..")
PACKAGES = ("gsa_jax", "envs")
MAX_ENVS_LAZY_IMPORTS = 12  # imports inside functions in envs/ (each commented with the dependency it defers)


def modules():
    """{dotted name: path} of every module of PACKAGES (a package as its __init__)."""
    found = {}
    for package in PACKAGES:
        for folder, dirs, names in os.walk(os.path.join(ROOT, package)):
            dirs[:] = sorted(d for d in dirs if d != "__pycache__")
            for name in sorted(n for n in names if n.endswith(".py")):
                rel = os.path.relpath(os.path.join(folder, name), ROOT)[:-3].split(os.sep)
                found[".".join(rel[:-1] if rel[-1] == "__init__" else rel)] = os.path.join(folder, name)
    return found


def imported(source, name, is_package, known):
    """The modules among `known` that module `name`'s source imports anywhere (from m import x: m.x where that is a
    module, else m)."""
    here = name if is_package else name.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = here.split(".")[: len(here.split(".")) - node.level + 1]
                base = ".".join(parent + ([base] if base else []))
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in known:  # a name inside a module, or a module outside PACKAGES
                t = t.rpartition(".")[0]
            if t and t != name:
                out.add(t)
    return out


def graph():
    """{module: set of modules it imports} of PACKAGES."""
    mods = modules()
    return {m: imported(open(p).read(), m, p.endswith("__init__.py"), mods) for m, p in mods.items()}


def cycles(edges):
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
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
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def test_no_import_circle():
    g = graph()
    assert len(g) > 80 and "gsa_jax.analysis.robustness.retention" in g["gsa_jax.commands.robustness"]
    assert {"envs.registry", "envs.randomized_env"} <= g["envs.build"] and "envs.task" in g["envs.families.record"]
    found = cycles(g)
    assert not found, "import circles: " + "; ".join(" <-> ".join(c) for c in found)


def test_the_check_sees_a_circle_and_imports_inside_functions():
    known = {"p", "p.a", "p.b", "p.c"}
    source = "import os\nfrom p import c\n\ndef f():\n    from p.b import thing\n"
    assert imported(source, "p.a", False, known) == {"p.b", "p.c"}
    assert imported("from . import a\nfrom .c import x\n", "p.b", False, known) == {"p.a", "p.c"}
    assert cycles({"p.a": {"p.b"}, "p.b": {"p.c"}, "p.c": {"p.a"}, "p": {"p.a"}}) == [["p.a", "p.b", "p.c"]]
    assert cycles({"p.a": {"p.b"}, "p.b": set()}) == []


def imports_in_functions(source):
    """[line] of the import statements inside a function (at any depth) of a module's source."""
    out = []

    def visit(node, inside):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.Import, ast.ImportFrom)) and inside:
                out.append(child.lineno)
            visit(child, inside or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)))

    visit(ast.parse(source), False)
    return out


def test_envs_imports_at_module_top_but_a_few():
    found = {path: lines for m, path in modules().items() if m.split(".")[0] == "envs"
             for lines in [imports_in_functions(open(path).read())] if lines}
    places = [f"{os.path.relpath(p, ROOT)}:{n}" for p, lines in sorted(found.items()) for n in lines]
    assert len(places) <= MAX_ENVS_LAZY_IMPORTS, f"{len(places)} imports inside functions in envs/: {', '.join(places)}"


def test_no_module_of_envs_imports_the_envs_package_back():
    back = sorted(m for m, deps in graph().items() if m.startswith("envs.") and "envs" in deps)
    assert not back, f"modules of envs/ that import the envs package itself (import envs / from envs import <name>): {back}"


def test_the_count_sees_imports_inside_functions():
    source = "import os\n\ndef f():\n    import json\n\n    def g():\n        from x import y\n\nclass A:\n    import re\n"
    assert imports_in_functions(source) == [4, 7]

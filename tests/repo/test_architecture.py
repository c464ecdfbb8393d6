"""The layers point down only (core < sims < studies < app) and no two files import each other in a cycle.

The graph is built from the source (ast), with every import, function-level ones included: a lazy import
is still a dependency.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
LAYERS = ("core", "sims", "studies", "app")
RANK = {name: i for i, name in enumerate(LAYERS)}


def modules() -> dict[str, Path]:
    found: dict[str, Path] = {}
    for layer in LAYERS:
        for path in sorted((ROOT / layer).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join(parts)] = path
    return found


def imports_of(name: str, path: Path, known: set[str]) -> set[str]:
    """The project modules that ``name`` imports (``from a.b import c`` counts a.b.c when it is a module)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(tree):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            targets = [f"{base}.{alias.name}" for alias in node.names] + [base]
        for target in targets:
            parts = target.split(".")
            for i in range(len(parts), 0, -1):
                candidate = ".".join(parts[:i])
                if candidate in known:
                    if candidate != name:
                        out.add(candidate)
                    break
    return out


def graph() -> dict[str, set[str]]:
    found = modules()
    known = set(found)
    return {name: imports_of(name, path, known) for name, path in found.items()}


def test_imports_point_down_the_layers_only() -> None:
    upward = [
        f"{source} imports {target}"
        for source, targets in graph().items()
        for target in targets
        if RANK[target.split(".")[0]] > RANK[source.split(".")[0]]
    ]
    assert not upward, "\n".join(sorted(upward))


def test_the_sage_package_reaches_no_step_loop() -> None:
    """core.sage (learners, gate, world model) implements the loop's protocols and reads its records from
    core.protocol: no file of it imports core.loop, directly or through another project module."""
    g = graph()
    reaching = []
    for source in sorted(name for name in g if name == "core.sage" or name.startswith("core.sage.")):
        seen: set[str] = set()
        todo = [source]
        while todo:
            for target in g.get(todo.pop(), ()):
                if target not in seen:
                    seen.add(target)
                    todo.append(target)
        if "core.loop" in seen:
            reaching.append(source)
    assert not reaching, "core.sage modules that import core.loop: " + ", ".join(reaching)


def test_no_import_cycles_between_files() -> None:
    g = graph()
    # a package's __init__ re-exporting its own modules is not a cycle of files depending on each other
    edges = {
        s: {t for t in ts if not (s == t.rpartition(".")[0] and (ROOT / s.replace(".", "/")).is_dir())}
        for s, ts in g.items()
    }
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:  # Tarjan's strongly connected components
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    import sys

    sys.setrecursionlimit(10_000)
    for v in sorted(edges):
        if v not in index:
            visit(v)
    assert not cycles, "import cycles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


def test_the_checker_sees_an_upward_import(tmp_path: Path) -> None:
    """The checker itself works: a core module importing app is reported."""
    bad = tmp_path / "mod.py"
    bad.write_text("def f():\n    from app.server import make_env\n")
    assert imports_of("core.mod", bad, {"app.server", "core.mod"}) == {"app.server"}

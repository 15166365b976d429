"""The package's layout rules (issue 33): no import cycle, even through imports inside functions; the command lines
each have a main(); the benchmark drivers import the library instead of editing sys.path."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "proto_brax"


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph(package: Path = PACKAGE) -> dict[str, set[str]]:
    """Module -> the package's modules it imports anywhere in its file (module level or inside a function)."""
    files = {module_name(p): p for p in package.rglob("*.py")}
    graph = {}
    for name, path in files.items():
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("proto_brax"):
                for alias in node.names:  # `from proto_brax import envs` imports the module proto_brax.envs
                    sub = f"{node.module}.{alias.name}"
                    deps.add(sub if sub in files else node.module)
            elif isinstance(node, ast.Import):
                deps.update(a.name for a in node.names if a.name in files)
        graph[name] = {d for d in deps if d in files and d != name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while not comp or comp[-1] != v:
                comp.append(stack.pop())
                on_stack.discard(comp[-1])
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_cycle_finder_finds_a_planted_cycle_and_ignores_a_chain():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []


def test_the_package_has_no_import_cycle():
    graph = import_graph()
    assert "proto_brax.experiment.run" in graph and "proto_brax.experiment.plan" in graph["proto_brax.experiment.run"]
    assert cycles(graph) == []


def test_the_library_never_imports_the_command_lines():
    """cli/ sits on top: nothing below it imports it (the ``python -m`` shims aside)."""
    shims = {"proto_brax.sweep", "proto_brax.pretrain", "proto_brax.datasets", "proto_brax.report",
             "proto_brax.checkpoints.__main__"}
    graph = import_graph()
    offenders = {m: sorted(d for d in deps if d.startswith("proto_brax.cli"))
                 for m, deps in graph.items() if not m.startswith("proto_brax.cli") and m not in shims}
    assert {m: d for m, d in offenders.items() if d} == {}


def test_every_command_line_module_has_a_main():
    for path in (PACKAGE / "cli").glob("*.py"):
        tree = ast.parse(path.read_text())
        functions = [n.name for n in tree.body if isinstance(n, ast.FunctionDef)]
        assert "main" in functions or path.name == "__init__.py", path


def test_benchmark_drivers_do_not_edit_sys_path():
    edits = [p.name for p in (ROOT / "benchmarks").glob("*.py") if "sys.path" in p.read_text()]
    assert edits == []

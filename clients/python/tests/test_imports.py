"""The package's modules import one another without a cycle (ARCHITECTURE.md, "no call cycles"):
every ``from .x import`` counts, at the top, inside a function or under TYPE_CHECKING. The graph
is read from the source with ast, not from the code under test."""

import ast
from pathlib import Path
from typing import Dict, List, Set

PACKAGE = Path(__file__).resolve().parent.parent / "clothd"


def _imports() -> Dict[str, Set[str]]:
    graph: Dict[str, Set[str]] = {}
    for path in sorted(PACKAGE.glob("*.py")):
        name = path.stem
        deps: Set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.level == 1:
                if node.module:
                    deps.add(node.module.split(".")[0])
                else:  # from . import x
                    deps.update(a.name for a in node.names)
        graph[name] = deps - {name}
    return graph


def test_the_modules_import_without_a_cycle() -> None:
    graph = _imports()
    assert {"recording", "usd", "client", "stream", "frames", "errors"} <= set(graph)
    cycles: List[List[str]] = []
    state: Dict[str, int] = {}

    def visit(m: str, path: List[str]) -> None:
        state[m] = 1
        for d in sorted(graph.get(m, ())):
            if state.get(d) == 1:
                cycles.append(path[path.index(d):] + [d])
            elif d in graph and not state.get(d):
                visit(d, path + [d])
        state[m] = 2

    for m in sorted(graph):
        if not state.get(m):
            visit(m, [m])
    assert cycles == [], "import cycles: %s" % ["  -> ".join(c) for c in cycles]
    assert "recording" not in graph["usd"]  # the writer reads a RecordingSource, not the module

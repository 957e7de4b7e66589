"""No import circles (issue 24): among the backend's services (top-level or inside a function: a lazy import
only hides a circle), and among the browser's modules (type-only imports count: a view that imports the page
that imports it is a circle the bundler resolves by luck)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    out, state = [], {}

    def visit(n, stack):
        state[n] = 1
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if state.get(m) == 1:
                out.append(stack[stack.index(m):] + [m])
            elif m not in state:
                visit(m, stack)
        stack.pop()
        state[n] = 2

    for n in sorted(graph):
        if n not in state:
            visit(n, [])
    return out


def test_backend_services_have_no_import_circle():
    root = REPO / "backend" / "services"
    mods = {p.stem: p for p in root.glob("*.py") if p.stem != "__init__"}
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for m, p in mods.items():
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 1:
                names = [node.module.split(".")[0]] if node.module else [a.name for a in node.names]
                graph[m] |= {x for x in names if x in mods and x != m}
    assert _cycles(graph) == []


def test_browser_modules_have_no_import_circle():
    src = REPO / "frontend" / "src"
    files = {p.relative_to(src).with_suffix("").as_posix(): p for p in src.rglob("*.ts*")}
    graph: dict[str, set[str]] = {f: set() for f in files}
    pattern = re.compile(r"""(?:import|export)\s[^;]*?from\s+["'](\.[^"']+)["']""", re.S)
    for f, p in files.items():
        for target in pattern.findall(p.read_text()):
            t = (Path(f).parent / target).as_posix()
            t = str(Path(t)).replace("\\\\", "/")
            parts = []
            for part in t.split("/"):
                if part == "..":
                    parts.pop()
                elif part != ".":
                    parts.append(part)
            t = "/".join(parts)
            if t in files:
                graph[f].add(t)
            elif f"{t}/index" in files:
                graph[f].add(f"{t}/index")
    assert len(graph) > 20 and sum(map(len, graph.values())) > 50       # the scan sees the imports
    assert _cycles(graph) == []

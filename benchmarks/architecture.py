"""The shape of the code, measured: per top-level folder its files and lines, the imports of project modules made
inside functions, and the import cycles among project modules (strongly connected components of the import graph,
every import counted, those inside functions too).

    python benchmarks/architecture.py [--root CHECKOUT]

Run it on two checkouts to compare a restructure before and after.
"""

from __future__ import annotations

import argparse
import ast
import json
from collections import defaultdict
from pathlib import Path

FOLDERS = ("pipeline", "cli", "systems", "formats", "tasks", "schemas")
PREFIX = "mocapflow."


def module_name(root: Path, path: Path) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return PREFIX + ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def project_imports(tree: ast.AST, name: str, is_package: bool, modules) -> list[tuple[list[str], bool]]:
    """Per import statement naming a project module: (the modules it imports, whether it sits inside a function).
    ``from package import name`` imports ``package.name`` where that is a module, else ``package``."""
    out = []
    functions = [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]
    inside = {id(n) for f in functions for n in ast.walk(f) if isinstance(n, (ast.Import, ast.ImportFrom))}
    package = name if is_package else name.rsplit(".", 1)[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[:len(package.split(".")) - node.level + 1] + ([base] if base else []))
            targets = sorted({f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names})
        else:
            continue
        targets = [t for t in targets if t.startswith(PREFIX)]
        if targets:
            out.append((targets, id(node) in inside))
    return out


def measure(root: Path) -> dict:
    modules = {module_name(root, p): p for folder in FOLDERS for p in (root / folder).rglob("*.py") if (root / folder).is_dir()}
    graph, report = defaultdict(set), {}
    for folder in FOLDERS:
        files = sorted((root / folder).rglob("*.py")) if (root / folder).is_dir() else []
        statements = inner = 0
        for path in files:
            name = module_name(root, path)
            for targets, in_function in project_imports(ast.parse(path.read_text()), name, path.name == "__init__.py",
                                                        modules):
                statements += 1
                inner += in_function
                for target in targets:
                    while target not in modules and "." in target[len(PREFIX):]:
                        target = target.rsplit(".", 1)[0]  # import package.name of a name: the package
                    if target in modules and target != name:
                        graph[name].add(target)
        report[folder] = {"files": len(files), "lines": sum(len(p.read_text().splitlines()) for p in files),
                          "project_imports": statements, "imports_in_functions": inner}
    cycles = [sorted(c) for c in strongly_connected(graph) if len(c) > 1]
    return {"folders": report, "cycles": cycles}


def strongly_connected(graph: dict) -> list[list[str]]:
    """Tarjan's algorithm, iterative."""
    index, low, on, stack, out, counter = {}, {}, set(), [], [], [0]
    for start in list(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph.get(start, ()))))]
        index[start] = low[start] = counter[0]
        counter[0] += 1
        stack.append(start)
        on.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter[0]
                    counter[0] += 1
                    stack.append(child)
                    on.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on.discard(member)
                    component.append(member)
                    if member == node:
                        break
                out.append(component)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=Path(__file__).parents[1])
    print(json.dumps(measure(parser.parse_args().root), indent=1))


if __name__ == "__main__":
    main()

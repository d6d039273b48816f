"""The package's modules and the imports between them, read from the source (ast): what the
layout and size tests judge. Imports inside functions count: a cycle through one is a cycle."""
import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "densecalib_ros"


def modules(root: Path = PACKAGE) -> dict[str, Path]:
    """Dotted name within `root` -> file, for every module under it."""
    out = {}
    for path in sorted(root.rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def imports(found: dict[str, Path], absolute_prefix: str) -> dict[str, set[str]]:
    """Module -> the modules of `found` it imports (relative imports, or absolute ones under
    absolute_prefix, e.g. "densecalib_ros.core.")."""
    graph = {}
    for name, path in found.items():
        package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        targets = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level and node.level - 1 <= len(package):
                base = package[:len(package) - (node.level - 1)]
                dotted = ".".join(base + (node.module.split(".") if node.module else []))
            elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith(
                    absolute_prefix):
                dotted = node.module[len(absolute_prefix):]
            else:
                continue
            for candidate in [dotted] + [f"{dotted}.{a.name}" for a in node.names]:
                if candidate in found and candidate != name:
                    targets.add(candidate)
        graph[name] = targets
    return graph


def cycles(graph: dict[str, set[str]]) -> list[str]:
    """Each module that reaches itself through the imports, with one such path."""
    out = []
    for start in graph:
        stack, seen = [(start, [start])], set()
        while stack:
            node, path = stack.pop()
            for nxt in graph[node]:
                if nxt == start:
                    out.append(" -> ".join(path + [start]))
                elif nxt not in seen:
                    seen.add(nxt)
                    stack.append((nxt, path + [nxt]))
    return sorted(out)

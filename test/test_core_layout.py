"""The core's layout (core/__init__.py): rooms import only from rooms before them and from the
shared modules; the shared modules import no room; no two modules import each other, even
through others or inside a function."""
import ast
from pathlib import Path

CORE = Path(__file__).resolve().parents[1] / "densecalib_ros" / "core"
ROOMS = ["io", "method", "robust", "monitor", "products", "synthetic"]  # in import order
# the modules that put the rooms together (what a calibration runs and returns)
ENTRY_POINTS = {"pipeline", "recalibration", "job", "calibration_result"}


def _modules() -> dict[str, Path]:
    """Dotted name within core -> file, for every module of core."""
    out = {}
    for path in sorted(CORE.rglob("*.py")):
        parts = list(path.relative_to(CORE).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _imports(modules: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the core modules it imports (at the top or in a function)."""
    graph = {}
    for name, path in modules.items():
        package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        targets = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level and node.level - 1 <= len(package):
                base = package[:len(package) - (node.level - 1)]
                dotted = ".".join(base + (node.module.split(".") if node.module else []))
            elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith(
                    "densecalib_ros.core."):
                dotted = node.module[len("densecalib_ros.core."):]
            else:
                continue
            for candidate in [dotted] + [f"{dotted}.{a.name}" for a in node.names]:
                if candidate in modules and candidate != name:
                    targets.add(candidate)
        graph[name] = targets
    return graph


def _room(module: str) -> str:
    head = module.split(".")[0]
    return head if head in ROOMS else "entry" if head in ENTRY_POINTS else "shared"


def _rank(room: str) -> int:
    return {"shared": -1, "entry": len(ROOMS)}.get(room, ROOMS.index(room) if room in ROOMS else -1)


def test_rooms_import_only_from_rooms_before_them():
    graph = _imports(_modules())
    upward = [f"{a} -> {b}" for a, targets in graph.items() for b in targets
              if _room(a) != _room(b) and _rank(_room(b)) > _rank(_room(a))]
    assert not upward, upward
    assert any(_room(b) == "method" for b in graph["pipeline"])  # the check sees imports


def test_no_module_imports_itself_through_others():
    graph = _imports(_modules())
    cycles = []
    for start in graph:
        stack, seen = [(start, [start])], set()
        while stack:
            node, path = stack.pop()
            for nxt in graph[node]:
                if nxt == start:
                    cycles.append(" -> ".join(path + [start]))
                elif nxt not in seen:
                    seen.add(nxt)
                    stack.append((nxt, path + [nxt]))
    assert not cycles, sorted(cycles)[:10]

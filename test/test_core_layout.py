"""The core's layout (core/__init__.py): rooms import only from rooms before them and from the
shared modules; the shared modules import no room; no two modules import each other, even
through others or inside a function."""
from import_graph import PACKAGE, cycles, imports, modules

CORE = PACKAGE / "core"
ROOMS = ["io", "method", "robust", "monitor", "products", "synthetic"]  # in import order
# the modules that put the rooms together (what a calibration runs and returns)
ENTRY_POINTS = {"stages", "pipeline", "recalibration", "job", "calibration_result"}


def _graph() -> dict[str, set[str]]:
    return imports(modules(CORE), "densecalib_ros.core.")


def _room(module: str) -> str:
    head = module.split(".")[0]
    return head if head in ROOMS else "entry" if head in ENTRY_POINTS else "shared"


def _rank(room: str) -> int:
    return {"shared": -1, "entry": len(ROOMS)}.get(room, ROOMS.index(room) if room in ROOMS else -1)


def test_rooms_import_only_from_rooms_before_them():
    graph = _graph()
    upward = [f"{a} -> {b}" for a, targets in graph.items() for b in targets
              if _room(a) != _room(b) and _rank(_room(b)) > _rank(_room(a))]
    assert not upward, upward
    assert any(_room(b) == "method" for b in graph["pipeline"])  # the check sees imports


def test_no_module_imports_itself_through_others():
    assert not cycles(_graph()), cycles(_graph())[:10]

"""Limits the code keeps (issue 83): every module of the package at most MAX_MODULE_LINES lines,
every function at most MAX_FUNCTION_LINES, and no module importing itself through others, in
any part of the package (core, ros, commands, eval)."""
import ast

from import_graph import PACKAGE, cycles, imports, modules

# A module a reader can hold in mind, and a function that reads on one screen.
MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 80


def test_modules_and_functions_stay_within_their_sizes():
    long_modules, long_functions = [], []
    for name, path in modules().items():
        source = path.read_text()
        if source.count("\n") > MAX_MODULE_LINES:
            long_modules.append(f"{name} ({source.count(chr(10))})")
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                length = node.end_lineno - node.lineno + 1
                if length > MAX_FUNCTION_LINES:
                    long_functions.append(f"{name}.{node.name} ({length})")
    assert not long_modules and not long_functions, (long_modules, long_functions)


def test_no_module_of_the_package_imports_itself_through_others():
    graph = imports(modules(), "densecalib_ros.")
    assert len(graph) > 100 and any(graph.values())  # the check sees the package's imports
    assert not cycles(graph), cycles(graph)[:10]

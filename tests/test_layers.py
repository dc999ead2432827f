"""The layering rules of docs/architecture.md ("Layers"), read from the source with ast.

* the runtime imports nothing from the application, the CLI or the nodes;
* the shared geometry imports nothing of ours but itself;
* a node room never imports another room, nor the application;
* paths.py and options.py (below every layer) import nothing of ours;
* the messages (the bottom layer) import nothing of ours but themselves;
* no import loop between modules, imports inside functions included;
* no source file over 600 lines and no function over 80 lines outside benchmarks/;
* no ``sys.path`` edit anywhere: the folder path is the import path.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
MAX_FILE_LINES = 600
MAX_FUNCTION_LINES = 80


NODES = REPO / "facesculpt" / "nodes"
# Below every layer, importable from anywhere: where files live, how an option is declared.
BOTTOM = ("facesculpt.paths", "facesculpt.options")


def _module_name(path: Path) -> str:
    rel = path.relative_to(REPO).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _sources(*folders: str) -> list[Path]:
    return sorted(p for folder in folders for p in (REPO / folder).rglob("*.py"))


def imported_modules(path: Path, source: str | None = None) -> set[str]:
    """Absolute names of every module ``path`` (or ``source`` as if it were that file) imports,
    relative imports resolved, at any depth."""
    module = _module_name(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text() if source is None else source, str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            found.add(name)
            found.update(f"{name}.{alias.name}" for alias in node.names)
    return found


def _violations(paths: list[Path], forbidden) -> list[str]:
    return [f"{p.relative_to(REPO)} imports {m}" for p in paths for m in sorted(imported_modules(p)) if forbidden(p, m)]


def _under(module: str, prefix: str) -> bool:
    return module == prefix or module.startswith(prefix + ".")


def test_the_runtime_imports_no_node_no_command_and_not_the_cli():
    bad = _violations(_sources("facesculpt/runtime"), lambda p, m: any(
        _under(m, x) for x in ("facesculpt.nodes", "facesculpt.app", "facesculpt.cli", "facesculpt.geometry")))
    assert not bad, bad


def test_the_shared_geometry_imports_only_itself():
    bad = _violations(_sources("facesculpt/geometry"), lambda p, m: _under(m, "facesculpt")
                      and not _under(m, "facesculpt.geometry") and not any(_under(m, b) for b in BOTTOM))
    assert not bad, bad


def test_the_bottom_modules_import_nothing_of_ours():
    """paths.py and options.py sit below every layer (the launch files are data)."""
    layers = ("facesculpt.nodes", "facesculpt.app", "facesculpt.cli", "facesculpt.runtime", "facesculpt.geometry",
              "facesculpt.msgs", "facesculpt.coding")
    bad = _violations([REPO / "facesculpt" / "paths.py", REPO / "facesculpt" / "options.py"],
                      lambda p, m: any(_under(m, x) for x in layers))
    assert not bad, bad


def test_node_rooms_never_import_each_other_nor_the_application():
    def forbidden(path: Path, module: str) -> bool:
        room = path.relative_to(NODES).parts[0]
        if _under(module, "facesculpt.app") or _under(module, "facesculpt.cli"):
            return True
        if not _under(module, "facesculpt.nodes") or module == "facesculpt.nodes":
            return False
        other = module.split(".")[2]
        return other != room and other != "BUILTIN_NODES"

    bad = _violations([p for p in _sources("facesculpt/nodes") if p.parent != NODES], forbidden)
    assert not bad, bad


def test_the_messages_import_only_themselves():
    bad = _violations(_sources("facesculpt/msgs"), lambda p, m: _under(m, "facesculpt")
                      and not _under(m, "facesculpt.msgs"))
    assert not bad, bad


def import_graph() -> dict[str, set[str]]:
    """Module -> the modules of ours it imports (at any depth in the file), each import resolved
    to the deepest module that exists (``from pkg import name`` is ``pkg.name`` when that is a
    module, else ``pkg``); a package's own ``__init__`` seen from inside it is not an edge."""
    modules = {_module_name(p) for p in _sources("facesculpt")}
    graph = {}
    for path in _sources("facesculpt"):
        name, targets = _module_name(path), set()
        for m in imported_modules(path):
            while m and m not in modules:
                m = m.rpartition(".")[0]
            if m and m != name and not name.startswith(m + "."):
                targets.add(m)
        graph[name] = targets
    return graph


def import_loops(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index, low, stack, on_stack, loops, counter = {}, {}, [], set(), [], [0]
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter[0]
                    counter[0] += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[v] = min(low[v], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.append(w)
                    if w == v:
                        break
                if len(component) > 1:
                    loops.append(sorted(component))
    return loops


def test_no_import_loop():
    loops = import_loops(import_graph())
    assert not loops, f"modules that import each other (through imports inside functions too): {loops}"


def test_the_loop_check_sees_a_loop():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert import_loops(graph) == [["a", "b", "c"]]
    assert import_loops({"a": {"b"}, "b": set()}) == []


def test_no_sys_path_edit_anywhere():
    edits = [f"{p.relative_to(REPO)}:{n}" for folder in ("facesculpt", "tests", "examples", "benchmarks", "docs")
             for p in _sources(folder) if p != Path(__file__).resolve()
             for n, line in enumerate(p.read_text().splitlines(), 1) if "sys.path." + "insert" in line
             or "sys.path." + "append" in line]
    assert not edits, edits


def test_the_check_itself_sees_cross_room_imports():
    """The checks above must be able to fail: relative and absolute imports into another room."""
    probe = NODES / "camera" / "probe.py"
    assert "facesculpt.nodes.deformer" in imported_modules(probe, "from ..deformer import EditStack\n")
    assert "facesculpt.nodes.deformer.arap" in imported_modules(probe, "def f():\n    import facesculpt.nodes.deformer.arap\n")
    assert "facesculpt.nodes.camera.sources" in imported_modules(probe, "from .sources import open_source\n")


SOURCE_FOLDERS = ("facesculpt", "tests", "examples")


@pytest.mark.parametrize("folder", SOURCE_FOLDERS)
def test_no_source_file_is_over_600_lines(folder):
    long = [f"{p.relative_to(REPO)}: {n}" for p in _sources(folder)
            if (n := p.read_text().count("\n")) > MAX_FILE_LINES]
    assert not long, long


@pytest.mark.parametrize("folder", SOURCE_FOLDERS)
def test_no_function_is_over_80_lines(folder):
    long = []
    for p in _sources(folder):
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long.append(f"{p.relative_to(REPO)}:{node.lineno} {node.name}: {n} lines")
    assert not long, long

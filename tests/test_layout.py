"""The house rules of the source tree, checked: no import circles among the product's modules,
no module over 600 lines, the engine's passes each in their own module, and every shader a pass
names present where its module says.

Imports are read with `ast` (nothing is imported), counting every import of a `sphrender`
module: module level, under ``TYPE_CHECKING`` and inside functions alike, since a circle that
only a lazy import keeps from failing is still a circle in the design.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: Source folders of the product and the import package each becomes (pyproject's package-dir).
PACKAGES = {
    "core": "sphrender.core",
    "server": "sphrender.server",
    "client": "sphrender.client",
}
MAX_MODULE_LINES = 600


def product_modules() -> dict[str, Path]:
    """Import name -> file, for every module under core/, server/ and client/."""
    modules: dict[str, Path] = {}
    for folder, package in PACKAGES.items():
        for path in sorted((REPO / folder).rglob("*.py")):
            parts = path.relative_to(REPO / folder).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            modules[".".join((package, *parts))] = path
    return modules


def imports_of(path: Path, name: str, known: set[str]) -> set[str]:
    """The product modules `path` (module `name`) imports, anywhere in the file."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{anchor}.{base}" if base else anchor
            # `from pkg import mod` imports the module pkg.mod when there is one
            targets = [base, *(f"{base}.{alias.name}" for alias in node.names)]
        else:
            continue
        found.update(target for target in targets if target in known and target != name)
    return found


def import_graph() -> dict[str, set[str]]:
    modules = product_modules()
    known = set(modules)
    return {name: imports_of(path, name, known) for name, path in modules.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import circle as a path [a, b, ..., a], or None (iterative depth-first search)."""
    state: dict[str, int] = {}  # 1 = on the current path, 2 = finished
    for root in sorted(graph):
        if state.get(root):
            continue
        path = [root]
        stack = [iter(sorted(graph[root]))]
        state[root] = 1
        while stack:
            child = next(stack[-1], None)
            if child is None:
                state[path.pop()] = 2
                stack.pop()
                continue
            if state.get(child) == 1:
                return [*path[path.index(child) :], child]
            if not state.get(child):
                state[child] = 1
                path.append(child)
                stack.append(iter(sorted(graph[child])))
    return None


def test_cycle_finder_finds_a_planted_circle() -> None:
    """The checker itself: a graph with a circle is reported, one without is not."""
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None


def test_no_import_circles_among_product_modules() -> None:
    cycle = find_cycle(import_graph())
    assert cycle is None, "import circle: " + " -> ".join(cycle or [])


#: The import direction, lowest first: a module imports only from its own layer or below.
LAYERS = (
    ("sphrender.core",),
    ("sphrender.client",),
    ("sphrender.server.scene", "sphrender.server.content"),
    (
        "sphrender.server.engine.frame_output",
        "sphrender.server.engine.input_notes",
        "sphrender.server.engine.frame_spacing",
        "sphrender.server.engine.geometry",
    ),
    ("sphrender.server.engine.gpu",),
    ("sphrender.server.engine.lighting", "sphrender.server.engine.sph"),
    ("sphrender.server.engine.passes",),
    ("sphrender.server.engine.renderer",),
    ("sphrender.server.output",),
    ("sphrender.server.service", "sphrender.server.bench", "sphrender.server.cluster"),
    ("sphrender.server.cli",),
)


def layer_of(name: str) -> int:
    for index, prefixes in enumerate(LAYERS):
        if any(name == p or name.startswith(p + ".") for p in prefixes):
            return index
    raise AssertionError(f"{name} is in no layer of tests/test_layout.py LAYERS")


def test_imports_point_down_the_layers() -> None:
    """ARCHITECTURE.md's import direction: cli -> service | bench -> output -> renderer ->
    passes -> lighting | sph -> gpu -> geometry -> scene -> client -> core."""
    for name, imported in import_graph().items():
        if name in (
            "sphrender.server",
            "sphrender.server.engine",
            "sphrender.client",
            "sphrender.core",
        ):
            continue  # the empty package modules
        for target in imported:
            if target in ("sphrender.server", "sphrender.server.engine"):
                continue
            assert layer_of(target) <= layer_of(name), f"{name} imports {target} (upwards)"
    for name, imported in import_graph().items():
        for a, b in (("service", "bench"), ("bench", "service")):
            if name.startswith(f"sphrender.server.{a}"):
                assert not any(t.startswith(f"sphrender.server.{b}") for t in imported), name


def test_client_never_imports_the_server_or_gpu_libraries() -> None:
    """The client side needs only numpy (DESIGN.md): no moderngl, pyopencl or server module."""
    for name, path in product_modules().items():
        if not name.startswith(("sphrender.client", "sphrender.core")):
            continue
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Import | ast.ImportFrom):
                names = (
                    [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module]
                )
                for imported in names:
                    assert not (imported or "").startswith(
                        ("sphrender.server", "moderngl", "pyopencl")
                    ), f"{name} imports {imported}"


@pytest.mark.parametrize("name", sorted(product_modules()))
def test_module_is_readable_in_one_sitting(name: str) -> None:
    lines = product_modules()[name].read_text().count("\n")
    assert lines <= MAX_MODULE_LINES, f"{name}: {lines} lines (limit {MAX_MODULE_LINES})"


def test_product_never_imports_bench_truth() -> None:
    """Ground truth for tests and benchmarks (`bench/analytic.py`) stays out of the product:
    only `sphrender.server.bench` itself may import it."""
    graph = import_graph()
    for name, imported in graph.items():
        if name.startswith("sphrender.server.bench"):
            continue
        assert "sphrender.server.bench.analytic" not in imported, name


def test_each_pass_has_its_module_and_its_shaders_exist() -> None:
    """`server/engine/passes/` holds one module per pass; every shader file a pass module names
    (a string constant ending in .glsl) exists under shaders/."""
    passes = REPO / "server" / "engine" / "passes"
    expected = {"splat", "smooth", "normals", "temperature", "shade", "readback"}
    assert expected <= {p.stem for p in passes.glob("*.py")}
    named = 0
    for path in passes.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            value = node.value if isinstance(node, ast.Constant) else None
            if isinstance(value, str) and value.endswith(".glsl") and "/" in value:
                assert (REPO / "shaders" / value).is_file(), f"{path.name}: {value}"
                named += 1
    assert named >= 8


def test_renderer_orchestrates_only() -> None:
    """`renderer.py` runs the passes in order and draws nothing itself: no GL draw calls,
    framebuffers or shader names of its own."""
    source = (REPO / "server" / "engine" / "renderer.py").read_text()
    for forbidden in (".render(", ".framebuffer(", ".vertex_array(", ".glsl", "moderngl."):
        assert forbidden not in source, forbidden
    assert source.count("\n") < 340


# -- the service by role -------------------------------------------------------------------------

SERVICE = REPO / "server" / "service"
#: A class in server/service does one job: at most this many methods and this many attributes.
MAX_CLASS_METHODS = 15
MAX_CLASS_ATTRIBUTES = 15


def class_sizes(path: Path) -> dict[str, tuple[int, int]]:
    """Class name -> (methods, attributes) for every class in `path`. Methods: the functions
    defined in the class body (properties included). Attributes: names assigned in the class
    body plus every ``self.name`` assigned in its methods."""
    sizes: dict[str, tuple[int, int]] = {}
    for node in ast.walk(ast.parse(path.read_text())):
        if not isinstance(node, ast.ClassDef):
            continue
        methods = [n for n in node.body if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)]
        attributes: set[str] = set()
        for item in node.body:
            if isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
                attributes.add(item.target.id)
            elif isinstance(item, ast.Assign):
                attributes.update(t.id for t in item.targets if isinstance(t, ast.Name))
        for method in methods:
            for sub in ast.walk(method):
                targets: list[ast.AST] = []
                if isinstance(sub, ast.Assign):
                    targets = [e for t in sub.targets for e in ast.walk(t)]
                elif isinstance(sub, ast.AnnAssign | ast.AugAssign):
                    targets = [sub.target]
                for target in targets:
                    if (
                        isinstance(target, ast.Attribute)
                        and isinstance(target.value, ast.Name)
                        and target.value.id == "self"
                    ):
                        attributes.add(target.attr)
        sizes[node.name] = (len(methods), len(attributes))
    return sizes


def test_service_classes_each_do_one_job() -> None:
    """No class in server/service has more than MAX_CLASS_METHODS (15) methods or
    MAX_CLASS_ATTRIBUTES (15) attributes (see `class_sizes` for what counts), and no two
    classes there share a name."""
    seen: dict[str, Path] = {}
    for path in sorted(SERVICE.rglob("*.py")):
        for name, (methods, attributes) in class_sizes(path).items():
            where = f"{path.relative_to(REPO)}: {name}"
            assert methods <= MAX_CLASS_METHODS, f"{where} has {methods} methods"
            assert attributes <= MAX_CLASS_ATTRIBUTES, f"{where} has {attributes} attributes"
            assert name not in seen, f"{where}: also a class in {seen[name].relative_to(REPO)}"
            seen[name] = path


def test_class_size_counter_counts_methods_and_attributes(tmp_path: Path) -> None:
    source = tmp_path / "sample.py"
    source.write_text(
        "class A:\n    x: int = 0\n    def __init__(self):\n        self.a = self.b = 1\n"
        "        self.c: int = 2\n    def f(self):\n        self.a += 1\n        self.d, y = 1, 2\n"
    )
    assert class_sizes(source) == {"A": (2, 5)}


#: The service's subfolders and a word each of their docstrings must say (their role).
SERVICE_ROLES = {"http": "HTTP", "stream": "stream", "render": "render"}


def test_service_is_arranged_by_role() -> None:
    """server/service/ holds the transports and the render side in subfolders named by their
    role, each a package that says what it is; what they share stays at the top."""
    for folder, word in SERVICE_ROLES.items():
        init = SERVICE / folder / "__init__.py"
        assert init.is_file(), folder
        docstring = ast.get_docstring(ast.parse(init.read_text())) or ""
        assert word.lower() in docstring.lower(), f"{folder}/__init__.py: {docstring!r}"
    top = {p.stem for p in SERVICE.glob("*.py")} - {"__init__"}
    assert not {name for name in top if name.startswith(("http", "stream", "render"))}, top
    assert (SERVICE / "render" / "messages.py").is_file()
    assert (SERVICE / "http" / "viewer_page" / "index.html").is_file()


def test_render_messages_are_typed_and_checked_without_ignores(tmp_path: Path) -> None:
    """The messages between the worker and the render process: frozen dataclasses, no
    `type: ignore` anywhere on that path, and mypy (against the real package, as
    test_static_checks builds it) finds nothing in them."""
    import os
    import shutil
    import subprocess
    import sys

    render = SERVICE / "render"
    for name in ("messages", "process", "handle", "worker", "in_flight", "outcomes"):
        assert "type: ignore" not in (render / f"{name}.py").read_text(), name
    tree = ast.parse((render / "messages.py").read_text())
    classes = [n for n in tree.body if isinstance(n, ast.ClassDef) and not n.name.startswith("_")]
    for node in classes:
        assert any("frozen=True" in ast.unparse(d) for d in node.decorator_list), node.name
    mypy = shutil.which("mypy", path=str(Path(sys.executable).parent)) or shutil.which("mypy")
    if mypy is None:
        pytest.skip("mypy is not installed")
    package = tmp_path / "sphrender"
    package.mkdir()
    for folder in PACKAGES:
        (package / folder).symlink_to(REPO / folder, target_is_directory=True)
    result = subprocess.run(
        [
            mypy,
            "--cache-dir",
            str(tmp_path / "cache"),
            "--follow-imports=silent",
            "-m",
            "sphrender.server.service.render.messages",
        ],
        cwd=REPO,
        env={**os.environ, "MYPYPATH": str(tmp_path)},
        capture_output=True,
        text=True,
        check=False,
    )
    assert result.returncode == 0, result.stdout + result.stderr

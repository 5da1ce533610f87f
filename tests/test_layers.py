"""The package's layers point one way: no module imports a higher layer, no import circle, no private reach-ins.

The layer order is written once, in ``optitact/__init__.py``'s docstring; :data:`LAYERS` is the same
list as data. Every import counts, at module level or inside a function (a function-level import of
a higher layer is still an upward dependency). The package is read as source with :mod:`ast`,
nothing is imported.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Where each part of the package lives in the repository (render/, calib/, forces/ install into optitact).
SOURCE_DIRS = {"optitact": ROOT / "optitact", "optitact.render": ROOT / "render",
               "optitact.calib": ROOT / "calib", "optitact.forces": ROOT / "forces"}

#: Bottom to top; a module may import its own layer and those below. Prefixes name subpackages or modules.
LAYERS = [
    ("foundation", ("optitact.errors", "optitact._validate", "optitact._optional", "optitact.dask_client")),
    ("optics", ("optitact.optics",)),
    ("io", ("optitact.io",)),
    ("pipeline", ("optitact.pipeline",)),
    ("render, forces", ("optitact.render", "optitact.forces")),
    ("calib", ("optitact.calib",)),
    ("registration", ("optitact.registration",)),
    ("orchestration", ("optitact.live", "optitact.taxels", "optitact.finger")),
    ("cli, studies", ("optitact.cli", "optitact.studies", "optitact.__main__")),
]


def _modules() -> dict[str, tuple[Path, bool]]:
    out = {}
    for package, folder in SOURCE_DIRS.items():
        for path in folder.rglob("*.py"):
            rel = path.relative_to(folder).with_suffix("").parts
            name = ".".join((package, *rel))
            is_pkg = rel[-1] == "__init__"
            if is_pkg:
                name = name.rsplit(".", 1)[0]
            if package == "optitact" and rel[0] in ("render", "calib", "forces"):
                continue
            out[name] = (path, is_pkg)
    return out


MODULES = _modules()
TREES = {name: ast.parse(path.read_text(), str(path)) for name, (path, _) in MODULES.items()}


def layer(module: str) -> int | None:
    """The layer index of ``module`` (the longest matching prefix); None for the package's own face."""
    best, found = -1, None
    for i, (_, prefixes) in enumerate(LAYERS):
        for p in prefixes:
            if (module == p or module.startswith(p + ".")) and len(p) > best:
                best, found = len(p), i
    return found


def _absolute(module: str, is_pkg: bool, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = module.split(".") if is_pkg else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def imports(module: str) -> list[tuple[int, str, list[str]]]:
    """``(line, imported module, names)`` for every import of the package's own modules in ``module``."""
    _, is_pkg = MODULES[module]
    out = []
    for node in ast.walk(TREES[module]):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("optitact"):
                    out.append((node.lineno, a.name, []))
        elif isinstance(node, ast.ImportFrom):
            target = _absolute(module, is_pkg, node)
            if not target.startswith("optitact"):
                continue
            names = [a.name for a in node.names]
            subs = [f"{target}.{n}" for n in names if f"{target}.{n}" in MODULES]
            if subs:  # `from optitact.calib import sets`: the submodule is what is imported
                out += [(node.lineno, s, []) for s in subs]
                names = [n for n in names if f"{target}.{n}" not in MODULES]
                if not names:
                    continue
            out.append((node.lineno, target, names))
    return out


def _target(name: str) -> str | None:
    """The module an imported dotted name resolves to (the longest known prefix)."""
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        cand = ".".join(parts[:k])
        if cand in MODULES:
            return cand
    return None


def test_every_module_has_a_layer():
    missing = [m for m in MODULES if m != "optitact" and layer(m) is None]
    assert not missing, f"modules in no layer of LAYERS: {missing}"


def test_the_layer_order_is_the_one_the_package_docstring_states():
    doc = ast.get_docstring(TREES["optitact"])
    positions = []
    for _, prefixes in LAYERS:
        pos = [doc.find(f":mod:`{p}`") for p in prefixes if f":mod:`{p}`" in doc]
        positions.append(min(pos) if pos else doc.find(f"``{prefixes[0]}``"))
    assert all(p >= 0 for p in positions), list(zip(LAYERS, positions, strict=True))
    assert positions == sorted(positions), "optitact/__init__.py lists the layers in another order"


def test_no_module_imports_a_higher_layer():
    bad = []
    for module in MODULES:
        mine = layer(module)
        if mine is None:
            continue
        for line, name, _ in imports(module):
            target = _target(name)
            theirs = None if target is None else layer(target)
            if theirs is not None and theirs > mine:
                where = f"{MODULES[module][0].relative_to(ROOT)}:{line}"
                bad.append(f"{where} ({LAYERS[mine][0]}) imports {target} ({LAYERS[theirs][0]})")
    assert not bad, "\n".join(bad)


def test_no_import_circle():
    graph = {m: set() for m in MODULES}
    for module in MODULES:
        for _, name, _ in imports(module):
            target = _target(name)
            if target is not None and target != module and target != "optitact":
                graph[module].add(target)
    # Tarjan's strongly connected components
    index, low, on, stack, comps, counter = {}, {}, set(), [], [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                comps.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    assert not comps, f"import circles: {comps}"


def test_no_private_name_is_imported_from_another_module():
    bad = []
    for module in MODULES:
        for line, name, names in imports(module):
            target = _target(name)
            if target is None or target == module:
                continue
            private = [n for n in names if n.startswith("_") and not n.startswith("__")]
            if private:
                bad.append(f"{MODULES[module][0].relative_to(ROOT)}:{line} imports {private} from {target}")
    assert not bad, "\n".join(bad)


def _private_members_defined(tree: ast.Module) -> set[str]:
    """Private attribute names a module's own classes define (methods, class attributes, ``self._x = ...``)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name.startswith("_"):
            out.add(node.name)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store) and node.attr.startswith("_"):
            out.add(node.attr)
        elif isinstance(node, ast.ClassDef):
            for item in node.body:
                if isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
                    out.add(item.target.id)
                elif isinstance(item, ast.Assign):
                    out.update(t.id for t in item.targets if isinstance(t, ast.Name))
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) \
                and node.func.attr == "__setattr__" and len(node.args) >= 2 \
                and isinstance(node.args[1], ast.Constant) and isinstance(node.args[1].value, str):
            out.add(node.args[1].value)  # object.__setattr__(self, "_x", ...) in frozen dataclasses
    return out


#: Underscored names that are public API of the standard library (namedtuples' methods, sys._getframe).
PUBLIC_UNDERSCORED = {"_replace", "_asdict", "_fields", "_make", "_field_defaults", "_getframe"}


def test_no_object_reaches_into_another_modules_private_attributes():
    """``obj._x`` only where ``_x`` belongs to a class of the same module (its own or a sibling instance)."""
    bad = []
    for module, tree in TREES.items():
        own = _private_members_defined(tree)
        for node in ast.walk(tree):
            if not isinstance(node, ast.Attribute) or not node.attr.startswith("_"):
                continue
            if node.attr.startswith("__"):
                continue
            if isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"):
                continue
            if node.attr in own or node.attr in PUBLIC_UNDERSCORED:
                continue
            bad.append(f"{MODULES[module][0].relative_to(ROOT)}:{node.lineno} .{node.attr}")
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("module", ["optitact.io", "optitact.pipeline", "optitact.live"])
def test_a_subpackage_and_its_old_module_name_do_not_both_exist(module):
    """``optitact/io.py`` beside ``optitact/io/`` would shadow one with the other."""
    path = MODULES[module][0]
    assert path.name == "__init__.py" and not path.parent.with_suffix(".py").exists()


def _defined(tree: ast.Module) -> set[str]:
    out = set()
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            out.add(node.name)
        elif isinstance(node, ast.Assign):
            out.update(n.id for t in node.targets for n in ast.walk(t) if isinstance(n, ast.Name))
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            out.add(node.target.id)
    return out


#: Package faces that export names of their own private modules (one home each: the package).
FACES = {"optitact.studies": "optitact.studies._protocol"}


def test_every_public_name_has_one_home():
    """A module's ``__all__`` lists only what the module itself defines: no re-exports."""
    bad = []
    for module, tree in TREES.items():
        names = []
        for node in tree.body:
            target = node.targets[0] if isinstance(node, ast.Assign) else getattr(node, "target", None)
            is_all = isinstance(target, ast.Name) and target.id == "__all__"
            if is_all and isinstance(node.value, (ast.List, ast.Tuple)):
                names += [e.value for e in node.value.elts]
        if "lazy_loader" in ast.unparse(tree):  # a subpackage listing its submodules
            continue
        home = TREES[FACES[module]] if module in FACES else tree
        bad += [f"{module}.{n}" for n in names if n not in _defined(home)]
    assert not bad, f"exported but defined elsewhere (a re-export): {bad}"

"""The documentation builds with ``sphinx-build -W`` and gives every public name an API page.

One build per session (a module fixture, into a temporary folder): the build itself is the
first test, and the API pages it wrote are checked against every public module's ``__all__``
(``docs/api/index.rst`` lists the modules; its templates give each name a page).
"""

from __future__ import annotations

import importlib
import inspect
import pathlib
import pkgutil
import subprocess
import sys

import pytest

pytest.importorskip("sphinx", reason="the docs extra is not installed (pip install -e '.[docs]')")
pytest.importorskip("numpydoc", reason="the docs extra is not installed (pip install -e '.[docs]')")
pytest.importorskip("myst_nb", reason="the docs extra is not installed (pip install -e '.[docs]')")
pytest.importorskip("pydata_sphinx_theme", reason="the docs extra is not installed (pip install -e '.[docs]')")

DOCS = pathlib.Path(__file__).resolve().parents[2] / "docs"
PACKAGES = ("optitact", "optitact.render", "optitact.calib", "optitact.forces")


@pytest.fixture(scope="module")
def build(tmp_path_factory):
    out = tmp_path_factory.mktemp("docs-html")
    cmd = [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
           "-d", str(out / ".doctrees"), str(DOCS), str(out)]
    result = subprocess.run(cmd, capture_output=True, text=True)
    return result, out


def _public_modules() -> list[str]:
    """Every module of the installed package whose dotted name has no private part."""
    names = set()
    for pkg in PACKAGES:
        mod = importlib.import_module(pkg)
        names.add(pkg)
        names.update(m.name for m in pkgutil.walk_packages(mod.__path__, prefix=f"{pkg}.")
                     if not m.name.endswith(".__main__"))
    return sorted(n for n in names if not any(part.startswith("_") for part in n.split(".")))


def _public_names(module) -> list[str]:
    """A module's ``__all__``; without one, the public functions and classes it defines."""
    if hasattr(module, "__all__"):
        return list(module.__all__)
    return [n for n, v in vars(module).items() if not n.startswith("_")
            and (inspect.isfunction(v) or inspect.isclass(v)) and v.__module__ == module.__name__]


def _expected_pages() -> set[str]:
    """The API pages the promise needs: each public name's, and each module's that has names."""
    pages = set()
    for name in _public_modules():
        module = importlib.import_module(name)
        names = _public_names(module)
        for attr in names:
            value = getattr(module, attr)
            if inspect.ismodule(value):  # a subpackage's lazy __all__ lists its modules
                continue
            pages.add(f"{name}.{attr}")
        if any(not inspect.ismodule(getattr(module, attr)) for attr in names):
            pages.add(name)
    return pages


def test_sphinx_build_has_no_warnings(build):
    result, _ = build
    assert result.returncode == 0, (result.stdout + result.stderr)[-20000:]


def test_every_public_name_has_an_api_page(build):
    _, out = build
    generated = out / "api" / "generated"
    made = {p.stem for p in generated.glob("*.html")}
    missing = sorted(_expected_pages() - made)
    assert not missing, (f"{len(missing)} public names or modules have no API page (add the module to "
                         f"docs/api/index.rst): {missing[:40]}")


def test_every_public_module_is_listed():
    """Each public module is in docs/api/index.rst, or is a package that only lists its modules."""
    index = (DOCS / "api" / "index.rst").read_text(encoding="utf-8")
    listed = {line.strip() for line in index.splitlines() if line.startswith("   optitact")}
    unlisted = []
    for name in _public_modules():
        module = importlib.import_module(name)
        names = _public_names(module)
        if name in listed or (hasattr(module, "__path__")
                              and all(inspect.ismodule(getattr(module, a)) for a in names)):
            continue
        unlisted.append(name)
    assert not unlisted, f"modules missing from docs/api/index.rst: {unlisted}"

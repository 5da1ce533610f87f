"""Sphinx configuration of the optitact documentation.

Build: ``sphinx-build -W --keep-going -b html docs docs/_build/html`` (the ``docs``
extra installs what it needs; ``tests/docs/test_sphinx.py`` runs the same build).

Nothing here reaches the network or executes a notebook: the tutorials are the
notebooks of ``notebooks/``, copied into ``docs/tutorials/`` (git-ignored) when the
build starts, with the outputs of the test suite's last run where it left them.
"""

from __future__ import annotations

import json
import pathlib
import re
import shutil
import warnings

import optitact

DOCS = pathlib.Path(__file__).resolve().parent
ROOT = DOCS.parent

# -- Project ---------------------------------------------------------------------------------
project = "optitact"
author = "optitact developers"
copyright = "optitact developers, BSD-3-Clause"
version = release = optitact.__version__

# -- Extensions --------------------------------------------------------------------------------
extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.intersphinx",
    "sphinx.ext.mathjax",
    "numpydoc",
    "myst_nb",
]

source_suffix = {".rst": "restructuredtext", ".md": "myst-nb", ".ipynb": "myst-nb"}
root_doc = "index"
exclude_patterns = ["_build", "**.ipynb_checkpoints"]
templates_path = ["_templates"]

# -- API reference (autosummary + numpydoc) ----------------------------------------------------
# docs/api/index.rst lists the modules; the templates in _templates/autosummary give every
# name in each module's __all__ a page of its own (docs/api/generated/, git-ignored).
autosummary_generate = True
autosummary_generate_overwrite = True
autosummary_ignore_module_all = False  # a module's members are exactly its __all__
autosummary_imported_members = False
# The stubs are regenerated from scratch at every build: a name removed from an __all__ must not
# leave its old page (and a failing import) behind in a working tree.
shutil.rmtree(DOCS / "api" / "generated", ignore_errors=True)
autodoc_default_options = {"member-order": "bysource"}
autodoc_typehints = "none"  # numpydoc's Parameters sections carry the types
autodoc_preserve_defaults = True
numpydoc_show_class_members = False  # the class template lists members through autodoc
numpydoc_class_members_toctree = False
numpydoc_attributes_as_param_list = True
numpydoc_xref_param_type = False


def _share_numpydoc_template_env() -> None:
    """Compile numpydoc's docstring template once, not once per documented object.

    numpydoc (1.x) builds a new Jinja environment, and so recompiles its template, for every
    docstring: about a quarter of this build's time. One environment per loader type gives the
    same output. If numpydoc changes its internals this does nothing.
    """
    import numpydoc.docscrape_sphinx as nds

    base = getattr(nds, "SandboxedEnvironment", None)
    if base is None or getattr(base, "_optitact_shared", False):
        return
    envs: dict = {}

    def shared(loader=None, **kwargs):
        key = (type(loader), tuple(sorted(kwargs)))
        if key not in envs:
            envs[key] = base(loader=loader, **kwargs)
        return envs[key]

    shared._optitact_shared = True
    nds.SandboxedEnvironment = shared


_share_numpydoc_template_env()

_SECTION = re.compile(r"^(\s*)(\S.*?)\s*$")


def _convention_into_notes(app, what, name, obj, options, lines) -> None:
    """Keep the package's ``Convention`` docstring sections, which numpydoc does not know.

    numpydoc drops a section it does not know; this moves a ``Convention`` section into the
    ``Notes`` section (made if absent) under a "Convention" rubric, before numpydoc runs.
    """
    heads = [i for i in range(len(lines) - 1)
             if lines[i].strip() and set(lines[i + 1].strip()) == {"-"}
             and len(lines[i + 1].strip()) == len(lines[i].strip())]
    conv = [i for i in heads if lines[i].strip() == "Convention"]
    if not conv:
        return
    start = conv[0]
    end = next((i for i in heads if i > start), len(lines))
    body = lines[start + 2:end]
    rest = lines[:start] + lines[end:]
    block = [".. rubric:: Convention", "", *[ln.strip() and ln for ln in body]]
    while block and not block[-1].strip():
        block.pop()
    notes = next((i for i in range(len(rest) - 1) if rest[i].strip() == "Notes"
                  and set(rest[i + 1].strip()) == {"-"}), None)
    if notes is None:
        new = rest + ([""] if rest and rest[-1].strip() else []) + ["Notes", "-----", *block, ""]
    else:
        new = rest[:notes + 2] + block + [""] + rest[notes + 2:]
    lines[:] = new


# numpydoc also parses docstrings for signatures and says so for each "Convention" section (a
# Python warning, not a Sphinx one): the section is kept by the hook above.
warnings.filterwarnings("ignore", message="Unknown section Convention", category=UserWarning)


def setup(app) -> None:
    """Run the ``Convention`` fix before numpydoc (which connects at the default priority 500)."""
    app.connect("autodoc-process-docstring", _convention_into_notes, priority=100)

# -- Cross-references to other projects --------------------------------------------------------
# No mapping: intersphinx would fetch objects.inv over the network, and the build must work
# offline (CI has no network). External names are written as plain literals.
intersphinx_mapping: dict = {}
intersphinx_disabled_reftypes = ["*"]

# -- MyST and notebooks ------------------------------------------------------------------------
myst_enable_extensions = ["dollarmath", "amsmath", "colon_fence", "deflist", "html_image"]
myst_heading_anchors = 3
myst_dmath_double_inline = True
nb_execution_mode = "off"  # never run a notebook while building; pytest executes them
nb_merge_streams = True

# The stories in notebooks/ become docs/tutorials/NN_name.ipynb (copied, not tracked).
TUTORIALS = DOCS / "tutorials"


#: Notebooks as the test suite last executed them, with their outputs (``tests/_notebook_runner.py``).
EXECUTED = ROOT / "docs" / "_build" / "executed-notebooks"


def _copy_notebooks() -> None:
    """Copy the notebooks, naming their language (the tracked ones carry no kernel).

    Where a test run left an executed copy that is newer than the notebook, the copy (with its
    outputs) is shown; otherwise the unexecuted notebook. Nothing is executed here.
    """
    for src in sorted((ROOT / "notebooks").glob("[0-9][0-9]_*.ipynb")):
        done = EXECUTED / src.name
        if done.is_file() and done.stat().st_mtime >= src.stat().st_mtime:
            src = done
        nb = json.loads(src.read_text(encoding="utf-8"))
        nb.setdefault("metadata", {}).update({
            "kernelspec": {"name": "python3", "display_name": "Python 3", "language": "python"},
            "language_info": {"name": "python", "pygments_lexer": "ipython3"}})
        text = json.dumps(nb, indent=1, ensure_ascii=False) + "\n"
        dst = TUTORIALS / done.name
        if not dst.exists() or dst.read_text(encoding="utf-8") != text:  # unchanged: no rebuild
            dst.write_text(text, encoding="utf-8")


_copy_notebooks()

# -- HTML --------------------------------------------------------------------------------------
html_theme = "pydata_sphinx_theme"
html_title = f"optitact {release}"
html_static_path = ["_static"]
html_css_files = ["optitact.css"]
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
    "header_links_before_dropdown": 8,
    "secondary_sidebar_items": ["page-toc"],
    # Six hundred API pages: a shallow, collapsed sidebar keeps each page's navigation quick to render.
    "navigation_depth": 2,
    "collapse_navigation": True,
}
# No primary sidebar on the ~600 generated API pages: the theme renders the whole API toctree
# into each page's sidebar, which made the build several times slower. Those pages are reached
# from the module tables of api/index; the header and the in-page contents remain.
html_sidebars = {"index": [], "api/generated/*": []}
html_show_sourcelink = False


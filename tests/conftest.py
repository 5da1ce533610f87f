"""Shared test set-up: caches go to a temporary folder, never the user's; notebooks run last.

Expensive objects (renders, calibration sets, study results) are built once per session
by fixtures here or in a folder's own ``conftest.py``; the notebooks run after every other
test, so they find the quick study results and tables in the session's cache, except those
that read none of it (``EARLY_NOTEBOOKS``): they start with the session in a background
process, beside the tests.
"""

from __future__ import annotations

import os
import pathlib
import subprocess
import sys

import pytest

# The tests mirror the package (tests/optics/, tests/pipeline/, ...); a test module may import another's
# helpers (``from test_frame_pipeline import ...``), so every such folder is on sys.path, as tests/ is.
sys.path[1:1] = [str(d) for d in sorted(pathlib.Path(__file__).parent.iterdir())
                 if d.is_dir() and not (d / "__init__.py").exists() and not d.name.startswith((".", "_"))]

from _notebook_runner import EARLY_NOTEBOOKS  # noqa: E402, I001  (tests/ is on sys.path: rootdir conftest)
from hypothesis import settings  # noqa: E402

# A busy machine is slow, not wrong: no per-example deadline anywhere in the suite.
settings.register_profile("optitact", deadline=None)
settings.load_profile("optitact")


@pytest.fixture(autouse=True, scope="session")
def _private_cache(tmp_path_factory, request):
    mp = pytest.MonkeyPatch()
    if os.environ.get("PYTEST_XDIST_WORKER"):  # one cache for every worker of this run (writes are atomic)
        cache = tmp_path_factory.getbasetemp().parent / "optitact-cache"
        cache.mkdir(exist_ok=True)
    else:
        cache = tmp_path_factory.mktemp("optitact-cache")
    mp.setenv("OPTITACT_CACHE_DIR", str(cache))
    early = getattr(request.config, "_optitact_early_notebooks", [])
    runner = None
    if early:
        out = tmp_path_factory.mktemp("early-notebooks")
        runner = subprocess.Popen([sys.executable, str(pathlib.Path(__file__).with_name("_notebook_runner.py")),
                                   str(out), *map(str, early)])
        request.config._optitact_early_runner = (runner, out)
    yield
    if runner is not None and runner.poll() is None:  # the session ended before its tests waited
        runner.kill()
        runner.wait()
    mp.undo()


#: Test files that take longest (tens of seconds each), in the order they start under pytest-xdist
#: (``--no-loadscope-reorder`` keeps it), one worker each in turn, so that the workers end together. The
#: notebooks come after the files whose session results they read from the shared cache (the quick finger
#: and taxel studies, the two-stage tests' small emission table).
LONGEST_FIRST = ("finger/test_studies.py", "render/test_twostage.py", "test_workflows.py",
                 "docs/test_sphinx.py",
                 "taxels/test_study_tracing.py", "taxels/test_study_palpation.py", "taxels/test_study_wire.py",
                 "taxels/test_study_fingertip.py", "test_notebooks.py", "studies/test_noise_sweep.py",
                 "registration/test_pose.py", "pipeline/test_distributed.py", "calib/test_calib.py",
                 "docs/test_guides.py")


def pytest_collection_modifyitems(config, items):
    """Run the notebook executions last (stable order otherwise); start the early ones at once.

    Under pytest-xdist (``-n 2 --dist loadfile``, the project's default) a file's tests run on one
    worker, in order, the longest files first (:data:`LONGEST_FIRST`), and the notebooks are ordinary
    tests there: the other worker is the second core.
    """
    items.sort(key=lambda item: item.get_closest_marker("notebook") is not None)
    if os.environ.get("PYTEST_XDIST_WORKER"):
        config._optitact_early_notebooks = []
        order = {name: i for i, name in enumerate(LONGEST_FIRST)}
        tests = pathlib.Path(__file__).resolve().parent
        rank = {id(item): order.get(pathlib.Path(str(item.fspath)).resolve().relative_to(tests).as_posix(),
                                     len(order)) for item in items}
        items.sort(key=lambda item: rank[id(item)])  # stable: the notebooks stay last within their file
        return
    notebooks = pathlib.Path(__file__).resolve().parents[1] / "notebooks"
    config._optitact_early_notebooks = [
        notebooks / f"{name}.ipynb" for name in EARLY_NOTEBOOKS
        if any(item.get_closest_marker("notebook") is not None and item.name.endswith(f"[{name}]")
               for item in items)]


@pytest.fixture(scope="session")
def finger_quick_study():
    """``studies.run("finger", seed=0, size="quick")``, computed once per run (about a minute).

    The finger tests and the finger notebook read it. Under pytest-xdist they may run on two
    workers: the first computes it into the run's shared cache while holding a lock, the other
    waits and then reads the cached result.
    """
    import fcntl

    from optitact import studies

    with open(pathlib.Path(os.environ["OPTITACT_CACHE_DIR"]) / "finger-quick-study.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            return studies.run("finger", seed=0, size="quick")
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


@pytest.fixture
def user(tmp_path, tmp_path_factory):
    """A researcher's shell for outside-in tests: fresh folder and cache, the installed ``optitact``.

    ``user.run("process", ...)`` runs the entry point as a subprocess (``tests/outside_in.py``);
    ``cached=True`` lets a command use the session's shared render cache instead of an empty one.
    """
    import os

    from outside_in import User

    return User(tmp_path / "work", tmp_path / "cache",
                shared_cache=pathlib.Path(os.environ["OPTITACT_CACHE_DIR"]))

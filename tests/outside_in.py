"""Run the installed ``optitact`` command as a user does: a new process, a fresh folder and cache.

Outside-in tests prove a workflow works the way a researcher types it: every command is the
installed entry point (``optitact`` beside this Python), run as a subprocess with its working
directory in a fresh temporary folder and ``OPTITACT_CACHE_DIR`` in a fresh cache folder, so
nothing the test process imported or registered can help it. In-process ``main([...])``
tests remain for options and messages.

Use the ``user`` fixture (``tests/conftest.py``)::

    def test_something(user):
        r = user.run("process", "frames.npy", "--out", "readings.csv")
        assert r.returncode == 0, r.stderr
        table = user.path("readings.csv")
"""

from __future__ import annotations

import os
import pathlib
import subprocess
import sys

__all__ = ["User", "optitact_executable"]


def optitact_executable() -> pathlib.Path:
    """The ``optitact`` console script installed beside the running Python."""
    exe = pathlib.Path(sys.executable).with_name("optitact")
    if not exe.exists():
        raise RuntimeError(f"the optitact entry point is not installed beside {sys.executable}: "
                           f"pip install -e '.[test]'")
    return exe


class User:
    """A researcher's shell: a working folder, a cache folder, and the installed ``optitact``.

    Parameters
    ----------
    folder, cache : pathlib.Path
        The working directory of every command and its ``OPTITACT_CACHE_DIR``.
    shared_cache : pathlib.Path, optional
        A cache folder to use instead of ``cache`` when a test says ``cached=True`` (the
        render caches a session's tests share; the workflow still runs in a new process).
    """

    def __init__(self, folder: pathlib.Path, cache: pathlib.Path,
                 shared_cache: pathlib.Path | None = None):
        self.folder = pathlib.Path(folder)
        self.cache = pathlib.Path(cache)
        self.shared_cache = shared_cache
        self.folder.mkdir(parents=True, exist_ok=True)
        self.cache.mkdir(parents=True, exist_ok=True)

    def env(self, *, cached: bool = False, **extra: str) -> dict[str, str]:
        """The environment of a command: this one, with the cache folder and no Python path tricks."""
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONSTARTUP")}
        env["OPTITACT_CACHE_DIR"] = str(self.shared_cache if cached and self.shared_cache else self.cache)
        env.update(extra)
        return env

    def run(self, *args: str, cached: bool = False, timeout: float = 600, input: str | None = None,
            env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
        """Run ``optitact ARGS...`` in the folder and return the finished process (text output)."""
        full_env = self.env(cached=cached)
        if env:
            full_env.update(env)
        return subprocess.run([str(optitact_executable()), *map(str, args)], cwd=self.folder,
                              env=full_env, capture_output=True, text=True, timeout=timeout,
                              input=input)

    def python(self, code: str, *, cached: bool = False, timeout: float = 600) -> subprocess.CompletedProcess:
        """Run a Python snippet in a new interpreter in the folder, as a user's script."""
        return subprocess.run([sys.executable, "-c", code], cwd=self.folder, env=self.env(cached=cached),
                              capture_output=True, text=True, timeout=timeout)

    def path(self, name: str) -> pathlib.Path:
        """A path in the working folder."""
        return self.folder / name

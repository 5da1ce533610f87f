"""Calibration-set stores that crash, are shared, or are fitted half-done; the shipped emission table.

Crash points are injected deterministically (a write that raises at its N-th call, a
subprocess that ``os._exit``s mid-write); the renderer is replaced by a cheap
deterministic stand-in wherever the store, not the light, is under test.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from optitact.calib import sets as sets_mod
from optitact.calib import store as _store
from optitact.calib.fit import fit
from optitact.calib.sets import CalibrationSet, generate

import optitact
from optitact.cli import main
from optitact.errors import InputError

SENSOR = optitact.optics.sensor.DomeSensor.default()
TINY = optitact.optics.camera.FisheyeCamera(width=80, height=60)
N = SENSOR.n_elements
GEN = dict(camera=TINY, spp=2, seed=5, progress=False, render_mode="full", baseline_frames=1)


class Crash(Exception):
    """An injected crash (the files on disk are what a SIGKILL at that point leaves)."""


def fake_render(sensor, forces, *, camera, seed=0, **kwargs):
    """A deterministic stand-in for the path tracer: a faint noisy frame, brighter with the load."""
    rng = np.random.default_rng(seed)
    load = float(np.abs(np.asarray(forces)).sum())
    return (0.02 + 0.002 * rng.random(camera.shape) + 0.001 * load).astype(np.float32)


@pytest.fixture
def cheap(monkeypatch):
    """Replace Mitsuba by :func:`fake_render` (generate and FrameMaker import it when they run)."""
    import optitact.render

    monkeypatch.setattr(optitact.render, "render", fake_render)


def same_set(a: CalibrationSet, b: CalibrationSet) -> None:
    assert a.complete and b.complete
    for name in ("G", "u", "contact", "saturated", "forces", "seeds", "baseline", "done"):
        np.testing.assert_array_equal(a.array(name), b.array(name), err_msg=name)


@pytest.fixture
def whole(cheap, tmp_path):
    """An uninterrupted 3-frame set: what every crashed-and-resumed run must equal."""
    return generate(tmp_path / "whole.zarr", frames=3, **GEN)


# ---------------------------------------------------------------------------- item: resume
def test_an_empty_folder_is_a_new_store(whole, tmp_path, capsys):
    """`mkdir S.zarr` (or a kill right after the folder was made) then generate: rebuilt, not refused."""
    out = tmp_path / "S.zarr"
    out.mkdir()
    same_set(generate(out, frames=3, **GEN), whole)
    empty = tmp_path / "E.zarr"
    empty.mkdir()
    assert main(["calibrate", "generate", "--frames", "2", "--out", str(empty), "--spp", "1", "--width", "80",
                 "--height", "60", "--render-mode", "full"]) == 0
    assert CalibrationSet(empty).complete
    capsys.readouterr()


@pytest.mark.parametrize("crash_at", [1, 2, 4, 13, 26, 27])
def test_a_store_killed_while_being_created_resumes(whole, tmp_path, monkeypatch, crash_at):
    """The store's writes are cut at the N-th (1: the group's first zarr.json, 2: the first array's,
    4: a chunk of the forces, 13: the group's metadata again, 26: the set's attributes, written last
    of the creation; 27: the first baseline chunk, in a whole store), leaving zarr's half-written
    temporary file; the same command then finishes it, identical to an uninterrupted run."""
    import zarr.storage._local as local

    real = local._put
    calls = {"n": 0}

    def put(path, value, exclusive=False):
        calls["n"] += 1
        if calls["n"] == crash_at:
            # half a file under zarr's own temporary name, then the crash
            path.parent.mkdir(parents=True, exist_ok=True)
            path.with_suffix(".0123456789abcdef0123456789abcdef.partial").write_bytes(
                bytes(value.as_buffer_like())[:7])
            raise Crash(f"killed at metadata write {crash_at}")
        return real(path, value, exclusive)

    out = tmp_path / "S.zarr"
    monkeypatch.setattr(local, "_put", put)
    with pytest.raises(Crash):
        generate(out, frames=3, **GEN)
    monkeypatch.setattr(local, "_put", real)
    same_set(generate(out, frames=3, **GEN), whole)
    assert not list(out.rglob("*.partial"))


def test_a_half_written_root_metadata_and_a_half_removed_store_are_rebuilt(whole, tmp_path):
    """A truncated zarr.json (a write cut half-way) and the remains of a store removed half-way
    (a kill inside the clean-up: most files gone, the root metadata among them)."""
    a = tmp_path / "a.zarr"
    a.mkdir()
    (a / "zarr.json").write_text('{"zarr_format": 3, "node_ty')
    same_set(generate(a, frames=3, **GEN), whole)

    b = tmp_path / "b.zarr"
    generate(b, frames=3, **GEN)
    for name in ("zarr.json", "G", "u", "done", "forces"):
        target = b / name
        if target.is_dir():
            import shutil

            shutil.rmtree(target)
        else:
            target.unlink()
    # the done flags went first: no finished frame is left, the rest is the store's own files
    same_set(generate(b, frames=3, **GEN), whole)


def test_a_users_folder_is_never_deleted(cheap, tmp_path, capsys):
    """Anything that is not a store's own file: refused, and left exactly as it was."""
    mine = tmp_path / "mine.zarr"
    mine.mkdir()
    (mine / "notes.txt").write_text("my data")
    (mine / "G").mkdir()
    (mine / "G" / "zarr.json").write_text("{}")
    with pytest.raises(InputError, match="notes.txt"):
        generate(mine, frames=2, **GEN)
    assert (mine / "notes.txt").read_text() == "my data" and (mine / "G" / "zarr.json").is_file()
    nested = tmp_path / "nested.zarr"
    (nested / "done" / "c").mkdir(parents=True)
    (nested / "done" / "c" / "thesis.pdf").write_text("x")
    with pytest.raises(InputError, match="thesis.pdf"):
        generate(nested, frames=2, **GEN)
    assert (nested / "done" / "c" / "thesis.pdf").is_file()
    afile = tmp_path / "file.zarr"
    afile.write_text("x")
    assert main(["calibrate", "generate", "--frames", "2", "--out", str(afile), "--width", "80", "--height",
                 "60", "--render-mode", "full"]) == 2
    assert "is a file" in capsys.readouterr().err and afile.read_text() == "x"


def test_a_store_with_finished_frames_but_no_settings_is_kept(cheap, tmp_path):
    out = tmp_path / "s.zarr"
    generate(out, frames=2, **GEN)
    (out / "zarr.json").unlink()
    with pytest.raises(InputError, match="finished frames"):
        generate(out, frames=2, **GEN)
    assert any((out / "done" / "c").iterdir())


def test_stray_partial_chunks_in_a_finished_store_are_removed(whole, tmp_path):
    """A crash mid-chunk leaves zarr's temporary `<chunk>.<uuid>.partial`: the next run removes it."""
    stray = [whole.path / "G" / "c" / "1" / "0.0123456789abcdef0123456789abcdef.partial",
             whole.path / "zarr.fedcba9876543210fedcba9876543210.partial"]
    for p in stray:
        p.write_bytes(b"\x00\x01")
    again = generate(whole.path, frames=3, **GEN)
    assert not any(p.exists() for p in stray)
    assert again.complete


def killed_writer(target, tmp_path) -> None:
    """A subprocess that dies (os._exit, no clean-up) half-way through atomic_write_text(target)."""
    code = ("import os, sys\nfrom optitact.io.files import atomic_write\n"
            "def half(tmp):\n    tmp.write_text('{\"schema\": ')\n    os._exit(9)\n"
            "atomic_write(sys.argv[1], half)\n")
    proc = subprocess.run([sys.executable, "-c", code, str(target)], cwd=tmp_path)
    assert proc.returncode == 9


def test_temporary_files_of_a_killed_write_are_cleaned(tmp_path):
    """A killed `calibrate fit` leaves its temporary CAL.json beside the target: the next write of
    the same target removes it; other files are left alone."""
    from optitact.io.files import atomic_write_text

    target = tmp_path / "CAL.json"
    keep = tmp_path / "other.json"
    keep.write_text("{}")
    killed_writer(target, tmp_path)
    leftovers = [p for p in tmp_path.iterdir() if p not in (keep,)]
    assert len(leftovers) == 1 and not target.exists()
    assert leftovers[0].name.startswith(".CAL.json.") and ".tmp" in leftovers[0].name
    atomic_write_text(target, "{}\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["CAL.json", "other.json"]


# ---------------------------------------------------------------------------- item: two writers
def test_a_second_writer_is_refused_and_told_who_holds_the_store(cheap, tmp_path, capsys):
    """Another process holds the store's lock (taken the way generate takes it): generate fails at
    once with who holds it, and the store is untouched; once released, the same call finishes."""
    out = tmp_path / "s.zarr"
    code = ("import sys\nfrom pathlib import Path\nfrom optitact.calib.sets import _store_lock\n"
            "with _store_lock(Path(sys.argv[1])):\n    print('locked', flush=True)\n    sys.stdin.read()\n")
    holder = subprocess.Popen([sys.executable, "-c", code, str(out), "--holder-flag"], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(_store.StoreLockedError, match=rf"pid {holder.pid} on .*--holder-flag.* since "):
            generate(out, frames=2, **GEN)
        assert main(["calibrate", "generate", "--frames", "2", "--out", str(out), "--width", "80",
                     "--height", "60", "--render-mode", "full"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"pid {holder.pid}" in err[0] and "another process" in err[0]
        assert sorted(p.name for p in out.iterdir()) == [_store.LOCK_NAME]  # nothing written
    finally:
        holder.communicate("")
    assert generate(out, frames=2, **GEN).complete


# ---------------------------------------------------------------------------- item: fitting a partial set
def test_fitting_an_incomplete_set_is_refused_unless_asked(cheap, tmp_path, monkeypatch, capsys):
    """A generate killed at frame 10 of 12 leaves 9 done: fit says so and refuses; partial=True
    (--partial) fits those 9 (readings replaced by an ideal sensor's, so the fit itself succeeds)."""
    real = sets_mod.FrameMaker.__call__
    calls = {"n": 0}

    def dies_at_ten(self, forces, seed):
        calls["n"] += 1
        if calls["n"] == 10:
            raise Crash("killed at frame 10")
        return real(self, forces, seed)

    out = tmp_path / "s.zarr"
    monkeypatch.setattr(sets_mod.FrameMaker, "__call__", dies_at_ten)
    with pytest.raises(Crash):
        generate(out, frames=12, **GEN)
    cs = CalibrationSet(out)
    assert cs.done.sum() == 9
    import zarr

    g = zarr.open_group(str(out), mode="r+")
    f = np.asarray(g["forces"][:])
    fz = f[..., 2]
    safe = np.where(fz > 0, fz, 1.0)
    g["G"][:] = np.where(fz > 0, np.linspace(50, 150, N) * fz, 0.0)
    g["u"][:] = np.where((fz > 0)[..., None], f[..., :2] * (3.0 / safe + 0.2 / np.sqrt(safe))[..., None], 0)
    g["contact"][:] = fz > 0
    with pytest.raises(InputError, match=r"incomplete: 9 of 12 frames done.*partial=True"):
        fit(out)
    cal = fit(out, partial=True)
    assert cal.provenance["frames"] == 9 and cal.provenance["frames_in_set"] == 12
    assert int(np.max(cal.residuals["n"])) <= 9
    cal_path = tmp_path / "c.json"
    assert main(["calibrate", "fit", str(out), "--out", str(cal_path)]) == 2
    assert "9 of 12 frames done" in capsys.readouterr().err and not cal_path.exists()
    assert main(["calibrate", "fit", str(out), "--partial", "--out", str(cal_path)]) == 0
    assert "from 9 of 12 frames" in capsys.readouterr().err and cal_path.is_file()


# ---------------------------------------------------------------------------- item: the shipped table
@pytest.fixture
def no_path_tracing(monkeypatch):
    """Every way stage 1 could path-trace raises: what runs must use a table it already has."""
    import optitact.render
    import optitact.render.emission as em

    def refuse(*args, **kwargs):
        raise Crash("stage 1 rendered")

    for module, name in ((em, "_measure"), (em, "noload_radiance"), (optitact.render, "render_contacts")):
        monkeypatch.setattr(module, name, refuse)
    return em


def test_the_default_sensor_and_camera_use_the_shipped_table(no_path_tracing, cheap, tmp_path, capsys):
    em = no_path_tracing
    camera = optitact.optics.camera.FisheyeCamera()
    table = em.emission_table(SENSOR, camera, progress=True)
    meta = table.meta
    assert meta["sensor"] == SENSOR.to_dict() and meta["camera"] == camera.to_dict()
    assert meta["settings"] == optitact.render.scene.RenderSettings().to_dict() and meta["spp"] == 4096
    assert table.radiance.shape == (len(em.TABLE_THETA_DEG), len(em.TABLE_RADII_MM))
    assert np.all(table.radiance > 0) and np.all(np.isfinite(table.coupling))
    assert np.median(table.stderr / table.radiance) < 0.02  # measured at 4096 spp: 0.8 %
    assert em.emission_table(SENSOR, camera, spp=meta["spp"]) is not None
    assert capsys.readouterr().err == ""  # nothing to announce: no one-time step
    # `calibrate generate` with every default (two-stage frames, 640x480) starts on its frames at once
    out = tmp_path / "s.zarr"
    cs = generate(out, frames=1, spp=1, seed=1, progress=False, baseline_frames=1)
    from optitact.io.files import json_fingerprint

    assert cs.complete and cs.attrs["two_stage_table"] == json_fingerprint(table.to_dict()["radiance"], 16)
    # anything else is measured (here: refused by the stand-in), announced first on stderr
    for kw in ({"camera": TINY}, {"camera": camera, "spp": 256},
               {"camera": camera, "settings": optitact.render.scene.RenderSettings(rim_radiance=2.0)}):
        with pytest.raises(Crash):
            em.emission_table(SENSOR, progress=True, **kw)
        err = capsys.readouterr().err
        assert "one-time step" in err and "cached in" in err and "Estimate:" in err
    with pytest.raises(Crash):
        main(["calibrate", "generate", "--frames", "1", "--out", str(tmp_path / "t.zarr"), "--width", "80",
              "--height", "60", "--table-spp", "64"])
    assert "64 spp" in capsys.readouterr().err


def test_a_measured_table_reestimates_its_time_after_the_first_render(monkeypatch, capsys):
    """The estimate printed before stage 1 is re-measured from its first render (stand-in renders)."""
    import optitact.render.emission as em

    monkeypatch.setattr(em, "noload_radiance", lambda sensor, camera, **kw: np.zeros(camera.shape, np.float32))

    def measure(sensor, camera, settings, probes_c, probes_r, extra_c, extra_r, **kw):
        n = len(probes_r)
        return np.full(n, 1.0 - 0.01 * len(extra_r)), np.full(n, 1e-3)

    monkeypatch.setattr(em, "_measure", measure)
    table = em.emission_table(SENSOR, TINY, spp=64, cache=False, progress=True)
    err = capsys.readouterr().err
    assert err.index("one-time step") < err.index("the first render took") < err.index("32/32")
    assert "32 path-traced renders at 64 spp" in err and "for the other 31" in err
    assert np.all(table.radiance > 0)

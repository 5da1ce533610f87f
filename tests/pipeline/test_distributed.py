"""Calibration sets on a Dask cluster: identical to local ones, and safe when workers die."""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest
from optitact.calib.sets import CalibrationSet, generate

import optitact
from optitact.optics.camera import FisheyeCamera

pytestmark = pytest.mark.render

distributed = pytest.importorskip("distributed")

GEN = dict(frames=12, camera=FisheyeCamera(width=80, height=60), spp=32, seed=8, progress=False,
           render_mode="pixels")
NAMES = ("G", "u", "contact", "saturated", "forces", "seeds", "baseline")


@pytest.fixture(scope="module")
def cluster():
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as c, distributed.Client(c) as client:
        yield client


def test_distributed_set_equals_local_set(cluster, tmp_path):
    local = generate(tmp_path / "local.zarr", **GEN)
    remote = generate(tmp_path / "remote.zarr", scheduler=cluster, **GEN)
    by_address = generate(tmp_path / "addr.zarr", scheduler=cluster.scheduler.address, **GEN)
    for s in (remote, by_address):
        assert s.complete
        for name in NAMES:
            np.testing.assert_array_equal(s.array(name), local.array(name), err_msg=name)


def test_killed_worker_loses_and_duplicates_nothing(cluster, tmp_path):
    path = tmp_path / "killed.zarr"
    killed = {}

    def kill_one_worker():
        deadline = time.time() + 120
        while time.time() < deadline:
            try:
                if CalibrationSet(path).done.sum() >= 2:
                    break
            except (FileNotFoundError, ValueError, KeyError):
                pass
            time.sleep(0.05)
        victim = sorted(cluster.scheduler_info()["workers"])[0]
        killed["at"] = int(CalibrationSet(path).done.sum())
        try:
            cluster.run(os._exit, 1, workers=[victim], wait=False)
        except Exception:  # the worker may die before it answers
            pass

    t = threading.Thread(target=kill_one_worker)
    t.start()
    got = generate(path, scheduler=cluster, **GEN)
    t.join()
    assert 2 <= killed["at"] < GEN["frames"], "the kill must land mid-run for this test to mean anything"
    want = generate(tmp_path / "whole.zarr", **GEN)
    assert got.complete and got.done.sum() == GEN["frames"]
    for name in NAMES:
        np.testing.assert_array_equal(got.array(name), want.array(name), err_msg=name)


def test_bad_scheduler_is_a_type_error(tmp_path):
    with pytest.raises(TypeError, match="scheduler must be an address string or a distributed.Client"):
        generate(tmp_path / "x.zarr", scheduler=3, **GEN)


def test_process_many_recordings_on_the_cluster(cluster, tmp_path):
    """optitact process --scheduler: one task per file, the same CSV as a local run."""
    from optitact.render import render

    from optitact.cli import main

    cam = optitact.optics.camera.FisheyeCamera(width=80, height=60)
    s = optitact.optics.sensor.DomeSensor.default()
    ccd = optitact.optics.ccd.CCD()
    noload = render(s, np.zeros((41, 3)), camera=cam, spp=8, seed=1)
    load = np.zeros((41, 3))
    load[[0, 3], 2] = 0.8
    loaded = render(s, load, camera=cam, spp=8, seed=2)
    files = []
    for k in range(3):
        stack = np.stack([ccd.expose(noload, seed=10 * k)] + [ccd.expose(loaded, seed=10 * k + j)
                                                              for j in range(1, 4)])
        files.append(tmp_path / f"rec{k}.npy")
        np.save(files[-1], stack)
    setup = ["--fov", "140", "--batch", "2"]
    local, remote = tmp_path / "local.csv", tmp_path / "remote.csv"
    assert main(["process", *map(str, files), "--out", str(local), *setup]) == 0
    assert main(["process", *map(str, files), "--out", str(remote), *setup,
                 "--scheduler", cluster.scheduler.address]) == 0
    assert remote.read_text() == local.read_text()
    assert len(local.read_text().splitlines()) == 1 + 12 * 41

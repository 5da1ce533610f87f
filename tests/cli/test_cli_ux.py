"""The CLI as a first-time user meets it (issue 17): tables, plots that explain, progress, early checks, help.

Nothing here renders: the render step is replaced by a fake that returns a known frame, so the
tests check what the CLI does around it (validation before the render, what is written after).
"""

from __future__ import annotations

import argparse
import json
import sys
import types

import cv2
import numpy as np
import pytest

import optitact
from optitact.cli import main, parser
from optitact.io.tables import write_forces_csv

SENSOR = optitact.optics.sensor.DomeSensor.default()
TINY = ["--spp", "2", "--width", "64", "--height", "48"]


# ----------------------------------------------------------------------------------------- fakes
def _known_frame(h: int = 48, w: int = 64, dtype=np.uint8) -> np.ndarray:
    """A dim frame like a real one: dark offset 4 almost everywhere, a few spots up to 151."""
    frame = np.full((h, w), 4, dtype)
    frame[10, 10:14] = (20, 60, 151, 90)
    frame[30, 40:42] = (7, 33)
    return frame


@pytest.fixture
def fake_render(monkeypatch):
    """Replace the render step of ``demo``/``render`` by a known frame; records the calls."""
    import optitact.cli.demo as demo
    from optitact.optics.camera import FisheyeCamera
    from optitact.optics.ccd import CCD

    calls = []

    def render_frame(sensor, forces, args, camera=None):
        calls.append(args)
        frame = _known_frame(args.height, args.width, np.uint16 if args.bits > 8 else np.uint8)
        return {"radiance": frame.astype(np.float32) / 255, "frame": frame,
                "camera": FisheyeCamera(width=args.width, height=args.height), "ccd": CCD(bits=args.bits),
                "variant": "scalar_rgb", "render_seconds": 0.01}

    monkeypatch.setattr(demo, "_render_frame", render_frame)
    return calls


@pytest.fixture
def forces_csv(tmp_path):
    f = np.zeros((41, 3))
    f[0, 2] = 0.5
    write_forces_csv(tmp_path / "f.csv", f)
    return tmp_path / "f.csv"


# ------------------------------------------------------------- item 1: experiments for humans
@pytest.fixture
def fake_study(monkeypatch, tmp_path):
    """A tiny study "fake" with a published figure, a published text and an unmatched entry."""
    from optitact.studies import _protocol
    from optitact.studies._protocol import Study

    def run(seed, *, full, progress):
        return {"value": seed + 1, "rate": {"left": 0.8125}, "series": np.arange(500)}

    module = types.ModuleType("fake_ux_study_for_tests")
    module.STUDY = Study(name="fake", summary="a test study", run=run,
                         published={"reference": "nobody (2024)", "value": 42, "rate": {"left": 0.75},
                                    "missing": [1, 2]})
    monkeypatch.setitem(sys.modules, module.__name__, module)
    monkeypatch.setattr(_protocol, "_REGISTRY", {**_protocol._REGISTRY, "fake": module.__name__})
    monkeypatch.setenv("OPTITACT_CACHE_DIR", str(tmp_path / "cache"))
    return module


def test_experiment_prints_a_table_by_default(fake_study, capsys):
    assert main(["experiment", "fake", "--seed", "3"]) == 0
    out = capsys.readouterr().out
    with pytest.raises(json.JSONDecodeError):
        json.loads(out)
    lines = out.splitlines()
    assert lines[0].startswith("fake (quick size, seed 3, ") and lines[0].endswith("a test study")
    rows = {line.split()[0]: line.split()[1:] for line in lines[3:-1]}
    assert rows == {"value": ["4", "42"], "rate/left": ["0.8125", "0.75"], "missing": ["-", "[1,", "2]"]}
    assert lines[-1] == "published: nobody (2024)"
    assert len(out) < 1000  # not the 500-value series


def test_experiment_json_and_out_keep_the_whole_result(fake_study, capsys, tmp_path):
    assert main(["experiment", "fake", "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["series"] == list(range(500)) and printed["published"]["value"] == 42
    path = tmp_path / "sub" / "result.json"
    assert main(["experiment", "fake", "--out", str(path)]) == 0
    captured = capsys.readouterr()
    assert captured.out.startswith("fake (quick size")  # the table on stdout, the JSON in the file
    assert json.loads(path.read_text()) == printed


def test_experiment_out_must_be_json(fake_study, capsys):
    with pytest.raises(SystemExit) as e:
        main(["experiment", "fake", "--out", "result.txt"])
    assert e.value.code == 2
    assert "expected a file name ending in .json, got 'result.txt'" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["fingertip", "wire", "tracing", "palpation"])
def test_key_figures_of_the_studies(name):
    """Every row pairs a figure of ours with the published one; the study's own numbers are there.

    The quick results are cached by the session (tests/taxels computes them first in a whole run).
    """
    from optitact import studies
    from optitact.cli.experiment import summary_table

    result = studies.run(name, seed=0, size="quick")
    rows = studies.key_figures(name, result)
    assert 3 <= len(rows) <= 20
    assert all(isinstance(label, str) and label for label, _, _ in rows)
    ours = [o for _, o, _ in rows if o is not None]
    assert len(ours) >= len(rows) / 2
    assert any(p is not None for _, _, p in rows)
    for _, o, p in rows:  # a published number is paired with a number, not a container or text
        if isinstance(p, float) and o is not None:
            assert isinstance(o, (int, float))
    table = summary_table(result)
    assert len(table.splitlines()) == len(rows) + 4 and len(table) < 4000


def test_key_figures_of_an_incomplete_result_is_an_input_error():
    from optitact import studies
    from optitact.errors import InputError

    with pytest.raises(InputError, match="not a complete 'wire' study result"):
        studies.key_figures("wire", {"published": {}})


# ---------------------------------------------------------------- item 2: plots that explain
def test_overlay_has_a_title_a_legend_and_units():
    from optitact.cli.demo import overlay
    from optitact.optics.camera import FisheyeCamera
    from optitact.optics.contact import contact_patches
    from optitact.optics.loads import indenter_load

    camera = FisheyeCamera(width=64, height=48)
    forces = indenter_load(SENSOR)
    frame = _known_frame()
    img = overlay(frame, SENSOR, camera, contact_patches(SENSOR, forces), forces,
                  title="overlay test: a title of some length")
    scale = img.shape[1] // 64
    assert scale >= 2 and img.shape[1] == 64 * scale  # small frames are enlarged for legible text
    head, foot = img[:30], img[30 + 48 * scale:]
    assert img.shape[0] == 30 + 48 * scale + foot.shape[0] and foot.shape[0] >= 4 * 20
    assert (head == 255).all(axis=2).sum() > 20  # white title text on the dark band
    green = (foot[..., 1] > 150) & (foot[..., 0] < 80) & (foot[..., 2] < 80)
    red = (foot[..., 2] > 150) & (foot[..., 0] < 80) & (foot[..., 1] < 80)
    assert green.sum() > 5 and red.sum() > 5  # the legend's marks in their colours
    assert (foot == 255).all(axis=2).sum() > 500  # and its text


def test_display_view_stretches_a_copy_and_leaves_the_data():
    from optitact.cli.demo import display_levels, display_view

    frame = _known_frame()
    before = frame.copy()
    view = display_view(frame)
    np.testing.assert_array_equal(frame, before)
    assert display_levels(frame)[0] == 4.0  # the dark offset is black
    assert view[frame == 4].max() == 0 and view.max() == 255
    order = np.argsort(frame.ravel(), kind="stable")  # a monotonic map of the grey levels
    assert np.all(np.diff(view.ravel()[order].astype(int)) >= 0)
    assert view[30, 41] > 2 * 33  # dim spots lifted (gamma < 1)


def test_demo_writes_a_view_beside_the_bit_exact_frame(fake_render, tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), *TINY]) == 0
    np.testing.assert_array_equal(cv2.imread(str(out / "frame.png"), cv2.IMREAD_UNCHANGED), _known_frame())
    view = cv2.imread(str(out / "frame_view.png"), cv2.IMREAD_UNCHANGED)
    assert view.dtype == np.uint8 and view.max() == 255 and view[0, 0] == 0
    assert "frame_view.png (viewing only)" in capsys.readouterr().err


def test_render_view_option(fake_render, forces_csv, tmp_path):
    out, view = tmp_path / "f.png", tmp_path / "v.png"
    assert main(["render", "--forces", str(forces_csv), "--out", str(out), "--view", str(view),
                 "--bits", "12", *TINY]) == 0
    raw = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16
    np.testing.assert_array_equal(raw, _known_frame(dtype=np.uint16))
    assert cv2.imread(str(view), cv2.IMREAD_UNCHANGED).max() == 255


# ------------------------------------------------------------ item 3: the baseline is announced
def test_noload_baseline_is_announced_with_an_estimate_and_a_bar(monkeypatch, capsys):
    import optitact.render.cache

    import optitact.io.cache
    from optitact.cli import demo
    from optitact.optics.camera import FisheyeCamera
    from optitact.optics.ccd import CCD

    seeds = []

    def fake_cached_render(sensor, forces, *, camera, spp, seed, variant=None, **kw):
        assert not np.any(forces)
        seeds.append(seed)
        return np.zeros(camera.shape, np.float32)

    monkeypatch.setattr(optitact.render.cache, "cached_render", fake_cached_render)
    camera = FisheyeCamera(width=64, height=48)
    args = argparse.Namespace(spp=64, seed=5, variant=None)
    base = demo._noload_baseline(SENSOR, camera, CCD(), args, seconds_per_frame=22.0)
    assert base.shape == (demo.NOLOAD_FRAMES, 48, 64) and seeds == [6, 7, 8, 9]
    err = capsys.readouterr().err
    first = err.splitlines()[0]
    assert first.startswith("optitact: no-load baseline: 4 renders at 64 spp, about 88 s on the first run")
    assert "cached in" in first
    assert "no-load baseline: 100%" in err and "4/4" in err  # the tqdm bar


# ---------------------------------------------- item 4: outputs are checked before any long work
@pytest.mark.parametrize("argv_out, match", [
    (["--out", "frame.jpg"], "expected a file name ending in .png or .npy, got 'frame.jpg'"),
    (["--out", "frame"], "expected a file name ending in .png or .npy, got 'frame'"),
    (["--out", "{dir}"], "is a folder; expected a file name ending in .png or .npy"),
    (["--out", "{file}/f001.png"], "is a file, not a folder"),
    (["--out", "f.png", "--radiance", "r.png"], "argument --radiance: expected a file name ending in .npy"),
    (["--out", "f.png", "--view", "v.tif"], "argument --view: expected a file name ending in .png"),
])
def test_render_refuses_bad_outputs_before_rendering(fake_render, forces_csv, tmp_path, capsys, monkeypatch,
                                                     argv_out, match):
    (tmp_path / "adir.png").mkdir()
    (tmp_path / "afile").write_text("x")
    monkeypatch.chdir(tmp_path)
    argv_out = [a.format(dir="adir.png", file="afile") for a in argv_out]
    with pytest.raises(SystemExit) as e:
        main(["render", "--forces", str(forces_csv), *argv_out, *TINY])
    assert e.value.code == 2
    assert match in capsys.readouterr().err
    assert fake_render == []  # nothing rendered


def test_render_writes_npy_and_creates_a_missing_folder(fake_render, forces_csv, tmp_path):
    out = tmp_path / "frames" / "f001.npy"
    assert main(["render", "--forces", str(forces_csv), "--out", str(out), *TINY]) == 0
    np.testing.assert_array_equal(np.load(out), _known_frame())
    png = tmp_path / "more" / "f002.PNG"
    assert main(["render", "--forces", str(forces_csv), "--out", str(png), *TINY]) == 0
    np.testing.assert_array_equal(cv2.imread(str(png), cv2.IMREAD_UNCHANGED), _known_frame())


@pytest.mark.parametrize("argv, match", [
    (["demo", "--out", "{file}"], "exists and is not a folder"),
    (["experiment", "tracing", "--plot", "fig.jpg"], "expected a file name ending in .png, got 'fig.jpg'"),
    (["bench", "accuracy", "--plot", "{file}/p.png"], "is a file, not a folder"),
    (["bench", "render", "--plot", "p.svg"], "expected a file name ending in .png"),
])
def test_other_commands_check_outputs_when_parsing(fake_render, tmp_path, capsys, monkeypatch, argv, match):
    import optitact.cli.bench as bench
    import optitact.studies

    def long_work(*args, **kwargs):
        raise AssertionError("started the long work before checking the outputs")

    monkeypatch.setattr(optitact.studies, "run", long_work)
    monkeypatch.setattr(bench, "BENCHES", dict.fromkeys(bench.BENCHES, long_work))
    (tmp_path / "afile").write_text("x")
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e:
        main([a.format(file="afile") for a in argv])
    assert e.value.code == 2
    assert match in capsys.readouterr().err
    assert fake_render == []


# ------------------------------------------------------------------------- item 5: help texts
def _parsers(p: argparse.ArgumentParser, path: str = "optitact"):
    """Every parser of the command tree with its command path."""
    yield path, p
    for action in p._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, child in action.choices.items():
                yield from _parsers(child, f"{path} {name}")




def test_every_option_and_command_has_help():
    missing = set()
    for path, p in _parsers(parser()):
        for action in p._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            name = action.option_strings[-1] if action.option_strings else (action.metavar or action.dest)
            if not action.help or action.help == argparse.SUPPRESS:
                missing.add((path, name))
            if isinstance(action, argparse._SubParsersAction):
                listed = {a.dest for a in action._choices_actions if a.help}
                missing |= {(path, name) for name in action.choices if name not in listed}
    assert missing == set()


def test_no_help_prints_a_literal_double_percent(capsys):
    pages = {path: p.format_help() for path, p in _parsers(parser())}
    assert len(pages) >= 12
    assert [path for path, text in pages.items() if "%%" in text] == []
    assert "(% FS)" in pages["optitact bench render"]

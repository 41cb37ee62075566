"""Issue 23, data loss and late or unclear errors: every case refused early, by name, with nothing lost.

* Data loss: ``--out`` pointing at a folder that holds inputs. A run plans every file it will write
  before any work (:func:`warpshade.measure._outputs.plan_outputs`) and never replaces a file that
  warpshade did not write there itself (the folder's manifest says which it did).
* Sizes that would not fit (``restarts``, ``view_resolution``, ``table_width``, an HDR header)
  are refused naming the parameter or file, before anything is allocated.
* ``specular = ["a", ...]`` names ``specular``; an HDR ``+Y`` orientation is read (flipped) and a
  rotated one is quoted as it is; ``component = "both"`` with ``--validate`` is refused before any
  work; a read-only cache names the directory and ``$WARPSHADE_CACHE``.
* Issue 39, the output layer under bad input: a forged or stale manifest entry never makes a file
  the run reads an output (a training clip, a BRDF table, a layer the scene pulls in); a link named
  like an output, a user's file named like a temporary of an interrupted write and a manifest that
  cannot be read are refused before any work; two runs recording into one folder at once keep
  each other's entries (the manifest's update is locked).

"Before any work" is asserted without timing: compiling the graph (which runs the precompute) is
replaced by a function that fails the test when called, and the output folder is left as it was.
"""

import errno
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from warpshade import cli
from warpshade.graph import GraphError, GraphSpec, Param, StageError, load
from warpshade.io import read_hdr, read_image, write_hdr
from warpshade.measure._outputs import MANIFEST_NAME, plan_outputs

from grids import CUBE_USDA as CUBE
from hang import START_S

ROOT = Path(__file__).resolve().parents[1]
ASSETS = ROOT / "warpshade" / "usd_assets"


@pytest.fixture(autouse=True)
def _private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("WARPSHADE_CACHE", str(tmp_path_factory.getbasetemp() / "outputs-cache"))


def _graph(path: Path, name: str, scene: str, stage: str = 'type = "prt.unshadowed"\norder = 2') -> Path:
    """A graph over ``scene`` stepping frames 0 and 1 (a static scene gets two time codes)."""
    static = "frame_count = 2\n" if not scene.startswith("bundled:") else ""
    path.write_text(f'[graph]\nname = "{name}"\nscene = "{scene}"\noutput = "shade.radiance"\nframes = "0:2"\n'
                    f'{static}\n[[stage]]\nname = "shade"\n{stage}\n')
    return path


def _no_work(monkeypatch):
    """Make compiling the graph (precompute, then frames) fail the test when it is reached."""
    def compile_(*args, **kwargs):
        raise AssertionError("the run started its work")

    monkeypatch.setattr(GraphSpec, "compile", compile_)


def _run(capsys, *argv) -> tuple[int, str]:
    rc = cli.main(list(argv))
    return rc, capsys.readouterr().err


def _snapshot(folder: Path) -> dict:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


# ---- 1. data loss: --out pointing at a folder that holds inputs -------------------------------------
@pytest.mark.parametrize("graph_name, usd_format, held", [
    ("figure", "auto", "figure.usda"),                 # the review's case: scene bend.usda, folder holds figure.usda
    ("wanderer_test", "usdc", "wanderer_test.usdc"),   # the review's case: --usd-format usdc
])
def test_an_input_named_like_the_usd_layer_is_kept_and_named_before_any_work(tmp_path, capsys, monkeypatch, graph_name,
                                                                             usd_format, held):
    out = tmp_path / "assets"
    out.mkdir()
    (out / held).write_bytes((ASSETS / held).read_bytes())
    before = _snapshot(out)
    g = _graph(tmp_path / "g.toml", graph_name, "bundled:bend")
    _no_work(monkeypatch)
    rc, err = _run(capsys, "run", str(g), "--out", str(out), "--usd-format", usd_format, "--device", "cpu")
    assert rc == 2 and f"already holds {held}" in err and "--out" in err and "Traceback" not in err, err
    assert _snapshot(out) == before, "the input is untouched and nothing was written"


@pytest.mark.parametrize("held, flags", [
    ("g.json", ()),                                        # the report
    ("g_0001.png", ()),                                    # a preview (frames 0:2: previews of 0 and 1)
    ("g_0000_vs_reference.png", ("--validate",)),          # a comparison picture
])
def test_an_input_named_like_any_output_is_kept_and_named_before_any_work(tmp_path, capsys, monkeypatch, held, flags):
    (tmp_path / "cube.usda").write_text(CUBE)
    out = tmp_path / "o"
    out.mkdir()
    (out / held).write_text("an input")
    g = _graph(tmp_path / "g.toml", "g", str(tmp_path / "cube.usda"))
    _no_work(monkeypatch)
    rc, err = _run(capsys, "run", str(g), "--out", str(out), "--device", "cpu", *flags)
    assert rc == 2 and f"already holds {held}" in err, err
    assert _snapshot(out) == {held: b"an input"}


def test_the_runs_own_scene_is_never_an_output_even_when_warpshade_wrote_it(tmp_path, capsys, monkeypatch):
    out = tmp_path / "o"
    out.mkdir()
    scene = out / "g.usda"
    scene.write_text(CUBE)
    st_ = scene.stat()
    (out / MANIFEST_NAME).write_text(json.dumps({"written": {"g.usda": {"size": st_.st_size,
                                                                        "mtime_ns": st_.st_mtime_ns}}}))
    g = _graph(tmp_path / "g.toml", "g", str(scene))
    _no_work(monkeypatch)
    rc, err = _run(capsys, "run", str(g), "--out", str(out), "--device", "cpu")
    assert rc == 2 and "g.usda (the run's own scene)" in err, err
    assert scene.read_text() == CUBE


def test_a_rerun_replaces_only_what_warpshade_wrote(device, tmp_path, capsys):
    (tmp_path / "cube.usda").write_text(CUBE)
    out = tmp_path / "o"
    g = _graph(tmp_path / "g.toml", "g", str(tmp_path / "cube.usda"))
    assert _run(capsys, "run", str(g), "--out", str(out), "--device", device)[0] == 0
    written = json.loads((out / MANIFEST_NAME).read_text())["written"]
    assert sorted(written) == sorted(p.name for p in out.iterdir() if p.name != MANIFEST_NAME) == [
        "g.json", "g.usda", "g_0000.png", "g_0001.png"]
    rc, err = _run(capsys, "run", str(g), "--out", str(out), "--device", device)
    assert rc == 0, err
    # a file of the same name put there since (not the one warpshade wrote) is kept
    (out / "g_0000.png").write_bytes(b"someone else's picture")
    rc, err = _run(capsys, "run", str(g), "--out", str(out), "--device", device)
    assert rc == 2 and "already holds g_0000.png" in err, err
    assert (out / "g_0000.png").read_bytes() == b"someone else's picture"


def test_the_plan_names_every_file_of_a_measured_pixel_run(tmp_path):
    plan = plan_outputs(tmp_path, "px", "px.usda", [0.0, 1.0, 2.0, 3.0], [0.0, 3.0], previews=True, validate=True,
                        pixels=True)
    assert sorted(p.name for p in plan.paths()) == sorted([
        "px.usda", "px.json", "px_0000.png", "px_0002.png", "px_0003.png", "px_0000_vs_reference.png",
        "px_0003_vs_reference.png", "px_px_0000.png", "px_px_0000.exr", "px_px_0002.png", "px_px_0002.exr",
        "px_px_0003.png", "px_px_0003.exr", "px_px_0000_vs_reference.png", "px_px_0003_vs_reference.png"])
    (tmp_path / "px_px_0002.exr").write_bytes(b"an input")
    with pytest.raises(FileExistsError, match=r"already holds px_px_0002\.exr"):
        plan.check()
    with pytest.raises(ValueError, match="was not planned"):
        plan.record([tmp_path / "other.png"])


# ---- issue 39: forged manifests, links, temporaries, two runs at once, a bad manifest ---------------
def _forge(out: Path, *names: str) -> None:
    """A manifest that claims ``names`` as warpshade's (their size and time as they are now)."""
    entries = {}
    for name in names:
        st_ = os.lstat(out / name)
        entries[name] = {"size": st_.st_size, "mtime_ns": st_.st_mtime_ns}
    (out / MANIFEST_NAME).write_text(json.dumps({"written": entries}))


def _dead_pid() -> int:
    """The id of a process that has ended."""
    done = subprocess.Popen([sys.executable, "-c", "pass"])
    done.wait()
    return done.pid


_TRAINED = ('type = "prt.unshadowed"\norder = 2\n\n[[stage]]\nname = "data"\ntype = "datadriven.data"\n'
            'training = "o/g.usda"\norder = 2\nsamples = 16')
_TABLE = 'type = "rpo.shade"\norder = 3\nrank = 4\neye = [0.0, -3.0, 1.0]\nbrdf = "tabulated"\nfile = "o/g.json"'


@pytest.mark.parametrize("case", ["training clip", "BRDF table", "sublayer of the scene"])
def test_a_forged_manifest_never_lets_a_run_replace_a_file_it_reads(tmp_path, capsys, monkeypatch, case):
    """A manifest entry that claims an input (forged, or stale: copied with the folder) does not
    make it an output: every file the graph reads is protected, not only the scene."""
    from warpshade.scene._materials import Microfacet
    from warpshade.scene._tabulated import write_merl

    out = tmp_path / "o"
    out.mkdir()
    scene = tmp_path / "cube.usda"
    scene.write_text(CUBE)
    if case == "training clip":      # datadriven.data's training clip, named like the USD layer
        (out / "g.usda").write_text(CUBE)
        g, held, reader = _graph(tmp_path / "g.toml", "g", str(scene), _TRAINED), "g.usda", "stage 'data' (parameter 'training')"
    elif case == "BRDF table":       # rpo.shade's MERL table, named like the report
        write_merl(out / "g.json", Microfacet(roughness=0.4), dims=(8, 8, 8))
        g = _graph(tmp_path / "g.toml", "g", str(scene), _TABLE)
        g.write_text(g.read_text().replace("[[stage]]", '[[stage]]\nname = "vis"\ntype = "rpo.visibility_traced"\n'
                                                        'order = 3\nsamples = 16\n\n[[stage]]', 1))
        held, reader = "g.json", "stage 'shade' (parameter 'file')"
    else:                            # the scene is a shot that sublayers a layer named like the USD layer
        (out / "g.usda").write_text(CUBE)
        scene.write_text('#usda 1.0\n(\n    subLayers = [@./o/g.usda@]\n    upAxis = "Z"\n)\n')
        g, held, reader = _graph(tmp_path / "g.toml", "g", str(scene)), "g.usda", "the run's scene"
    _forge(out, held)
    before = _snapshot(out)
    _no_work(monkeypatch)
    rc, err = _run(capsys, "run", str(g), "--out", str(out), "--device", "cpu")
    assert rc == 2 and f"already holds {held} (read by {reader})" in err and "--out" in err, err
    assert _snapshot(out) == before


def test_a_link_named_like_an_output_is_refused_whatever_the_manifest_says(tmp_path, capsys, monkeypatch):
    """``--out`` holding links named like outputs (the USD layer's write follows its link out of
    ``--out``): refused, the files they point to untouched."""
    (tmp_path / "cube.usda").write_text(CUBE)
    out = tmp_path / "o"
    out.mkdir()
    victims = {"g.usda": tmp_path / "victim.usda", "g_0000.png": tmp_path / "victim.png"}
    for name, victim in victims.items():
        victim.write_text(f"the user's {victim.name}")
        os.symlink(victim, out / name)
    _forge(out, *victims)
    g = _graph(tmp_path / "g.toml", "g", str(tmp_path / "cube.usda"))
    _no_work(monkeypatch)
    rc, err = _run(capsys, "run", str(g), "--out", str(out), "--device", "cpu")
    assert rc == 2 and f"g.usda (a symbolic link to {victims['g.usda']}" in err and "g_0000.png (a symbolic link" in err, err
    assert all(victim.read_text() == f"the user's {victim.name}" for victim in victims.values())
    assert all((out / name).is_symlink() for name in victims)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cube.usda", "g.toml", "o", "victim.png", "victim.usda"]


def test_a_users_file_named_like_a_temporary_is_kept(tmp_path, capsys, monkeypatch):
    """The clean-up after interrupted writes removes ``.<output>-<pid>-*`` files of ended
    processes: one the manifest does not list as warpshade's is the user's, and refused."""
    (tmp_path / "cube.usda").write_text(CUBE)
    out = tmp_path / "o"
    out.mkdir()
    notes = out / f".g-{_dead_pid()}-abcd1234.usda"  # exactly the shape of a temporary file
    notes.write_text("my notes")
    g = _graph(tmp_path / "g.toml", "g", str(tmp_path / "cube.usda"))
    _no_work(monkeypatch)
    rc, err = _run(capsys, "run", str(g), "--out", str(out), "--device", "cpu")
    assert rc == 2 and f"already holds {notes.name} (named like the temporary file" in err, err
    assert notes.read_text() == "my notes"


def test_a_users_file_of_another_shape_is_no_temporary(tmp_path):
    """Only mkstemp's exact name shape counts as a temporary file of an interrupted write: a
    user's ``.g-<pid>-notes.usda`` is neither refused nor removed by the clean-up."""
    from warpshade._fileio import remove_stale_temporaries, temporary_pattern

    pid = _dead_pid()
    mine = tmp_path / f".g-{pid}-notes.usda"
    mine.write_text("my notes")
    stale = tmp_path / f".g-{pid}-x_9abc12.usda"
    stale.write_text("left by a killed write")
    assert not temporary_pattern(tmp_path / "g.usda").match(mine.name)
    assert remove_stale_temporaries(tmp_path / "g.usda") == [stale]
    assert mine.read_text() == "my notes" and not stale.exists()


def test_the_temporaries_of_a_killed_run_are_still_removed(tmp_path):
    """A temporary file of a writer the manifest lists (a run killed while it wrote) is warpshade's:
    the plan passes and the next write of that file removes it; the checking process is entered
    as a writer."""
    from warpshade._fileio import write_json_atomic

    pid = _dead_pid()
    left = tmp_path / f".g-{pid}-x1y2z3w4.json"
    left.write_text("{")
    (tmp_path / MANIFEST_NAME).write_text(json.dumps({"written": {}, "writers": [pid]}))
    plan = plan_outputs(tmp_path, "g", "g.usda", [0.0], previews=False)
    plan.check()
    assert json.loads(plan.manifest.read_text())["writers"] == sorted([pid, os.getpid()])
    write_json_atomic(plan.report, {})
    plan.record([plan.report])
    assert not left.exists()
    assert json.loads(plan.manifest.read_text())["writers"] == [os.getpid()]  # the killed run's entry goes with it


@pytest.mark.parametrize("lock", ["flock", "lock directory"])
def test_two_runs_writing_into_one_folder_keep_each_others_entries(tmp_path, monkeypatch, lock):
    """The manifest's read-modify-write is locked (``flock`` on the folder, or the lock directory
    where there is none): two plans recording at once lose no entry."""
    import threading

    import warpshade.measure._outputs as outputs

    if lock == "lock directory":
        monkeypatch.setattr(outputs, "_flock_directory", lambda directory: None)
    write = outputs.write_json_atomic

    def slow_write(*args, **kwargs):  # widen the window between reading and writing the manifest
        time.sleep(0.004)
        return write(*args, **kwargs)

    monkeypatch.setattr(outputs, "write_json_atomic", slow_write)
    frames = list(range(24))
    plans = [plan_outputs(tmp_path, name, f"{name}.usda", frames, frames, validate=True) for name in ("a", "b")]
    failed = []

    def run(plan):
        try:
            for path in plan.comparisons.values():
                path.write_bytes(b"png")
                plan.record([path])
        except Exception as exc:  # shown by the assertion below
            failed.append(exc)

    threads = [threading.Thread(target=run, args=(plan,)) for plan in plans]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=START_S)
    assert not failed and not any(t.is_alive() for t in threads), failed
    written = json.loads((tmp_path / MANIFEST_NAME).read_text())["written"]
    assert sorted(written) == sorted(p.name for plan in plans for p in plan.comparisons.values())
    assert not (tmp_path / outputs.LOCK_NAME).exists()


def test_a_lock_directory_held_too_long_is_named(tmp_path, monkeypatch):
    import warpshade.measure._outputs as outputs

    monkeypatch.setattr(outputs, "_flock_directory", lambda directory: None)
    monkeypatch.setattr(outputs, "LOCK_TIMEOUT_S", 0.2)
    (tmp_path / outputs.LOCK_NAME).mkdir()
    plan = plan_outputs(tmp_path, "g", "g.usda", [0.0], previews=False)
    (tmp_path / "g.json").write_text("{}")
    with pytest.raises(TimeoutError, match=rf"{tmp_path}: {outputs.LOCK_NAME} has been held .* remove it"):
        plan.record([plan.report])
    assert not plan.manifest.exists()


@pytest.mark.parametrize("manifest, problem", [
    ("{", "is not valid JSON"),
    ("[1, 2]", "is not a manifest of warpshade"),
    ('{"written": ["g.usda"]}', "is not a manifest of warpshade"),
    ('{"written": {}, "writers": ["me"]}', "is not a manifest of warpshade"),
    (None, r"cannot be read \(Is a directory\)"),
    ("link", "is a symbolic link"),
])
def test_a_bad_manifest_is_named_before_any_work(tmp_path, capsys, monkeypatch, manifest, problem):
    """A manifest that cannot be read or is not one is named when the outputs are planned, not
    after the USD layer is written."""
    (tmp_path / "cube.usda").write_text(CUBE)
    out = tmp_path / "o"
    out.mkdir()
    if manifest is None:
        (out / MANIFEST_NAME).mkdir()
    elif manifest == "link":
        (tmp_path / "elsewhere.json").write_text('{"written": {}}')
        os.symlink(tmp_path / "elsewhere.json", out / MANIFEST_NAME)
    else:
        (out / MANIFEST_NAME).write_text(manifest)
    before = sorted(p.name for p in out.iterdir())
    g = _graph(tmp_path / "g.toml", "g", str(tmp_path / "cube.usda"))
    _no_work(monkeypatch)
    rc, err = _run(capsys, "run", str(g), "--out", str(out), "--device", "cpu")
    assert rc == 2 and f"{out}: its manifest {MANIFEST_NAME}" in err and "--out" in err, err
    assert re.search(problem, err), err
    assert sorted(p.name for p in out.iterdir()) == before
    if manifest not in (None, "link"):
        assert (out / MANIFEST_NAME).read_text() == manifest


# ---- 5. sizes that would not fit, named before allocating -------------------------------------------
@pytest.mark.parametrize("stage, parameter", [
    ('type = "ldprt.fit"\nrestarts = 1000000000', "restarts"),
    ('type = "ldprt.glossy_fit"\nrestarts = 1000000000', "restarts"),
    ('type = "ldprt.glossy_fit"\nview_resolution = 100000', "view_resolution"),
    ('type = "ldprt.glossy_shade"\nview_resolution = 100000', "view_resolution"),
    ('type = "ldprt.shade"\ntable_width = 10000000', "table_width"),
    ('type = "ldprt.glossy_shade"\ntable_width = 10000000', "table_width"),
])
def test_fit_and_table_sizes_that_would_not_fit_name_the_parameter(tmp_path, stage, parameter):
    g = _graph(tmp_path / "g.toml", "g", "cube.usda", stage)
    with pytest.raises(GraphError, match=rf"stage 'shade': parameter '{parameter}' must be <= \d+"):
        load(g)


def _hdr_bytes(tmp_path, image) -> bytes:
    write_hdr(tmp_path / "base.hdr", image)
    return (tmp_path / "base.hdr").read_bytes()


def _with_resolution_line(data: bytes, line: bytes) -> bytes:
    head, _, rest = data.partition(b"\n\n")
    return head + b"\n\n" + line + b"\n" + rest.partition(b"\n")[2]


def test_an_hdr_header_claiming_a_huge_image_names_the_file_and_limit(tmp_path):
    data = _with_resolution_line(_hdr_bytes(tmp_path, np.ones((2, 2, 3), np.float32)), b"-Y 2000000 +X 2000000")
    path = tmp_path / "huge.hdr"
    path.write_bytes(data)
    with pytest.raises(ValueError, match=r"huge\.hdr.*2000000x2000000 .* exceeds the limit of .* pixels an image may have"):
        read_image(path)


def test_hdr_orientation_lines_are_read_or_quoted(tmp_path):
    image = np.arange(4 * 3 * 3, dtype=np.float32).reshape(4, 3, 3) + 1.0
    data = _hdr_bytes(tmp_path, image)
    stored = read_hdr(tmp_path / "base.hdr")  # RGBE-rounded, rows top to bottom
    for line, expected in [(b"+Y 4 +X 3", stored[::-1]), (b"-Y 4 -X 3", stored[:, ::-1]),
                           (b"+Y 4 -X 3", stored[::-1, ::-1])]:
        path = tmp_path / "flipped.hdr"
        path.write_bytes(_with_resolution_line(data, line))
        np.testing.assert_array_equal(read_hdr(path), expected)
    path = tmp_path / "rotated.hdr"
    path.write_bytes(_with_resolution_line(data, b"+X 3 -Y 4"))
    with pytest.raises(ValueError, match=r"rotated\.hdr.*unsupported resolution line b'\+X 3 -Y 4'"):
        read_hdr(path)


# ---- 5. values named by their parameter ---------------------------------------------------------------
def test_a_specular_colour_of_words_names_specular(tmp_path):
    g = _graph(tmp_path / "g.toml", "g", "cube.usda", 'type = "rpo.shade"\nspecular = ["a", "b", "c"]')
    with pytest.raises(GraphError, match=r"stage 'shade': parameter 'specular' must hold numbers, got \('a', 'b', 'c'\)"):
        load(g)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.one_of(st.text(max_size=3), st.booleans(), st.none(), st.lists(st.integers(), max_size=2)),
                min_size=1, max_size=4))
def test_tuple_parameters_refuse_anything_but_numbers(values):
    with pytest.raises(StageError, match=r"parameter 'specular' must hold numbers"):
        Param((1.0, 1.0, 1.0), tuple, "colour").check("shade", "specular", [1.0, *values])


def test_component_both_with_validate_is_refused_before_any_work(tmp_path, capsys, monkeypatch):
    g = tmp_path / "sg_both.toml"
    g.write_text((ROOT / "stages" / "sunlit_sg.toml").read_text().replace('brdf = "beckmann"',
                                                                          'brdf = "beckmann"\ncomponent = "both"'))
    out = tmp_path / "o"
    _no_work(monkeypatch)
    rc, err = _run(capsys, "run", str(g), "--out", str(out), "--validate", "--device", "cpu")
    assert rc == 2 and "stage 'shade': component = 'both' has no single reference" in err, err
    assert not list(out.iterdir())


def test_tabulated_brdfs_with_validate_pass_the_checks_before_work(tmp_path, capsys, monkeypatch):
    """The glossy reference shades tabulated BRDFs: a table as the stage's BRDF or in the material
    track passes --validate's checks (the run reaches its work); a material the reference does
    not shade is refused before any work, naming the entry and the file."""
    from warpshade.scene._materials import Microfacet
    from warpshade.scene._tabulated import write_merl

    class Reached(Exception):
        pass

    def compile_(*args, **kwargs):
        raise Reached

    (tmp_path / "cube.usda").write_text(CUBE)
    write_merl(tmp_path / "gold.binary", Microfacet(roughness=0.4), dims=(8, 8, 8), rgb=(1.0, 0.78, 0.34))
    vis = '[[stage]]\nname = "vis"\ntype = "rpo.visibility_traced"\norder = 3\nsamples = 16\n\n'
    shade = 'type = "rpo.shade"\norder = 3\nrank = 4\neye = [0.0, -3.0, 1.0]'
    monkeypatch.setattr(GraphSpec, "compile", compile_)
    g = _graph(tmp_path / "stage.toml", "tab_stage", "cube.usda", shade + '\nbrdf = "tabulated"\nfile = "gold.binary"')
    g.write_text(g.read_text().replace("[[stage]]", vis + "[[stage]]", 1))
    rc, err = _run(capsys, "run", str(g), "--out", str(tmp_path / "o1"), "--validate", "--device", "cpu")
    assert "Reached" in err, err
    g = _graph(tmp_path / "track.toml", "tab_track", "cube.usda", shade)
    g.write_text(g.read_text().replace("[[stage]]", '[[material]]\nbrdf = "tabulated"\nfile = "gold.binary"\n\n' + vis +
                                       "[[stage]]", 1))
    rc, err = _run(capsys, "run", str(g), "--out", str(tmp_path / "o2"), "--validate", "--device", "cpu")
    assert "Reached" in err, err
    # a material the reference has no device form of: named with its file, before any work
    from warpshade.scene import _materials_warp as materials_warp

    def unsupported(brdf):
        raise ValueError("the ray-traced glossy reference does not shade BRDF 'tabulated'")

    monkeypatch.setattr(materials_warp, "check_reference_brdf", unsupported)
    _no_work(monkeypatch)
    rc, err = _run(capsys, "run", str(g), "--out", str(tmp_path / "o3"), "--validate", "--device", "cpu")
    assert rc == 2 and "[[material]] #1" in err and "gold.binary" in err and "does not shade" in err, err
    assert not (tmp_path / "o3").exists() or not list((tmp_path / "o3").iterdir())


def test_an_unwritable_cache_names_the_directory_and_variable_before_any_work(tmp_path, capsys, monkeypatch):
    (tmp_path / "cube.usda").write_text(CUBE)
    blocked = tmp_path / "a_file"
    blocked.write_text("x")
    monkeypatch.setenv("WARPSHADE_CACHE", str(blocked / "cache"))  # cannot be created (read-only as root too)
    g = _graph(tmp_path / "g.toml", "g", str(tmp_path / "cube.usda"))
    _no_work(monkeypatch)
    rc, err = _run(capsys, "run", str(g), "--out", str(tmp_path / "o"), "--device", "cpu")
    assert rc == 2 and f"artifact cache {blocked / 'cache'} is not writable" in err and "$WARPSHADE_CACHE" in err, err


def test_a_cache_that_refuses_a_write_names_the_directory_and_variable(tmp_path, monkeypatch):
    from warpshade.graph import ArtifactCache
    from warpshade.graph import _cache as cache_module

    def read_only(path, *args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", str(path))

    monkeypatch.setattr(cache_module, "atomic_path", read_only)
    with pytest.raises(OSError, match=rf"artifact cache {tmp_path}: cannot store k\.\w+\.npz \(Permission denied\); "
                                      r"set \$WARPSHADE_CACHE") as caught:
        ArtifactCache(tmp_path).store("k", {"a": np.zeros(2)})
    assert caught.value.errno == errno.EACCES

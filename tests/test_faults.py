"""Bad input and faults end in a clear message: no traceback, crash, wrong answer or lost data.

One test per family of the reliability review: output names that could escape ``--out``,
frame selections, the environment (files where directories are expected, a full disk, an
unwritable directory), sizes refused before allocating, late validation, misleading messages,
leftovers of killed writers, and the friction a new user meets. Cache faults are in
``tests/test_graph.py``; property-based fuzzing of the loaders in ``tests/test_fuzz_inputs.py``.
"""

import errno
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from warpshade import cli
from warpshade.graph import GraphError, GraphSpec, StageSpec, load
from warpshade.io import load_usd
from warpshade.scene import Environment, Mesh, Scene

ROOT = Path(__file__).resolve().parents[1]
CUBE = textwrap.dedent("""\
    #usda 1.0
    (
        upAxis = "Z"
        {extra}
    )
    def Mesh "Cube"
    {{
        int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]
        int[] faceVertexIndices = [0, 1, 3, 2, 2, 3, 7, 6, 6, 7, 5, 4, 4, 5, 1, 0, 2, 6, 4, 0, 7, 3, 1, 5]
        point3f[] points = [(-1, -1, -1), (1, -1, -1), (-1, 1, -1), (1, 1, -1), (-1, -1, 1), (1, -1, 1), (-1, 1, 1), (1, 1, 1)]
    }}
    """)


def _cube(path: Path, extra: str = "") -> Path:
    path.write_text(CUBE.format(extra=extra))
    return path


def _graph(path: Path, scene: Path, graph_extra: str = "", tables: str = "", stage: str = "") -> Path:
    path.write_text(textwrap.dedent(f"""\
        [graph]
        name = "g"
        scene = "{scene}"
        output = "shade.radiance"
        {graph_extra}
        {tables}
        [[stage]]
        name = "shade"
        type = "prt.unshadowed"
        order = 2
        {stage}
        """))
    return path


@pytest.fixture(autouse=True)
def _private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("WARPSHADE_CACHE", str(tmp_path_factory.getbasetemp() / "fault-cache"))


def _run(capsys, *argv) -> tuple[int, str, str]:
    rc = cli.main(list(argv))
    out, err = capsys.readouterr()
    return rc, out, err


# ---- 1. nothing is written outside --out ------------------------------------------------------
@pytest.mark.parametrize("name", ["/some/dir/precious", "../../x", "a/b", "..", ".hidden", "", "x" * 101, "a..b", "a b"])
def test_graph_names_that_could_leave_the_output_directory_are_refused(tmp_path, name):
    g = tmp_path / "g.toml"
    _graph(g, _cube(tmp_path / "cube.usda"))
    g.write_text(g.read_text().replace('name = "g"', f'name = "{name}"'))
    with pytest.raises(GraphError, match=r"\[graph\]: name .* is not allowed"):
        load(g)


def test_a_run_writes_only_into_out(device, tmp_path, capsys):
    precious = tmp_path / "precious.usda"
    precious.write_text("keep me")
    g = _graph(tmp_path / "g.toml", _cube(tmp_path / "cube.usda"))
    out = tmp_path / "out"
    rc, printed, err = _run(capsys, "run", str(g), "--out", str(out), "--device", device)
    assert rc == 0, err
    assert precious.read_text() == "keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cube.usda", "g.toml", "out", "precious.usda"]
    assert {p.suffix for p in out.iterdir()} == {".usda", ".json", ".png"}


# ---- 3/6. [validate] frames are decided before any work ---------------------------------------
def test_validate_frames_outside_the_run_are_left_out_and_reported(device, tmp_path, capsys):
    g = _graph(tmp_path / "g.toml", _cube(tmp_path / "cube.usda"), "frame_count = 8", "[validate]\nframes = [0, 6]\nsamples = 16")
    rc, printed, err = _run(capsys, "run", str(g), "--frames", "0:4", "--validate", "--out", str(tmp_path / "o"),
                            "--device", device, "--no-previews")
    assert rc == 0, err
    assert "[6.0] are outside the frames run" in printed
    report = json.loads((tmp_path / "o" / "g.json").read_text())
    assert [m["frame"] for m in report["error"]["per_frame"]] == [0.0] and report["error"]["frames_left_out"] == [6.0]


def test_validate_frames_all_outside_the_run_fail_before_any_work(tmp_path, capsys):
    g = _graph(tmp_path / "g.toml", _cube(tmp_path / "cube.usda"), "frame_count = 8", "[validate]\nframes = [6]")
    out = tmp_path / "o"
    rc, printed, err = _run(capsys, "run", str(g), "--frames", "0:4", "--validate", "--out", str(out), "--device", "cpu")
    assert rc == 2 and "[validate] frames [6] are all outside the frames run" in err
    assert not list(out.iterdir()), "nothing was computed or written"


@pytest.mark.parametrize("tables, message", [
    ("[validate]\nsamples = 0", r"\[validate\] samples must be >= 4"),
    ("[validate]\nsamples = 1e11", r"\[validate\] samples must be an integer"),
    ("[validate]\nsamples = 100000000000", r"exceeds the limit of 1048576 rays per vertex"),
    ("[validate]\nframes = [nan]", r"\[validate\] frames: frame must be finite"),
    ("[validate]\nframes = 3", r"\[validate\] frames must be a list"),
    ("[validate]\nsample = 4", r"\[validate\] has unknown key\(s\) \['sample'\]"),
    ("[lighting]\nintensity = \"bright\"", r"\[lighting\] intensity must be a number, got 'bright'"),
    ("[lighting]\nrotate_degrees_per_frame = inf", r"rotate_degrees_per_frame must be finite"),
    ("[lighting]\ncolor = [1, 2]", r"\[lighting\] color must be three numbers"),
    ("[lighting]\nsource = \"missing.hdr\"", r"missing.hdr"),
    ("[validat]\nsamples = 4", r"unknown table\(s\) \['validat'\]"),
])
def test_bad_tables_are_named_before_any_work(tmp_path, capsys, tables, message):
    g = _graph(tmp_path / "g.toml", _cube(tmp_path / "cube.usda"), tables=tables)
    rc, printed, err = _run(capsys, "run", str(g), "--out", str(tmp_path / "o"), "--device", "cpu")
    assert rc == 2, err
    assert len([line for line in err.splitlines() if line.startswith("warpshade")]) == 1 and "Traceback" not in err
    import re

    assert re.search(message, err), err


@pytest.mark.parametrize("graph_extra, message", [
    ('frame_count = "ten"', r"\[graph\] frame_count must be an integer, got 'ten'"),
    ("frame_count = 1000000000", r"frame_count = 1000000000 exceeds the limit of 100000 time codes"),
    ('ground_plane = "yes"', r"\[graph\] ground_plane must be true or false"),
    ("colour = 1", r"\[graph\] has unknown key 'colour'"),
    ('frames = "0:abc"', r"\[graph\] frames: 'abc' in '0:abc' is not a number"),
])
def test_bad_graph_keys_are_named(tmp_path, graph_extra, message):
    g = _graph(tmp_path / "g.toml", _cube(tmp_path / "cube.usda"), graph_extra)
    with pytest.raises(GraphError, match=message):
        load(g)


def test_stage_parameters_that_would_not_fit_are_refused(tmp_path):
    g = _graph(tmp_path / "g.toml", _cube(tmp_path / "cube.usda"))
    g.write_text(g.read_text().replace('type = "prt.unshadowed"\norder = 2',
                                       'type = "prt.trace"\norder = 2\nsamples = 100000000000'))
    with pytest.raises(GraphError, match=r"parameter 'samples' must be <= 1048576"):
        load(g)


# ---- 4. frames ----------------------------------------------------------------------------------
@pytest.mark.parametrize("frames, message", [("nan", "is not a finite time code"), ("abc", "'abc' in 'abc' is not a number"),
                                             ("inf:3", "is not a finite time code"), ("7", "frame 7")])
def test_bad_frame_flags_name_the_flag(tmp_path, capsys, frames, message):
    g = _graph(tmp_path / "g.toml", _cube(tmp_path / "cube.usda"), "frame_count = 4")
    with pytest.raises(SystemExit) if frames != "7" else _nothing():
        rc, printed, err = _run(capsys, "run", str(g), "--frames", frames, "--out", str(tmp_path / "o"))
    captured = capsys.readouterr().err if frames != "7" else err
    assert "--frames" in captured and message in captured, captured


class _nothing:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_step_refuses_frames_that_are_not_time_codes(device):
    box = Mesh("/box", [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    scene = Scene.from_meshes([box], frames=range(3), lights=[Environment.constant()])
    rt = GraphSpec([StageSpec("shade", "prt.unshadowed", {"order": 2})], "shade.radiance").compile(
        scene, device=device, cache_dir=None, progress=False)
    for bad, error, message in [(float("nan"), ValueError, "finite"), (True, TypeError, "number"), ("3", TypeError, "number"),
                                (1.5, ValueError, "not one of the sampled time codes")]:
        with pytest.raises(error, match=message):
            rt.step(bad)
    assert np.all(np.isfinite(rt.step(2).numpy()))


# ---- 5. the environment -----------------------------------------------------------------------
def test_environment_errors_are_one_line(tmp_path, capsys, monkeypatch):
    g = _graph(tmp_path / "g.toml", _cube(tmp_path / "cube.usda"))
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    cases = [
        (("run", str(g), "--out", str(a_file)), "--out directory .* is an existing file"),
        (("run", str(tmp_path)), "is a directory, not a TOML file"),
        (("run", str(g), "--out", str(a_file / "sub")), "is not writable|is an existing file"),
        (("run", str(tmp_path / "nope.toml")), "not found"),
        (("info", str(tmp_path / "nope.usda")), "does not exist|not found"),
        (("run", str(g), "--device", "cuda:7"), "device 'cuda:7' is not available"),
    ]
    import re

    for argv, message in cases:
        rc, out, err = _run(capsys, *argv)
        assert rc == 2 and re.search(message, err) and "Traceback" not in err, (argv, err)
    # a full disk while the USD layer is written
    import warpshade.io._usd_write as usd_write

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "o" / "g.usda"))

    monkeypatch.setattr(usd_write, "_author", full)
    rc, out, err = _run(capsys, "run", str(g), "--out", str(tmp_path / "o"), "--device", "cpu", "--no-previews")
    errors = [line for line in err.splitlines() if line.startswith("warpshade")]
    assert rc == 2 and len(errors) == 1 and "No space left on device" in errors[0] and "Errno" not in errors[0], err
    assert not [p for p in (tmp_path / "o").iterdir() if p.name.startswith(".")], "no temporary file left"


def test_selfcheck_order_out_of_range_names_the_flag(capsys):
    with pytest.raises(SystemExit):
        cli.main(["selfcheck", "--order", "0"])
    assert "argument --order: must be in 1..12, got 0" in capsys.readouterr().err


def test_time_ranges_too_long_to_sample_are_refused(tmp_path):
    big = _cube(tmp_path / "long.usda", "startTimeCode = 0\n    endTimeCode = 1000000000")
    with pytest.raises(ValueError, match=r"endTimeCode 1e\+09 spans 1,000,000,001 time codes; at most 100,000"):
        load_usd(big)


def test_unexpected_errors_point_to_debug(tmp_path, capsys, monkeypatch):
    def boom(args):
        raise RuntimeError("a bug")

    monkeypatch.setattr(cli, "_cmd_list_stages", boom)
    monkeypatch.setattr(cli, "build_parser", _parser_with(cli.build_parser, "list-stages", boom))
    rc, out, err = _run(capsys, "list-stages")
    assert rc == 1 and "unexpected error: RuntimeError: a bug" in err and "--debug" in err
    with pytest.raises(RuntimeError, match="a bug"):
        cli.main(["--debug", "list-stages"])


def _parser_with(build, command, func):
    def patched():
        parser = build()
        for action in parser._subparsers._group_actions:
            action.choices[command].set_defaults(func=func)
        return parser

    return patched


# ---- 7. messages that name the cause -----------------------------------------------------------
def test_missing_sublayer_names_the_missing_file(tmp_path):
    usd = _cube(tmp_path / "with_sublayer.usda", "subLayers = [@./missing_layer.usda@]")
    with pytest.raises(ValueError, match=r"missing_layer\.usda"):
        load_usd(usd)


def test_binary_junk_as_toml_is_named(tmp_path):
    junk = tmp_path / "junk.toml"
    junk.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(GraphError, match="is not a text"):
        load(junk)


# ---- 8. leftovers of killed writers -------------------------------------------------------------
def test_temporary_files_of_dead_writers_are_removed(device, tmp_path, capsys):
    g = _graph(tmp_path / "g.toml", _cube(tmp_path / "cube.usda"))
    out = tmp_path / "o"
    out.mkdir()
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        dead_pid = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                                  text=True).stdout.strip()
        stale = out / f".g-{dead_pid}-abc12345.usda"
        stale.write_bytes(b"x" * 1000)
        live = out / f".g-{child.pid}-def45678.usda"
        live.write_bytes(b"x")
        # both writers are warpshade runs the folder's manifest lists (a temporary file of a
        # process it does not list is a user's file and refused: test_faults_outputs.py)
        (out / ".warpshade-outputs.json").write_text(json.dumps({"written": {}, "writers": [int(dead_pid), child.pid]}))
        rc, printed, err = _run(capsys, "run", str(g), "--out", str(out), "--device", device, "--no-previews")
        assert rc == 0, err
        assert not stale.exists(), "a dead writer's temporary file is removed"
        assert live.exists(), "a running writer's temporary file is kept"
    finally:
        child.kill()
        child.wait()


# ---- 9. friction --------------------------------------------------------------------------------
def test_help_is_plain_text_and_every_flag_says_what_it_does(capsys):
    parser = cli.build_parser()
    assert "``" not in parser.format_help()
    for sub in parser._subparsers._group_actions[0].choices.values():
        for action in sub._actions:
            assert action.help, f"{sub.prog}: {action.option_strings or action.dest} has no help text"


def test_list_stages_shows_parameters(capsys):
    assert cli.main(["list-stages"]) == 0
    out = capsys.readouterr().out
    assert "prt.transfer" in out and "samples" in out and "range [16, 1048576]" in out


def test_no_cuda_driver_note_unless_cuda_is_asked_for():
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    res = subprocess.run([sys.executable, "-m", "warpshade.cli", "list-stages", "--brief"], capture_output=True, text=True,
                         env=env, cwd=str(ROOT))
    assert res.returncode == 0 and "CUDA" not in res.stderr, res.stderr


def test_the_readme_python_loop_writes_usd(device, tmp_path):
    from warpshade.measure import write_usd

    box = Mesh("/box", [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    scene = Scene.from_meshes([box], frames=range(3), lights=[Environment.constant()])
    rt = GraphSpec([StageSpec("shade", "prt.unshadowed", {"order": 2})], "shade.radiance").compile(
        scene, device=device, cache_dir=None, progress=False)
    for frame in rt.scene.frames:
        rt.step(frame, record=True)
    assert write_usd(rt, tmp_path / "loop.usda").exists()
    bare = GraphSpec([StageSpec("shade", "prt.unshadowed", {"order": 2})], "shade.radiance").compile(
        scene, device=device, cache_dir=None, progress=False)
    bare.step(0.0)
    with pytest.raises(ValueError, match=r"record=True"):
        write_usd(bare, tmp_path / "none.usda")


def test_large_outputs_are_binary_usd():
    from warpshade.io._usd_write import USDA_MAX_BYTES, usd_output_name

    class _Scene:
        vertex_count = 2_000_000

    assert usd_output_name("g", _Scene(), 4) == "g.usdc"
    _Scene.vertex_count = 100
    assert usd_output_name("g", _Scene(), 4) == "g.usda" and 100 * 4 * 12 < USDA_MAX_BYTES
    assert usd_output_name("g", _Scene(), 4, "usdc") == "g.usdc"
    with pytest.raises(ValueError, match="USD format"):
        usd_output_name("g", _Scene(), 4, "obj")

"""Issue 39, paths under bad input: a prefixed scene name that leads out of its directory, and the
asset generator's ``--out`` that cannot be written.

* ``bundled:NAME`` (and ``warp-example:NAME``) name a file in their directory: a NAME that leads
  out of it (``../..``, an absolute path) is refused, naming the spec, before any file is read;
  from the API, ``warpshade info`` and a graph's ``scene``.
* ``python -m warpshade.usd_assets.generator --out X`` with X a file, below a file or not writable
  ends in one line naming X and exit status 2, not a traceback, and writes nothing.
"""

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from warpshade import cli
from warpshade.graph import GraphSpec
from warpshade.io import bundled_asset_directory, resolve_scene_path
from warpshade.usd_assets.generator.__main__ import main as generator_main

from hang import HANG_S

ROOT = Path(__file__).resolve().parents[1]
BUNDLED = Path(bundled_asset_directory())


@pytest.fixture
def outside(tmp_path) -> Path:
    """A copy of the bundled bend.usda outside the bundled directory."""
    copy = tmp_path / "bend.usda"
    shutil.copyfile(BUNDLED / "bend.usda", copy)
    return copy


def _escapes(outside: Path) -> list[str]:
    up = os.path.relpath(outside, BUNDLED)
    return [f"bundled:{up}", f"bundled:{up[: -len('.usda')]}", f"bundled:{outside}"]


# ---- 5. bundled:NAME stays in the bundled scenes -----------------------------------------------------
def test_a_bundled_name_that_leads_out_of_the_bundled_scenes_is_refused(outside):
    assert resolve_scene_path("bundled:bend") == os.path.join(BUNDLED, "bend.usda")  # an ordinary name still works
    for spec in _escapes(outside):
        with pytest.raises(ValueError, match=rf"scene spec '{spec}': .* leads out of the directory of the bundled "
                                             r"scenes .*give another file by its path"):
            resolve_scene_path(spec)
    assert resolve_scene_path(str(outside)) == str(outside)  # the file itself, by its path


def test_a_warp_example_name_that_leads_out_of_warps_assets_is_refused(tmp_path):
    pytest.importorskip("warp.examples")
    import warp.examples

    target = tmp_path / "bunny.usd"
    target.write_text("#usda 1.0\n")
    spec = f"warp-example:{os.path.relpath(target, warp.examples.get_asset_directory())}"
    with pytest.raises(ValueError, match=r"leads out of the directory of Warp's example assets"):
        resolve_scene_path(spec)


def test_the_cli_refuses_a_bundled_name_out_of_the_bundled_scenes(outside, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(GraphSpec, "compile", lambda *a, **k: pytest.fail("the run started its work"))
    spec = _escapes(outside)[0]
    assert cli.main(["info", spec]) == 2
    err = capsys.readouterr().err
    assert f"scene spec '{spec}'" in err and "leads out of" in err and "Traceback" not in err, err
    g = tmp_path / "g.toml"
    g.write_text(f'[graph]\nname = "g"\nscene = "{spec}"\noutput = "shade.radiance"\n\n'
                 '[[stage]]\nname = "shade"\ntype = "prt.unshadowed"\norder = 2\n')
    out = tmp_path / "o"
    assert cli.main(["run", str(g), "--out", str(out), "--device", "cpu"]) == 2
    err = capsys.readouterr().err
    assert f"scene spec '{spec}'" in err and "leads out of" in err, err
    assert not list(out.iterdir())


# ---- 6. the asset generator's --out -------------------------------------------------------------------
@pytest.mark.parametrize("where, message", [
    ("a file", "is an existing file, not a directory"),
    ("below a file", r"is not writable \(Not a directory\)"),
])
def test_the_generator_names_an_out_it_cannot_write(tmp_path, capsys, where, message):
    a_file = tmp_path / "scenes.usda"
    a_file.write_text("a user's file")
    out = a_file if where == "a file" else a_file / "sub"
    assert generator_main(["--out", str(out), "--scenes", "bend"]) == 2
    printed = capsys.readouterr()
    lines = printed.err.strip().splitlines()
    assert len(lines) == 1 and f"--out directory {out} " in lines[0] and re.search(message, lines[0])
    assert lines[0].startswith("python -m warpshade.usd_assets.generator: error: ") and not printed.out
    assert a_file.read_text() == "a user's file" and sorted(p.name for p in tmp_path.iterdir()) == ["scenes.usda"]


def test_the_generator_names_a_directory_it_may_not_write(tmp_path, capsys, monkeypatch):
    """A directory without write permission (simulated where the tests run as root, who may write
    anywhere): the probe's PermissionError becomes one line naming it."""
    import tempfile

    out = tmp_path / "read_only"
    out.mkdir()
    if os.geteuid() != 0:
        out.chmod(0o555)
    else:
        mkstemp = tempfile.mkstemp

        def refused(*args, dir=None, **kwargs):
            if dir is not None and Path(dir) == out:
                raise PermissionError(13, "Permission denied", str(Path(dir) / "probe"))
            return mkstemp(*args, dir=dir, **kwargs)

        monkeypatch.setattr(tempfile, "mkstemp", refused)
    try:
        assert generator_main(["--out", str(out), "--scenes", "bend"]) == 2
    finally:
        out.chmod(0o755)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"--out directory {out} is not writable (Permission denied)" in err[0], err
    assert not list(out.iterdir())


def test_the_generator_exits_2_from_the_command_line(tmp_path):
    a_file = tmp_path / "x"
    a_file.write_text("keep")
    done = subprocess.run([sys.executable, "-m", "warpshade.usd_assets.generator", "--out", str(a_file), "--scenes", "bend"],
                          cwd=ROOT, capture_output=True, text=True, timeout=HANG_S)
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert [line for line in done.stderr.splitlines() if line.strip()] == [
        f"python -m warpshade.usd_assets.generator: error: --out directory {a_file} is an existing file, not a directory"]
    assert a_file.read_text() == "keep"


@pytest.mark.parametrize("name", ["bundled:../../../etc/hostname", "bundled:/etc/hostname"])
def test_a_stage_file_parameter_cannot_leave_the_bundled_assets(name):
    """A stage's file parameter (a BRDF table, a texture, a training clip) named bundled:... stays
    in the bundled assets, like a scene spec."""
    from warpshade.graph import StageContext

    ctx = StageContext(scene=None, device="cpu", dims={})
    with pytest.raises(ValueError, match="leads out of the directory of the bundled assets"):
        ctx.resolve_path(name)
    assert ctx.resolve_path("bundled:sky.hdr").is_file()

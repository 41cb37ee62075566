"""Movies of a run (issue 26, item 4): ``warpshade run GRAPH --movie``.

A short run of a small scene writes ``<graph>.mp4`` (or ``.gif`` where ffmpeg is missing) with one
movie frame per frame run, and with ``--validate`` ``<graph>_vs_reference.mp4`` with one strip
per validated frame; both are planned before any work and recorded in the output folder's
manifest. Flags that cannot go together are refused before any work, naming both.
"""

import json
from pathlib import Path

import numpy as np
import pytest

from warpshade import cli
from warpshade.graph import GraphSpec
from warpshade.measure._outputs import MANIFEST_NAME, plan_outputs
from warpshade.measure._pictures import movie_format, write_movie

from grids import CUBE_USDA as CUBE

imageio = pytest.importorskip("imageio.v3")

FRAME_COUNT = 4


@pytest.fixture(autouse=True)
def _private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("WARPSHADE_CACHE", str(tmp_path_factory.getbasetemp() / "movie-cache"))


def _graph(tmp_path: Path) -> Path:
    """A cube on a ground plane under a turning sky, unshadowed order 2, frames 0..3, validated on 0 and 3."""
    (tmp_path / "cube.usda").write_text(CUBE)
    g = tmp_path / "m.toml"
    g.write_text(f'[graph]\nname = "m"\nscene = "{tmp_path / "cube.usda"}"\nground_plane = true\n'
                 f'frame_count = {FRAME_COUNT}\noutput = "shade.radiance"\n\n[lighting]\nrotate_degrees_per_frame = 30.0\n\n'
                 '[validate]\nframes = [0, 3]\nsamples = 16\n\n[[stage]]\nname = "shade"\ntype = "prt.unshadowed"\n'
                 'order = 2\n')
    return g


def _frames(path: Path) -> np.ndarray:
    return imageio.imread(path, index=None)


def test_a_run_with_movie_writes_one_movie_frame_per_frame_run(device, tmp_path, capsys):
    out = tmp_path / "o"
    rc = cli.main(["run", str(_graph(tmp_path)), "--out", str(out), "--device", device, "--movie", "--validate"])
    assert rc == 0, capsys.readouterr().err
    suffix = movie_format()
    movie, strips = out / f"m.{suffix}", out / f"m_vs_reference.{suffix}"
    frames = _frames(movie)
    assert frames.shape[0] == FRAME_COUNT and frames.shape[-1] == 3, frames.shape
    assert frames.dtype == np.uint8 and frames.std() > 1.0          # a picture, not a blank
    assert not np.array_equal(frames[0], frames[-1])                  # the sky turns between them
    assert _frames(strips).shape[0] == 2                              # validated frames 0 and 3
    written = json.loads((out / MANIFEST_NAME).read_text())["written"]
    assert {movie.name, strips.name} <= set(written)
    printed = capsys.readouterr().out
    assert f"movie   {movie}" in printed and f"movie   {strips}" in printed
    # a rerun replaces the movies warpshade wrote
    assert cli.main(["run", str(_graph(tmp_path)), "--out", str(out), "--device", device, "--movie"]) == 0


def test_movie_with_no_previews_is_refused_before_any_work(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(GraphSpec, "compile", lambda *a, **k: pytest.fail("the run started its work"))
    rc = cli.main(["run", str(_graph(tmp_path)), "--out", str(tmp_path / "o"), "--movie", "--no-previews"])
    err = capsys.readouterr().err
    assert rc == 2 and "--movie and --no-previews" in err, err
    assert not (tmp_path / "o").exists()


def test_a_movie_named_like_an_input_is_refused_before_any_work(tmp_path, capsys, monkeypatch):
    out = tmp_path / "o"
    out.mkdir()
    held = out / f"m.{movie_format()}"
    held.write_bytes(b"someone else's movie")
    monkeypatch.setattr(GraphSpec, "compile", lambda *a, **k: pytest.fail("the run started its work"))
    rc = cli.main(["run", str(_graph(tmp_path)), "--out", str(out), "--movie"])
    err = capsys.readouterr().err
    assert rc == 2 and f"already holds {held.name}" in err, err
    assert held.read_bytes() == b"someone else's movie"


def test_without_imageio_movie_names_what_to_install(tmp_path, capsys, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "imageio", None)   # import imageio raises ImportError
    monkeypatch.setattr(GraphSpec, "compile", lambda *a, **k: pytest.fail("the run started its work"))
    rc = cli.main(["run", str(_graph(tmp_path)), "--out", str(tmp_path / "o"), "--movie"])
    err = capsys.readouterr().err
    assert rc == 2 and "--movie" in err and "pip install imageio imageio-ffmpeg" in err, err


def test_the_plan_names_the_movies(tmp_path):
    plan = plan_outputs(tmp_path, "g", "g.usda", [0.0, 1.0, 2.0], [0.0, 2.0], validate=True, movie="gif")
    assert plan.movie.name == "g.gif" and plan.comparison_movie.name == "g_vs_reference.gif"
    assert plan.movie in plan.paths() and plan.comparison_movie in plan.paths()
    plan = plan_outputs(tmp_path, "g", "g.usda", [0.0, 1.0], movie="mp4")
    assert plan.movie.name == "g.mp4" and plan.comparison_movie is None
    with pytest.raises(ValueError, match="'mp4' or 'gif'"):
        plan_outputs(tmp_path, "g", "g.usda", [0.0], movie="avi")


@pytest.mark.parametrize("suffix", [".gif", ".mp4"])
def test_write_movie_keeps_frame_count_and_pads_odd_sizes(tmp_path, suffix):
    if suffix == ".mp4" and movie_format() != "mp4":
        pytest.skip("no ffmpeg binary (imageio-ffmpeg)")
    rng = np.random.default_rng(0)
    images = [np.full((15, 21, 3), 40 * i, np.uint8) + rng.integers(0, 8, (15, 21, 3), dtype=np.uint8) for i in range(5)]
    path = write_movie(tmp_path / f"a{suffix}", iter(images), fps=12)
    frames = _frames(path)
    assert frames.shape[0] == 5 and frames.shape[1:3] in [(15, 21), (16, 22)], frames.shape
    assert [p.name for p in tmp_path.iterdir()] == [path.name]      # no temporary left behind


def test_write_movie_refuses_bad_frames_and_leaves_nothing(tmp_path):
    with pytest.raises(ValueError, match="no frames"):
        write_movie(tmp_path / "a.gif", [], fps=10)
    with pytest.raises(ValueError, match="frame 1 is"):
        write_movie(tmp_path / "a.gif", [np.zeros((4, 4, 3), np.uint8), np.zeros((4, 6, 3), np.uint8)], fps=10)
    with pytest.raises(ValueError, match="fps must be > 0"):
        write_movie(tmp_path / "a.gif", [np.zeros((4, 4, 3), np.uint8)], fps=0)
    assert list(tmp_path.iterdir()) == []

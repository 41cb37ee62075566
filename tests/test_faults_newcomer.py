"""What a new user meets first (issue 23, family 7): the README's commands work as written, the
run says what it measures, progress is visible and log-friendly, pictures of a run compare, the
cache follows the platform convention, and a known error is explained where it is reported.
"""

import io
import json
import re
import shlex
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest

from warpshade import cli
from warpshade.tasks import progress_bar
from warpshade.graph import default_cache_dir, load
from warpshade.measure import Measurement, render_comparisons, run_exposure
from warpshade.measure._pictures import ERROR_LABEL, write_panels
from warpshade.scene._materials import Microfacet
from warpshade.scene._tabulated import read_merl, write_merl

from grids import CUBE_USDA as CUBE

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
#: Rays of the quick copies of README graphs (the README's 256 / 1024 take minutes on a CPU).
QUICK_SAMPLES = 16


@pytest.fixture(autouse=True)
def _private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("WARPSHADE_CACHE", str(tmp_path_factory.getbasetemp() / "newcomer-cache"))


def _cube_graph(tmp_path: Path, extra: str = "") -> Path:
    (tmp_path / "cube.usda").write_text(CUBE)
    g = tmp_path / "g.toml"
    g.write_text(textwrap.dedent(f"""\
        [graph]
        name = "g"
        scene = "cube.usda"
        output = "shade.radiance"
        frame_count = 8
        {extra}
        [[stage]]
        name = "shade"
        type = "prt.unshadowed"
        order = 2
        """))
    return g


def _readme_run_command() -> list[str]:
    line = next(ln for ln in README.splitlines() if ln.startswith("warpshade run stages/bunny_prt.toml"))
    return shlex.split(line.split("#")[0])[1:]


# ---- (a) the README's run command validates only frames it runs -------------------------------
def test_readme_run_command_runs_every_validate_frame():
    argv = _readme_run_command()
    assert "--validate" in argv
    spec = load(ROOT / argv[1])
    scene = spec.load_scene()
    run = spec.run_frames(scene, argv[argv.index("--frames") + 1])
    measured, left_out = spec.validation_frames(scene, run)
    assert left_out == [] and measured == [float(f) for f in spec.validate_spec["frames"]]


def test_readme_run_command_as_written_with_quick_samples(tmp_path, capsys):
    argv = _readme_run_command()
    quick = tmp_path / "bunny_prt.toml"
    quick.write_text(re.sub(r"samples = \d+", f"samples = {QUICK_SAMPLES}", (ROOT / argv[1]).read_text()))
    argv[1] = str(quick)
    argv[argv.index("--out") + 1] = str(tmp_path / "out")
    rc = cli.main([*argv, "--no-previews"])
    _, err = capsys.readouterr()
    assert rc == 0, err
    report = json.loads((tmp_path / "out" / "bunny_prt.json").read_text())
    assert [m["frame"] for m in report["error"]["per_frame"]] == [0.0, 24.0]
    assert "frames_left_out" not in report["error"] and "left out" not in err


def test_validate_frames_left_out_are_named_before_the_run(tmp_path, capsys):
    g = _cube_graph(tmp_path, "[validate]\nframes = [0, 6]\nsamples = 16")
    rc = cli.main(["run", str(g), "--frames", "0:4", "--validate", "--out", str(tmp_path / "o"), "--no-previews",
                   "--device", "cpu"])
    _, err = capsys.readouterr()
    assert rc == 0, err
    note = "--validate measures frame(s) 0; [validate] frame(s) 6 are outside the frames run (0..3)"
    assert note in err and err.index(note) < err.index("frames:"), "said before the frame loop"


# ---- (b) the README's tabulated-BRDF example, and coloured tables ------------------------------
def test_readme_rpo_example_reads_only_files_it_writes():
    block = next(b for b in re.findall(r"```python\n(.*?)```", README, re.S) if "read_merl" in b)
    read = set(re.findall(r'read_merl\("([^"]+)"', block))
    written = set(re.findall(r'write_merl\("([^"]+)"', block))
    assert read and read <= written


def test_read_merl_keeps_colour_by_default_and_warns_when_asked_for_grey(tmp_path):
    gold = write_merl(tmp_path / "gold.binary", Microfacet(roughness=0.4), dims=(8, 8, 8), rgb=(1.0, 0.78, 0.34))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        brdf = read_merl(gold)
    assert brdf.channel == "rgb" and [c.channel for c in brdf.color_channels()] == ["r", "g", "b"]
    with pytest.warns(UserWarning, match=r"gold\.binary: the table is coloured .* specular = \[1\.\d+, 0\.\d+, 0\.\d+\]"):
        grey = read_merl(gold, channel="luminance")
    assert grey.color_channels() is None
    plain = write_merl(tmp_path / "grey.binary", Microfacet(roughness=0.4), dims=(8, 8, 8))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_merl(plain, channel="luminance")
        read_merl(gold, channel="r")


# ---- (c, d) progress: ground truth shows it, and logs get lines, not carriage returns ----------
def test_progress_bar_writes_plain_lines_where_stderr_is_no_terminal():
    log = io.StringIO()
    with progress_bar(total=1000, desc="work", unit="item", leave=False, stream=log, interval_s=3600.0) as bar:
        for _ in range(1000):
            bar.update(1)
        bar.set_postfix(E="0.1", refresh=False)
    text = log.getvalue()
    lines = text.splitlines()
    assert "\r" not in text and "\x1b" not in text
    assert len(lines) == 2 and lines[0].startswith("work:   0%") and "1000/1000" in lines[-1]


def test_progress_bar_redraws_in_place_on_a_terminal():
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    tty = Terminal()
    with progress_bar(total=3, desc="work", stream=tty, interval_s=0.0) as bar:
        bar.update(3)
    assert "\r" in tty.getvalue()


@pytest.mark.parametrize("scheduler", [[], ["--scheduler", "serial"]], ids=["in-process", "executor"])
def test_ground_truth_frames_show_progress_in_plain_lines(tmp_path, capsys, monkeypatch, scheduler):
    monkeypatch.setenv("WARPSHADE_CACHE", str(tmp_path / "cache"))  # nothing cached: both frames computed
    monkeypatch.delenv("WARPSHADE_SCHEDULER", raising=False)
    g = _cube_graph(tmp_path, "[validate]\nframes = [0, 3]\nsamples = 16")
    rc = cli.main(["run", str(g), "--validate", "--out", str(tmp_path / "o"), "--no-previews", "--device", "cpu",
                   *scheduler])
    _, err = capsys.readouterr()
    assert rc == 0, err
    assert re.search(r"ground truth \(16 spp\): 100%.* 2/2", err), err
    assert "\r" not in err


# ---- (e) one exposure for every picture of a run ------------------------------------------------
def test_comparisons_of_a_run_share_one_exposure(tmp_path, monkeypatch):
    import warpshade.render

    rt = load(_cube_graph(tmp_path)).compile(device="cpu", progress=False)
    rt.run([0.0, 1.0])
    ref = rt.results[0.0].astype(np.float64)
    measurement = Measurement({}, {0.0: ref, 1.0: 10.0 * ref}, {0.0: ref, 1.0: 10.0 * ref})
    exposures = []
    real = warpshade.render.render

    def recording(*args, **kwargs):
        if "environment" in kwargs:  # the method and reference panels (the error panel has none)
            exposures.append(kwargs["exposure"])
        return real(*args, **kwargs)

    monkeypatch.setattr(warpshade.render, "render", recording)
    render_comparisons(rt, measurement, tmp_path, width=16, height=12)
    assert len(exposures) == 4 and set(exposures) == {run_exposure(rt)}


# ---- (f) comparison strips carry titles and a labelled colour bar -------------------------------
def test_panels_have_titles_and_a_labelled_colour_bar(tmp_path, monkeypatch):
    import matplotlib.figure

    seen = {}
    real = matplotlib.figure.Figure.savefig

    def recording(fig, *args, **kwargs):
        seen["titles"] = [ax.get_title() for ax in fig.axes[:3]]
        seen["bar"] = fig.axes[3].get_ylabel()
        return real(fig, *args, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", recording)
    image = np.zeros((12, 16, 3), np.uint8)
    path = write_panels(tmp_path / "strip.png", [image] * 3, ["method: m", "reference: r", "error"], caption="frame 0")
    assert path.exists() and seen == {"titles": ["method: m", "reference: r", "error"], "bar": ERROR_LABEL}
    with pytest.raises(ValueError, match="three uint8"):
        write_panels(tmp_path / "bad.png", [image, image, image[:4]], ["a", "b", "c"])


def test_pixel_error_panel_maps_the_signed_error():
    from warpshade.measure._pixels import _error_image

    ref = np.ones((4, 4, 3))
    est = ref.copy()
    est[0, 0] *= 1.5
    mask = np.ones((4, 4), bool)
    mask[3, 3] = False
    img, err = _error_image(est, ref, mask)
    assert img.dtype == np.uint8 and img.shape == (4, 4, 3) and err.shape == (15,)
    assert img[0, 0, 0] > img[0, 0, 2], "too bright is red"
    assert tuple(img[3, 3]) == (128, 128, 128), "uncovered pixels are the grey background"


# ---- (g) the cache follows $XDG_CACHE_HOME ------------------------------------------------------
def test_default_cache_dir_follows_the_platform_convention(tmp_path, monkeypatch):
    monkeypatch.delenv("WARPSHADE_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert default_cache_dir() == tmp_path / "xdg" / "warpshade"
    monkeypatch.setenv("XDG_CACHE_HOME", "relative/path")
    assert default_cache_dir() == Path.home() / ".cache" / "warpshade"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert default_cache_dir() == Path.home() / ".cache" / "warpshade"
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.setenv("WARPSHADE_CACHE", str(tmp_path / "mine"))
    assert default_cache_dir() == tmp_path / "mine"
    assert "$XDG_CACHE_HOME/warpshade" in README


# ---- (h) the SHEXP-over-RPO graph: the ground blocks as a disc, and the report says what the error is
def test_figure_rpo_shexp_blocks_with_the_ground_and_says_where_its_error_is():
    """The reviewer's reading of the 0.35 error (light from below the ground) is not what happens:
    the static ground plane is a disc blocker of the graph's blocker model, above every figure
    vertex, and the description (the run report's) names the cause that remains."""
    from warpshade.methods.shexp._model import plane_blockers

    spec = load(ROOT / "stages" / "figure_rpo_shexp.toml")
    blockers = next(st for st in spec.stages if st.type == "shexp.blockers")
    assert blockers.params.get("planes", True)
    scene = spec.load_scene()
    planes = plane_blockers(scene)
    assert planes.shape == (1, 7)
    centre, normal, radius = planes[0, :3], planes[0, 3:6], planes[0, 6]
    figure = next(m for m in scene.meshes if m.path != "/World/Ground")
    pts = scene.points_at(float(scene.frames[30]))[figure.vertex_offset : figure.vertex_offset + figure.vertex_count]
    assert abs(normal[2]) > 0.999 and radius > 2.0
    assert np.all((pts - centre) @ normal > -1e-3)  # the figure stands on the disc
    assert "self-shadowing" in spec.description and "traced visibility" in spec.description
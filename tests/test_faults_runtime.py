"""Run-time changes under bad input (issue 23, families 3 and 4, and the late errors of 5).

Every ``set_*`` is all or nothing: a rejected change raises an error naming what is at fault and
leaves the run exactly as it was -- the next frames equal a fresh runtime's, and the next valid
change is applied. Open-ended values (exponents, albedos, roughness) are drawn by hypothesis:
each is either refused with an error naming the parameter, or shades a finite, non-black result.
"""

import warnings

import numpy as np
import pytest
from grids import ground_grid
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from warpshade.tasks import executor
from warpshade.graph import GraphError, GraphSpec, StageError, StageSpec
from warpshade.scene import Environment, LightingSource, Mesh, Scene, SphereLight
from warpshade.scene import _materials as M
from warpshade.scene._brdfs import brdf_from_spec, make_brdf
from warpshade.scene._tabulated import read_merl, write_merl

#: Few examples each: every one compiles or steps a tiny graph on the CPU.
FEW = settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
#: A recorded frame after a rejected change against a fresh runtime's: the same kernels on the
#: same buffers, so the same floats up to summation order of chunked launches.
ATOL_SAME_FRAME = 1e-6
EYE = [0.4, -0.6, 3.0]
SKY = LightingSource.fixed([Environment.sky(height=8, width=16)], "Z")


@pytest.fixture(scope="module")
def sheets():
    """A 5 x 5 curved sheet (25 vertices) under a small plate (4 vertices), three frames."""
    pts, faces = ground_grid(np.linspace(-1.0, 1.0, 5))
    pts[:, 2] = 0.1 * pts[:, 0] ** 2
    plate = np.array([[-0.3, -0.3, 0.5], [0.3, -0.3, 0.6], [0.3, 0.3, 0.6], [-0.3, 0.3, 0.5]])
    return Scene.from_meshes([Mesh("/sheet", pts, faces), Mesh("/plate", plate, np.array([[0, 1, 2], [0, 2, 3]]))],
                             frames=np.arange(3.0))


def _rpo(shade=None, vis=None, materials=()):
    return GraphSpec(stages=[
        StageSpec("vis", "rpo.visibility_traced", {"order": 3, "samples": 16, **(vis or {})}),
        StageSpec("shade", "rpo.shade", {"order": 3, "rank": 4, "view_order": 4, "eye": EYE, "materials": 1,
                                         **(shade or {})}),
    ], output="shade.radiance", materials=list(materials), name="rpo-faults")


def _compile(spec, scene, **kw):
    return spec.compile(scene, device="cpu", cache_dir=None, progress=False, lighting=kw.pop("lighting", SKY), **kw)


def _same_as_fresh(rt, fresh, frames=(0.0, 1.0, 2.0)):
    """Step both over ``frames`` twice (direct, then recorded) and compare every frame."""
    for _ in range(2):
        for f in frames:
            got = rt.step(f).numpy().copy()
            want = fresh.step(f).numpy()
            assert np.all(np.isfinite(got))
            np.testing.assert_allclose(got, want, atol=ATOL_SAME_FRAME)


@pytest.fixture(scope="module")
def rpo_runs(sheets):
    """One runtime to abuse, and fresh ones to compare with (ggx, phong 6)."""
    return {"rt": _compile(_rpo(), sheets), "ggx": _compile(_rpo(), sheets),
            "phong": _compile(_rpo({"brdf": "phong", "exponent": 6.0}), sheets)}


# ---- family 3: a rejected change changes nothing --------------------------------------------

def test_rejected_material_and_parameter_leave_the_run_as_it_was(rpo_runs):
    rt = rpo_runs["rt"]
    for f in (0.0, 1.0, 0.0):
        rt.step(f)  # recorded
    before = rt.state.materials.saved()
    with pytest.raises(StageError, match="material slots"):
        rt.set_material(M.Phong(6.0), prims=["/plate"])  # two BRDFs, one slot
    assert rt.state.materials.saved() == before
    with pytest.raises(StageError, match="rank"):
        rt.set_parameter("shade", "rank", 100)
    assert rt.stages[1].params["rank"] == 4
    _same_as_fresh(rt, rpo_runs["ggx"])
    rt.set_material(M.Phong(6.0))  # the next valid change applies, with no stale error
    _same_as_fresh(rt, rpo_runs["phong"])
    rt.set_material(None)
    _same_as_fresh(rt, rpo_runs["ggx"])


def test_rejected_lighting_eye_and_albedo_change_nothing(rpo_runs):
    rt = rpo_runs["rt"]
    with pytest.raises(StageError, match="sphere light"):
        rt.set_lighting([SphereLight([0.0, 0.0, 2.0], 0.1, [1.0, 1.0, 1.0])])
    assert rt.lighting is rt.ctx.lighting
    with pytest.raises(ValueError, match="eye"):
        rt.set_eye([0.0, np.nan, 1.0])
    with pytest.raises(ValueError, match="albedo"):
        rt.set_albedo([1.0, 2.0])
    _same_as_fresh(rt, rpo_runs["ggx"])


def test_a_failing_set_up_drops_the_recording(rpo_runs):
    """A set-up that fails part way must not leave a recording of buffers the stage replaced."""
    rt = rpo_runs["rt"]
    rt.step(0.0)
    rt.step(0.0)
    with pytest.raises(StageError):
        rt.set_parameter("shade", "rank", 10)  # > 9 coefficients: refused in set-up
    _same_as_fresh(rt, rpo_runs["ggx"], frames=(0.0, 2.0))
    rt.set_parameter("shade", "brdf", "phong")
    rt.set_parameter("shade", "exponent", 6.0)
    _same_as_fresh(rt, rpo_runs["phong"], frames=(0.0, 2.0))
    rt.set_parameter("shade", "brdf", "ggx")


@FEW
@given(exponent=st.one_of(st.floats(0.0, 1e300), st.sampled_from([1e300, 1e5, 5e3, 1.0])))
def test_run_time_phong_exponents_are_refused_or_shade_light(rpo_runs, exponent):
    rt = rpo_runs["rt"]
    try:
        rt.set_material(M.Phong(exponent))
    except StageError as exc:
        assert "exponent" in str(exc) and "sharper" in str(exc)
        _same_as_fresh(rt, rpo_runs["ggx"], frames=(1.0,))
        return
    out = rt.step(1.0).numpy()
    assert np.all(np.isfinite(out)) and out.max() > 0.05  # not black
    rt.set_material(None)
    _same_as_fresh(rt, rpo_runs["ggx"], frames=(1.0,))


def test_material_track_frame_refused_names_the_track_and_frame(sheets):
    track = [{"frames": "1:2", "prims": ["/plate"], "brdf": M.Phong(6.0), "where": "g.toml [[material]] #1"}]
    rt = _compile(_rpo(materials=track), sheets)
    fresh = _compile(_rpo(), sheets)
    np.testing.assert_allclose(rt.step(0.0).numpy(), fresh.step(0.0).numpy(), atol=ATOL_SAME_FRAME)
    with pytest.raises(GraphError, match=r"\[\[material\]\] #1 at frame 1.*material slots"):
        rt.step(1.0)
    _same_as_fresh(rt, fresh, frames=(0.0, 2.0))


def test_material_changes_on_a_graph_without_material_stage_are_refused(sheets):
    prt = [StageSpec("bake", "prt.transfer", {"order": 2, "samples": 16}), StageSpec("shade", "prt.shade", {"order": 2})]
    track = [{"frames": None, "prims": None, "brdf": M.Phong(6.0), "where": "g.toml [[material]] #1"}]
    with pytest.raises(GraphError, match=r"\[\[material\]\] #1.*rpo.shade"):
        _compile(GraphSpec(prt, "shade.radiance", materials=track), sheets)
    rt = _compile(GraphSpec(prt, "shade.radiance"), sheets)
    with pytest.raises(GraphError, match="set_material.*ignored"):
        rt.set_material(M.Phong(6.0))


# ---- family 4: silently wrong values are refused -----------------------------------------------

@FEW
@given(key=st.sampled_from(["specular", "albedo"]), value=st.one_of(st.floats(max_value=-1e-9), st.just(np.inf)))
def test_negative_or_infinite_brdf_values_are_refused_naming_them(key, value):
    kind = "lambert" if key == "albedo" else "ggx"
    with pytest.raises(ValueError, match=f"g.toml \\[\\[material\\]\\] #2: .*{key}"):
        brdf_from_spec({"brdf": kind, key: value}, where="g.toml [[material]] #2")


@FEW
@given(exponent=st.floats(0.0, 1e300), kind=st.sampled_from(["phong", "blinn-phong"]))
def test_operator_tables_refuse_lobes_their_quadrature_misses(exponent, kind):
    brdf = make_brdf(kind, exponent=exponent)
    views = np.array([[0.0, 0.0, 1.0]])
    try:
        table = M.brdf_matrix(brdf, 2, views, 32, 64)
    except ValueError as exc:
        assert "exponent" in str(exc) and "sharper" in str(exc)
        return
    albedo = table[0, 0] / M.sh.basis(views, 1)[0, 0]  # directional albedo at normal view (analytic: 1)
    assert 0.3 < albedo < 1.2


def test_values_a_brdf_does_not_use_are_refused(tmp_path, sheets):
    with pytest.raises(ValueError, match=r"'ggx' does not use \['file'\]"):
        brdf_from_spec({"brdf": "ggx", "file": "gold.binary"}, where="[[material]] #1")
    with pytest.raises(ValueError, match=r"does not use \['exponent'\]"):
        make_brdf("lambert", exponent=3.0)
    with pytest.raises(StageError, match="'shade'.*file"):
        _compile(_rpo({"file": "gold.binary"}), sheets)


def test_albedo_prims_are_checked_up_front(rpo_runs):
    rt = rpo_runs["rt"]
    before = rt.evaluator.albedo.numpy().copy()
    with pytest.raises(ValueError, match="non-empty"):
        rt.set_albedo([0.5, 0.5, 0.5], prims=[])
    with pytest.raises(ValueError, match=r"no mesh prim \['/World/X'\]"):
        rt.set_albedo([0.5, 0.5, 0.5], prims="/World/X")  # one path, not its characters
    with pytest.raises(ValueError, match=r"\(3,\) or one per vertex \(4, 3\), got shape \(2,\)"):
        rt.set_albedo([1, 2], prims="/plate")
    with pytest.raises(ValueError, match="non-negative"):
        rt.set_albedo([-0.5, 0.5, 0.5])
    np.testing.assert_array_equal(rt.evaluator.albedo.numpy(), before)
    rt.set_albedo([0.1, 0.2, 0.3], prims="/plate")
    np.testing.assert_allclose(rt.evaluator.albedo.numpy()[25:], [[0.1, 0.2, 0.3]] * 4, rtol=1e-6)
    rt.evaluator.albedo.assign(before)


def test_visibility_in_the_wrong_frame_is_refused(sheets):
    with pytest.raises(GraphError, match="'shade' input 'visibility' expects world.*'vis' output 'visibility'.*local"):
        _compile(_rpo({"visibility_space": "world"}), sheets)


def test_local_scheduler_is_capped_at_the_cores():
    with pytest.warns(RuntimeWarning, match="local:99999.*99999 worker processes"):
        ex = executor("local:99999")
    assert ex.workers < 99999
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert executor("local:1").workers == 1


# ---- family 5: NaN named where it appears ------------------------------------------------------

def test_huge_merl_values_are_refused_naming_the_file(tmp_path):
    path = tmp_path / "huge.binary"
    write_merl(path, M.Microfacet(0.5), dims=(4, 4, 8))
    raw = bytearray(path.read_bytes())
    raw[12 + 8 * 3: 12 + 8 * 4] = np.array([1e300]).tobytes()
    path.write_bytes(bytes(raw))
    with pytest.raises(ValueError, match="huge.binary.*beyond"):
        read_merl(path)


def test_non_finite_frames_name_the_stage_and_frame(sheets):
    rt = _compile(_rpo(), sheets, capture=False)
    vis = rt.frame_stages[0]
    launch = vis.launch

    def poisoned(state):
        launch(state)
        if state.frame == 1.0:
            v = rt.frame_outputs["vis"]["visibility"]
            host = v.numpy()
            host[3, 0] = np.nan
            v.assign(host)

    vis.launch = poisoned
    rt.step(0.0, record=True)
    with pytest.raises(GraphError, match=r"frame 1: stage 'vis' \(rpo.visibility_traced\) output 'visibility'.*row 3"):
        rt.step(1.0, record=True)
    assert sorted(rt.results) == [0.0]


def test_a_black_frame_is_not_silent(sheets):
    """An eye below every vertex's horizon shades the whole frame black: a recorded step warns,
    naming the frame, the output and the cause; a lit frame again re-arms the warning."""
    rt = _compile(_rpo(), sheets)
    rt.step(0.0, record=True)
    rt.set_parameter("shade", "eye", (0.0, 0.0, -3.0))  # under the sheet and the plate: every view below the horizon
    with pytest.warns(UserWarning, match=r"frame 1: the output 'shade.radiance' is black at every vertex: 29 of 29 "
                                         r"vertices see the eye at or below their horizon"):
        rt.step(1.0, record=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rt.step(2.0, record=True)  # still black: said once
        rt.set_parameter("shade", "eye", tuple(EYE))
        rt.step(2.0, record=True)
    assert rt.results[2.0].max() > 0.0


# ---- SG roughness through set_parameter ---------------------------------------------------------

@pytest.fixture(scope="module")
def sg_runs(tmp_path_factory):
    pts, faces = ground_grid(np.linspace(-1.0, 1.0, 4))
    scene = Scene.from_meshes([Mesh("/ground", pts, faces)], frames=np.arange(2.0))
    spec = GraphSpec(stages=[StageSpec("ssdf", "sg.ssdf", {"resolution": 4, "supersample": 1}),
                             StageSpec("environment", "sg.environment", {"lobes": 2}),
                             StageSpec("tangents", "ldprt.tangents"),
                             StageSpec("shade", "sg.shade", {"eye": (0.5, -1.5, 2.0), "component": "both"})],
                     output="shade.radiance", name="sg-faults")
    cache = tmp_path_factory.mktemp("cache")
    run = lambda: spec.compile(scene, device="cpu", cache_dir=cache, progress=False, lighting=SKY)  # noqa: E731
    return {"rt": run(), "fresh": run()}


@FEW
@given(model=st.sampled_from(["beckmann", "cook-torrance", "ward", "blinn-phong"]),
       roughness=st.one_of(st.floats(1e-3, 1e30), st.just(1e30)))
def test_sg_roughness_is_bounded_or_refused(sg_runs, model, roughness):
    rt = sg_runs["rt"]
    try:
        rt.set_parameter("shade", "brdf", model)
        rt.set_parameter("shade", "roughness", roughness)
    except StageError as exc:
        assert "roughness" in str(exc)
    else:
        assert np.all(np.isfinite(rt.step(1.0).numpy()))
    rt.set_parameter("shade", "roughness", 1.0)  # valid for every model
    rt.set_parameter("shade", "brdf", "beckmann")
    rt.set_parameter("shade", "roughness", 0.3)
    _same_as_fresh(rt, sg_runs["fresh"], frames=(1.0,))

"""The newest features under bad input (issue 39): late refusals, too little data, ignored parameters.

A problem that needs only the parameters and the graph's wiring is refused when the graph is
checked (:meth:`GraphSpec.check`, before any scene is loaded) or, where it needs the scene's frames,
by ``GraphSpec.compile`` before any precompute: never after minutes of tracing training data, fitting
a model or baking a transfer. Every graph here has the precompute and set-up of its stage types
replaced by a sentinel that fails the test when reached, so a refusal that comes late fails it.
The messages name the stage and the parameter (or input) at fault.
"""

import numpy as np
import pytest

from warpshade.graph import GraphError, GraphSpec, StageError, StageSpec, get_stage_type
from warpshade.io import load_scene
from warpshade.methods.hybrid import glossy_stages_for
from warpshade.methods.hybrid import stages_for as hybrid_stages_for
from warpshade.methods.visibility import fit_cluster, fit_visibility
from warpshade.methods.visibility._rows import stages_for as visibility_stages_for
from warpshade.methods.visibility._select import fewest_frames
from warpshade.methods.visibility._stack import fit_stack

#: Training frames of the bend the small visibility graphs select (15 of its 60: enough for the fit).
TRAINING_FRAMES = "0:60:4"
#: A selection too short for the fit's cross-validation (3 frames, fewer than fewest_frames()).
FEW_FRAMES = "0:12:4"


class WorkStarted(Exception):
    """A precompute or set-up was reached: the refusal under test came too late."""


@pytest.fixture(scope="module")
def bend():
    return load_scene("bundled:bend")


@pytest.fixture
def no_work(monkeypatch):
    """Replace every stage type's precompute and set-up by a sentinel (returns the graph builder)."""

    def guard(spec: GraphSpec) -> GraphSpec:
        for st in spec.stages:
            cls = get_stage_type(st.type, st.name)
            for method in ("precompute", "setup"):
                if hasattr(cls, method):
                    monkeypatch.setattr(cls, method, _sentinel(st.type, method))
        return spec

    return guard


def _sentinel(type_name, method):
    def run(self, *args, **kwargs):
        raise WorkStarted(f"{type_name}.{method} ran before the refusal")

    return run


def _graph(stages, output="shade.radiance", name="refusal"):
    return GraphSpec([StageSpec(n, t, dict(p), dict(i)) for n, t, p, i in stages], output, name=name)


def _visibility_graph(regressor="linear", fit=None, data=None, predict=None, order=3, frames=TRAINING_FRAMES):
    """visibility.data -> visibility.fit -> visibility.predict -> rpo.shade on the bend's own clip."""
    stages = [list(s) for s in visibility_stages_for("", frames, regressor, order=order, samples=16,
                                                     fit={"hidden": (4,), "max_iterations": 10, **(fit or {})})]
    stages[0][2] = {**stages[0][2], **(data or {})}
    stages[2][2] = {**stages[2][2], **(predict or {})}
    stages[-1] = ["shade", "rpo.shade", {"order": stages[2][2]["order"], "rank": 4, "brdf": "ggx", "roughness": 0.5}, {}]
    return _graph(stages, name="visibility-refusal")


def _refused_before_work(spec, bend, match, at_check=True):
    """``spec`` is refused with an error matching ``match``: by ``check()`` (``at_check``) and by
    ``compile`` before any precompute or set-up."""
    if at_check:
        with pytest.raises(GraphError, match=match):
            spec.check()
    with pytest.raises(StageError, match=match):
        spec.compile(bend, device="cpu", cache_dir=None, progress=False, scheduler="serial")


# ---- 1. late refusals: parameter-only problems found after minutes of work ------------------------------
@pytest.mark.parametrize("model", ["network", "linear", "quadratic"])
def test_relative_inputs_with_a_model_that_cannot_take_them_are_refused_at_check(bend, no_work, model):
    spec = no_work(_visibility_graph(model, fit={"relative": 4}))
    _refused_before_work(spec, bend, r"stage 'fit' \(visibility.fit\): parameter 'relative' = 4 applies to "
                                     rf"regressor = 'auto' or 'stack' only.*'{model}'")


@pytest.mark.parametrize("hidden", [[], [0.0], [2.5], [4.0, -1.0]])
def test_hidden_without_positive_whole_counts_is_refused_at_check(bend, no_work, hidden):
    spec = no_work(_visibility_graph("network", fit={"hidden": hidden}))
    _refused_before_work(spec, bend, r"stage 'fit' \(visibility.fit\): parameter 'hidden' needs positive whole")


def test_diffuse_metric_in_the_world_frame_is_refused_at_check(bend, no_work):
    spec = no_work(_visibility_graph("auto", fit={"metric": "diffuse", "space": "world"}))
    _refused_before_work(spec, bend, r"stage 'fit' \(visibility.fit\): parameter 'metric' = 'diffuse' applies to "
                                     "local frames only")


def test_world_frame_fit_wired_into_predict_is_refused_at_check(bend, no_work):
    spec = no_work(_visibility_graph(fit={"space": "world"}))
    _refused_before_work(spec, bend, r"stage 'predict' \(visibility.predict\): input 'model' is fed by stage 'fit' "
                                     r"\(visibility.fit\) with parameter 'space' = 'world'")


@pytest.mark.parametrize("predict_first", [False, True])
def test_training_order_unlike_the_predict_order_is_refused_at_check(bend, no_work, predict_first):
    """Data traced at order 3, predicted at order 4 (the shading at 4): refused at check, whichever of
    the fit and the predict stage the graph lists first."""
    spec = _visibility_graph(order=4, data={"order": 3})
    if predict_first:
        stages = list(spec.stages)
        spec = GraphSpec([stages[0], stages[2], stages[1], *stages[3:]], spec.output, name=spec.name)
    spec = no_work(spec)
    _refused_before_work(spec, bend, r"stage 'predict' \(visibility.predict\): parameter 'order' = 4, but the model "
                                     r"of stage 'fit' is trained on visibility of order 3")


def test_matching_orders_and_local_frames_pass_the_check(no_work):
    """The checks above refuse only what cannot run: the same graph with consistent parameters passes."""
    for spec in (_visibility_graph(), _visibility_graph("auto", fit={"relative": 4, "metric": "diffuse"}),
                 _visibility_graph("stack", fit={"relative": 2, "space": "one_ring"}), _visibility_graph(order=4)):
        no_work(spec).check()


@pytest.mark.parametrize("graph", ["ldprt", "glossy"])
def test_reproject_in_the_tangent_frames_is_refused_at_check(bend, no_work, graph):
    """hybrid.trace with space = 'local' and reproject: refused at check, not after the control's
    bake (ldprt.transfer, rpo.visibility_static)."""
    trace = {"reproject": True, "filter_iterations": 0}
    stages = (hybrid_stages_for("ldprt", 4, order=3, bake_samples=16, trace=trace) if graph == "ldprt" else
              glossy_stages_for(4, order=3, bake_samples=16, trace=trace))
    spec = no_work(_graph(stages, name="hybrid-refusal"))
    _refused_before_work(spec, bend, r"stage 'trace' \(hybrid.trace\): parameter 'reproject' applies to the world "
                                     r"frame \(space = 'world'\)")


@pytest.mark.parametrize("params, match", [
    ({"order": 3, "space": "world", "visibility_order": 4}, r"parameter 'visibility_order' = 4 is above 'order' = 3"),
    ({"order": 4, "space": "local", "visibility_order": 3}, r"parameter 'visibility_order' applies to space = 'world'"),
])
def test_visibility_transfer_orders_are_refused_at_check(bend, no_work, params, match):
    """hybrid.visibility_transfer's visibility order: refused at check, not after the control's fit."""
    stages = [list(s) for s in hybrid_stages_for("visibility", 4, order=4, training="", frames=TRAINING_FRAMES,
                                                 training_samples=16)]
    model = next(s for s in stages if s[0] == "model")
    model[2] = params
    if params["space"] == "world":
        model[3] = {"visibility": "predict.visibility"}
    spec = no_work(_graph(stages, name="hybrid-visibility-refusal"))
    _refused_before_work(spec, bend, r"stage 'model' \(hybrid.visibility_transfer\): " + match)


def test_data_that_is_not_visibility_training_data_is_refused_at_check(bend, no_work):
    """datadriven.data's transfer wired into visibility.fit: refused at check, not with a KeyError
    after the training transfer is traced."""
    stages = [list(s) for s in visibility_stages_for("", TRAINING_FRAMES, "linear", order=3, samples=16)]
    stages[0][1] = "datadriven.data"
    stages[0][2] = {"order": 3, "samples": 16, "frames": TRAINING_FRAMES}
    stages[-1] = ["shade", "rpo.shade", {"order": 3, "rank": 4, "brdf": "ggx", "roughness": 0.5}, {}]
    spec = no_work(_graph(stages))
    _refused_before_work(spec, bend, r"stage 'fit' \(visibility.fit\): input 'data' is fed by stage 'data' "
                                     r"\(datadriven.data\)'s 'data', which is not visibility training data")


# ---- 2. too little data: refused before training, never NaN -------------------------------------------------
@pytest.mark.parametrize("model, features", [("stack", "joints"), ("network", "joints"), ("linear", "joints"),
                                             ("quadratic", "joints"), ("auto", "dihedral")])
def test_too_few_training_frames_are_refused_before_tracing(bend, no_work, model, features):
    """Every model (and the cloth's dihedral inputs) goes through visibility.data's selection, refused
    by compile before any precompute when the clip is the graph's own scene."""
    spec = no_work(_visibility_graph(model, data={"features": features}, frames=FEW_FRAMES))
    spec.check()  # the frame count needs the scene
    _refused_before_work(spec, bend, rf"stage 'data' \(visibility.data\): parameter 'frames' selects 3 frame\(s\); "
                                     rf"the model needs at least {fewest_frames()}", at_check=False)


def test_too_few_frames_of_another_clip_are_refused_before_tracing(bend, monkeypatch):
    """A training clip other than the graph's scene: refused when the clip is read, before its tracing."""
    from warpshade.methods.visibility import _stages as visibility_stages

    monkeypatch.setattr(visibility_stages, "trace_training", _sentinel("visibility.data", "trace_training"))
    spec = _visibility_graph(data={"training": "bundled:bend"}, frames=FEW_FRAMES)
    with pytest.raises(StageError, match=r"stage 'data' \(visibility.data\): parameter 'frames' selects 3"):
        spec.compile(bend, device="cpu", cache_dir=None, progress=False, scheduler="serial")


def test_cached_training_data_with_too_few_frames_is_not_reused():
    """An artifact left with fewer frames than the fit needs is invalid: the runtime traces again
    (and the selection is refused then)."""
    stage = get_stage_type("visibility.data")("data", {})
    p, v, c = fewest_frames() - 1, 6, 9
    data = {"visibility": np.ones((p, v, c), np.float32), "points": np.zeros((p, v, 3), np.float32),
            "normals": np.zeros((p, v, 3), np.float32), "dihedral": np.zeros((p, 4)),
            "settings": np.array([3, 16, 0, 1])}
    with pytest.raises(ValueError, match=rf"visibility.data: {p} training frame\(s\), fewer than the fit needs"):
        stage.check_artifact({"data": data})


@pytest.mark.parametrize("model", ["linear", "quadratic", "network", "auto", "stack"])
def test_fit_of_too_few_frames_is_a_clear_error(model):
    """Training data made some other way (not by visibility.data) with too few frames: every model
    is refused before its first cluster, naming the frame count and the parameter to change."""
    p = fewest_frames() - 1
    data = {"visibility": np.ones((p, 5, 9), np.float32), "settings": np.array([3, 16, 0, 1])}
    with pytest.raises(ValueError, match=rf"training data holds {p} frame\(s\); the fit needs at least "
                                         rf"{fewest_frames()}.*visibility.data parameter 'frames'"):
        fit_visibility(data, regressor=model)


@pytest.mark.parametrize("count", [1, 2, 3])
@pytest.mark.parametrize("model", ["linear", "quadratic", "network"])
def test_cluster_fit_of_too_few_frames_is_a_clear_error(rng, model, count):
    """A cluster task on too few frames (its contiguous folds would train on one frame or none: a
    mean of nothing is NaN) is refused, naming the shortfall."""
    x, y = rng.normal(size=(count, 2)), rng.normal(size=(count, 12))
    task = {"x": x, "y": y, "model": model, "variance": 0.999, "predictable": 1.0, "k_max": 8, "hidden": (2,),
            "max_iterations": 5, "seed": 0, "cluster": 0, "vertices": 4}
    if count == 1:  # one frame: nothing varies, the cluster is its mean (no fit, no NaN)
        out = fit_cluster(task)
        assert out["report"]["model_used"] == "constant" and np.all(np.isfinite(out["mean"]))
        return
    with pytest.raises(ValueError, match=r"cross-validation of \d training frame\(s\): a fold trains on [01] frame"):
        fit_cluster(task)


@pytest.mark.parametrize("count", [4, 5, 7])
def test_stack_of_too_few_frames_is_a_clear_error(rng, count):
    """fit_stack's blocked folds on fewer than fewest_frames() frames: refused, not 'no candidate
    inputs' (every candidate's validation error NaN) nor folds that train on one frame."""
    x, y = rng.normal(size=(count, 3)), rng.normal(size=(count, 2))
    with pytest.raises(ValueError, match=rf"blocked cross-validation of {count} training frame\(s\).*at least "
                                         rf"{fewest_frames()} training frames"):
        fit_stack({"global": (x, ("linear",))}, y)


# ---- 3. ignored parameters ----------------------------------------------------------------------------------
def _trace_graph(**trace):
    return _graph([("trace", "hybrid.trace", {"order": 3, "samples": 4, "control": "previous", **trace}, {}),
                   ("shade", "prt.shade", {"order": 3}, {"transfer": "trace.transfer"})], name="trace-refusal")


@pytest.mark.parametrize("given", [{"warmup_passes": 3}, {"warmup_noise": 0.1}, {"warmup_limit": "none"},
                                   {"warmup_passes": 2},  # the default, given: refused all the same
                                   {"warmup_passes": 3, "warmup_noise": 0.5, "warmup_frames": 0.0}])
def test_warmup_parameters_without_warmup_frames_are_refused_at_check(bend, no_work, given):
    spec = no_work(_trace_graph(**given))
    named = "'" + "', '".join(k for k in ("warmup_passes", "warmup_limit", "warmup_noise") if k in given) + "'"
    _refused_before_work(spec, bend, r"stage 'trace' \(hybrid.trace\): parameter\(s\) " + named +
                         r" only apply to the history-aware filter, which is off with warmup_frames = 0")


def test_warmup_parameters_with_warmup_frames_pass_the_check(no_work):
    for trace in ({}, {"warmup_frames": 6.0}, {"warmup_frames": 6.0, "warmup_passes": 3, "warmup_noise": 0.5,
                                              "warmup_limit": "none"}):
        no_work(_trace_graph(**trace)).check()

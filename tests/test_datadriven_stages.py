"""Data-driven PRT as stage graphs: training, the recorded frame, executors, bad input.

The bundled bend (a tube skinned to a 4-joint chain) trains on its even frames and is tested on
its odd ones against ray-traced transfer; the model is compared with the transfer baked at the
rest pose (what static PRT would use), which ignores the bend.
"""

import numpy as np
import pytest

from warpshade.graph import GraphError, GraphSpec, StageSpec
from warpshade.io import load_scene
from warpshade.methods.datadriven._rows import stages_for
from warpshade.methods._shared.training import trace_training
from warpshade.graph import StageError
from warpshade.transfer import compute

#: rays of the transfer the held-out frames are compared with (its own noise ~0.05 at order 3)
TRUTH_RAYS = 1024
#: the model must be at least this much closer to the truth than the rest-pose bake
MAX_ERROR_RATIO_TO_STATIC = 0.6
#: float32 pose features from float32 joint matrices, amplified by the standardisation (1/std)
RTOL_FRAME = 1e-4


@pytest.fixture(scope="module")
def bend():
    return load_scene("bundled:bend")


def _graph(reduction="reduced", data=None, fit=None, order=3, training=""):
    stages = list(stages_for(training, reduction, order=order, samples=64, fit=fit))
    stages[0] = ("data", "datadriven.data", {"order": order, "samples": 64, "frames": "0:60:2", "training": training,
                                             **(data or {})}, {})
    return GraphSpec([StageSpec(n, t, dict(p), dict(i)) for (n, t, p, i) in stages], "shade.radiance", name="dd")


def _transfer_stage(rt):
    return next(s for s in rt.stages if s.type_name == "datadriven.transfer")


@pytest.mark.parametrize("model", ["reduced", "full"])
def test_held_out_frames_beat_the_rest_pose_bake(device, bend, model, tmp_path):
    rt = _graph(model).compile(bend, device=device, cache_dir=tmp_path, progress=False, scheduler="serial")
    st = _transfer_stage(rt)
    static = compute(bend, 0.0, 3, TRUTH_RAYS, device=device, seed=5).transfer
    for frame in (15.0, 45.0):
        rt.step(frame)
        got = st._transfer.numpy()
        truth = compute(bend, frame, 3, TRUTH_RAYS, device=device, seed=5).transfer
        err = np.linalg.norm(got - truth) / np.linalg.norm(truth)
        err_static = np.linalg.norm(static - truth) / np.linalg.norm(truth)
        assert err < MAX_ERROR_RATIO_TO_STATIC * err_static, (frame, err, err_static)
        # the kernels are the float64 model at the frame's pose
        from warpshade.methods.datadriven import pose_features

        pose = pose_features(bend, [bend.frame_index(frame)], st.layout, st.meta["root_reference"])
        want = st.model.predict(pose)[0]
        np.testing.assert_allclose(got, want, atol=RTOL_FRAME * np.abs(want).max())
    report = rt.stages[1].report
    assert report["kind"] == model and report["stored_floats"] > 0
    # the model the frame loop keeps is counted, not the training data only the fit reads
    assert rt.model_bytes() == 4 * report["stored_floats"]
    if model == "reduced":
        assert "PCA(" in report["choice"]["reason"] and report["choice"]["met"]
    out = rt.output.numpy()
    assert np.all(np.isfinite(out)) and out.min() >= 0.0


def test_recorded_frame_replays_the_unrecorded_one(device, bend, tmp_path):
    recorded = _graph().compile(bend, device=device, cache_dir=tmp_path, progress=False, scheduler="serial")
    plain = _graph().compile(bend, device=device, cache_dir=tmp_path, progress=False, capture=False, scheduler="serial")
    assert plain.timings["data"].cache == "hit", "the second graph reuses the cached training data"
    for frame in (3.0, 27.0, 3.0):
        recorded.step(frame)
        plain.step(frame)
        np.testing.assert_array_equal(recorded.output.numpy(), plain.output.numpy())


def test_process_workers_give_the_serial_training_data(bend):
    frames = np.array([1, 9, 17, 25, 33])
    serial = trace_training(bend, frames, 2, 32, seed=3, executor=_serial())
    from warpshade.tasks import executor

    with executor("local:2") as ex:
        local = trace_training(bend, frames, 2, 32, seed=3, executor=ex)
    np.testing.assert_array_equal(serial, local)
    again = trace_training(bend, frames[:2], 2, 32, seed=4, executor=_serial())
    assert not np.array_equal(again, serial[:2]), "the seed changes the rays"


def _serial():
    from warpshade.tasks import SerialExecutor

    return SerialExecutor()


def test_out_of_range_poses_are_reported_not_hidden(device, bend, tmp_path):
    """Trained on the first third of the bend cycle only: the middle of the cycle (frames
    28-41) holds novel poses; the novelty score says so, the error grows with it, and the output
    stays finite."""
    rt = _graph(data={"frames": "0:20"}, fit={"validation": 0.0, "ka": 2, "kv": 16}).compile(
        bend, device=device, cache_dir=tmp_path, progress=False, scheduler="serial")
    st = _transfer_stage(rt)
    nov = st.novelty()
    inside = nov["nearest"][:20]
    outside = nov["nearest"][28:42]
    assert inside.max() < 0.2 and outside.min() > 2 * inside.max()
    errors = []
    for frame in (10.0, 35.0):
        rt.step(frame)
        got = st._transfer.numpy()
        assert np.all(np.isfinite(got))
        truth = compute(bend, frame, 3, TRUTH_RAYS, device=device, seed=5).transfer
        errors.append(np.linalg.norm(got - truth) / np.linalg.norm(truth))
    assert errors[1] > errors[0]
    assert st.diagnostics()["novelty_max"] == pytest.approx(nov["nearest"].max())


def test_bad_training_input_names_the_stage(device, bend, tmp_path):
    with pytest.raises(StageError, match=r"stage 'data' \(datadriven.data\): parameter 'training': no such file"):
        _graph(training=str(tmp_path / "missing.usda")).compile(bend, device=device, cache_dir=None, progress=False)
    with pytest.raises((StageError, GraphError), match="training scene .*figure.usda has .* vertices.*bend.usda"):
        _graph(training="bundled:figure").compile(bend, device=device, cache_dir=None, progress=False)
    with pytest.raises(StageError, match="frames '5:5' select none"):
        _graph(data={"frames": "5:5"}).compile(bend, device=device, cache_dir=None, progress=False)
    # local-frame training data would be shaded as world-frame transfer: refused, not shaded wrong
    with pytest.raises(StageError, match=r"stage 'fit' \(datadriven.fit\): .*space = 'local'"):
        _graph(data={"space": "local", "frames": "0:60:20"}).compile(bend, device=device, cache_dir=None, progress=False,
                                                                     scheduler="serial")


def test_pose_components_beyond_the_training_poses_are_refused(device, bend, tmp_path):
    """ka = 100000 was once cut silently to what the poses allow; it is refused, naming ka and the limit."""
    with pytest.raises(StageError, match=r"stage 'fit' \(datadriven.fit\): parameter 'ka' = 100000 exceeds the \d+ pose "
                                         r"components .* set ka <= \d+"):
        _graph(data={"frames": "0:60:20"}, fit={"ka": 100000}).compile(bend, device=device, cache_dir=tmp_path,
                                                                      progress=False, scheduler="serial")


def test_model_order_must_match_the_transfer_stage(device, bend, tmp_path):
    spec = _graph()
    spec.stages[2] = StageSpec("transfer", "datadriven.transfer", {"order": 4}, {"model": "fit.model"})
    spec.stages[3] = StageSpec("shade", "prt.shade", {"order": 4}, {"transfer": "transfer.transfer"})
    with pytest.raises(StageError, match="trained at order 3 .* the stage has order 4"):
        spec.compile(bend, device=device, cache_dir=tmp_path, progress=False, scheduler="serial")


def test_interreflected_training_feeds_per_channel_shading(device, bend, tmp_path):
    """bounces = 1: per-channel transfer (V, 3, C) from the model, shaded per channel, measured
    against the reference with one bounce."""
    from warpshade.methods.datadriven import pose_features
    from warpshade.methods.prt import shade_transfer_f64

    stages = [StageSpec("data", "datadriven.data", {"order": 2, "samples": 32, "frames": "0:60:6", "bounces": 1}, {}),
              StageSpec("fit", "datadriven.fit", {"reduction": "reduced", "validation": 0.0, "ka": 3, "kv": 8}, {"data": "data.data"}),
              StageSpec("transfer", "datadriven.transfer", {"order": 2, "color": True}, {"model": "fit.model"}),
              StageSpec("shade", "prt.shade", {"order": 2, "color": True, "bounces": 1}, {"transfer_rgb": "transfer.transfer_rgb"})]
    rt = GraphSpec(stages, "shade.radiance", name="dd_rgb").compile(bend, device=device, cache_dir=tmp_path, progress=False,
                                                                    scheduler="serial")
    st = _transfer_stage(rt)
    out = rt.step(21.0).numpy()
    pose = pose_features(bend, [bend.frame_index(21.0)], st.layout, st.meta["root_reference"])
    t = st.model.predict(pose)[0].reshape(bend.vertex_count, 3, 4)
    want = shade_transfer_f64(t, rt.lighting.sh(2, 21.0), bend.albedo)
    np.testing.assert_allclose(out, want, atol=RTOL_FRAME * want.max())
    assert rt.output_stage().reference_model() == {"bounces": 1}
    assert rt.stages[0].report["coefficients"] == 12

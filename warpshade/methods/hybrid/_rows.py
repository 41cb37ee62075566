"""Settings of the hybrid tracer for the speed-vs-accuracy harness (``benchmarks/run.py``)."""

from __future__ import annotations

from .._rows import HarnessRow, training_clips

__all__: list[str] = []

#: Rays per vertex per frame the harness runs.
SAMPLES = (8, 16, 32, 64)
#: Scenes the rows apply to (the animated bundled scenes).
SCENES = ("figure", "figure_walk", "wanderer", "cloth", "bend", "blockers")
#: Data-driven control: training clip (:func:`warpshade.methods._rows.training_clips`) and frames per
#: held-out scene of a skinned character (as the data-driven rows, so that the cached training data
#: is shared): every frame, every other one of the wanderer's 1000.
DATADRIVEN_SCENES = {scene: (clip, {"wanderer": "0:1000:2"}.get(scene)) for scene, clip in training_clips("joints").items()}


#: The data-driven visibility model used as control: stages/figure_visibility_diffuse.toml's fit
#: (per cluster the ridge model chosen by blocked cross-validation on the training clip, from the
#: joint rotations or the nearest clusters' centroids in the cluster's frame, PCA to 99 %), so the
#: two share the cached fit (its errors as control: benchmarks/results/HISTORY.md, hybrid rows).
VISIBILITY_FIT = {"regressor": "auto", "variance": 0.99, "k_max": 64, "relative": 8}


#: hybrid.trace settings that keep the history through a turn (reprojected; no cut by the normal's
#: turn, motion cut at 4 edge lengths per frame) and blend by the bias estimated over 4 frames (soft
#: reset, cut at z > 8).
REPROJECT_SOFT = {"reproject": True, "normal_turn": 180.0, "motion": 4.0, "reset": "soft", "threshold": 8.0,
                  "bias_frames": 4}
#: REPROJECT_SOFT for the visibility control on the figure, with the history-aware filter: vertices
#: whose history holds fewer than 24 effective frames are filtered further (2 passes), no further
#: than the least-squares weight for the bias the passes add, the noise they remove taken as 0.1 of
#: the tracked variance (the tracked one overstates the actual spread on the figure, and the limit
#: weighs all coefficients alike while the shading weighs the low bands). Measured against 0.33 and
#: without the filter: benchmarks/results/HISTORY.md, hybrid rows.
VISIBILITY_TRACE = {**REPROJECT_SOFT, "warmup_frames": 24.0, "warmup_noise": 0.1}
#: The visibility control's training clip, frames and rays per held-out scene (those of the
#: visibility graphs and harness rows, so that the traced training data is shared with them).
VISIBILITY_TRAINING = {scene: (clip, {"figure": "0:600:3", "figure_walk": "0:600:3", "wanderer": "0:1000:8"}.get(scene),
                              {"wanderer": 64}.get(scene, 128)) for scene, clip in training_clips("joints").items()}
#: The trace settings of the visibility control per scene: figure_walk and the wanderer (and any
#: other scene): REPROJECT_SOFT with 2 filter passes, less noise than one pass at about the same
#: error (benchmarks/results/HISTORY.md, hybrid rows).
VISIBILITY_TRACES = {"figure": VISIBILITY_TRACE, "figure_walk": {**REPROJECT_SOFT, "filter_iterations": 2},
                     "wanderer": {**REPROJECT_SOFT, "filter_iterations": 2}}


#: SHEXP as control: its world-frame visibility of the blocker spheres (HYB, the sphere budget of
#: stages/blockers_shexp.toml), the cosine re-applied about each normal, at the transfer's order up
#: to 6 (on the blockers order 6 leaves a residual that filters better than order 4's;
#: benchmarks/results/HISTORY.md, hybrid rows).
SHEXP_CONTROL = {"order": 6, "budget": 8, "method": "hyb"}
#: hybrid.trace settings for a control that follows the motion (SHEXP's spheres): a short history
#: (a new frame weighs at least 0.3) and 3 filter passes over mesh neighbours, since averaging over
#: frames blurs a moving shadow (any reuse raises the 1024-ray blockers' error) while the residual
#: against the spheres is smooth over the surface.
SHEXP_TRACE = {"alpha": 0.3, "filter_iterations": 3}
#: hybrid.trace settings for LDPRT's transfer as control (rotated with the surface, tangent frames):
#: its residual is the change of the self-shadowing since the bake, smooth over the surface, so 4
#: filter passes and a history blended by its estimated bias (soft reset over 4 frames) with a new
#: frame weighing at least 0.2 (on the bend below the last estimate as control with REPROJECT_SOFT,
#: at about the 1024-ray tracer's noise). The history-aware filter tops up vertices whose history
#: holds fewer than 12 effective frames (the clip's first frames, cuts, the soft reset's blends; the
#: moving average alone settles at (2 - alpha) / alpha = 9). Measurements: benchmarks/results/HISTORY.md,
#: hybrid rows.
LDPRT_TRACE = {"alpha": 0.2, "filter_iterations": 4, "reset": "soft", "threshold": 8.0, "bias_frames": 4,
               "warmup_frames": 12.0}
#: The trace settings each control's harness rows use (others: the stage's defaults).
CONTROL_TRACE = {"shexp": SHEXP_TRACE, "ldprt": LDPRT_TRACE}


def stages_for(control: str, samples: int, order: int = 6, training: str | None = None, frames: str | None = None,
               training_samples: int = 256, bake_samples: int = 256, space: str = "world", trace: dict | None = None) -> tuple:
    """The stages of a hybrid graph with a control: ``"datadriven"`` (needs ``training``),
    ``"visibility"`` (the data-driven visibility model of ``visibility.fit`` trained on
    ``training``, its prediction turned into world-frame transfer by ``hybrid.visibility_transfer``),
    ``"ldprt"`` (local transfer baked at the first frame, rotated with the surface: always in the
    tangent frames), ``"shexp"`` (SHEXP's visibility of the scene's blocker spheres, world frame,
    :data:`SHEXP_CONTROL`), ``"previous"`` or ``"none"`` (in ``space``, world or the tangent frames); the
    ray count ``samples`` is ``hybrid.trace``'s. Local-frame graphs shade with
    ``ldprt.shade_rotated``, world-frame ones with ``prt.shade``."""
    params = {"order": order, "samples": samples, **(trace or {})}
    local = control == "ldprt" or space == "local"
    if local:
        params["space"] = "local"
        pre = (("tangents", "ldprt.tangents", {}, {}),)
        wires = {"tangents": "tangents.tangents"}
        shade = ("shade", "ldprt.shade_rotated", {"order": order}, {"transfer": "trace.transfer", "tangents": "tangents.tangents"})
    else:
        pre, wires = (), {}
        if params.get("reproject"):
            pre, wires = (("tangents", "ldprt.tangents", {}, {}),), {"tangents": "tangents.tangents"}
        shade = ("shade", "prt.shade", {"order": order}, {"transfer": "trace.transfer"})
    if control in ("previous", "none"):
        return (*pre, ("trace", "hybrid.trace", {**params, "control": control}, wires), shade)
    if control == "datadriven":
        if training is None or local:
            raise ValueError("stages_for: the data-driven control needs a training clip and the world frame")
        data = {"training": training, "order": order, "samples": training_samples}
        if frames is not None:
            data["frames"] = frames
        return (("data", "datadriven.data", data, {}),
                ("fit", "datadriven.fit", {"reduction": "reduced"}, {"data": "data.data"}),
                ("model", "datadriven.transfer", {"order": order}, {"model": "fit.model"}),
                *pre, ("trace", "hybrid.trace", {**params, "control": "model"}, {"control": "model.transfer", **wires}), shade)
    if control == "visibility":
        if training is None or local:
            raise ValueError("stages_for: the visibility control needs a training clip and the world frame")
        data = {"training": training, "order": order, "samples": training_samples}
        if frames is not None:
            data["frames"] = frames
        if params.get("reproject"):  # the history turns with the visibility's own tangent frames
            wires = {"tangents": "predict.tangents"}
        return (("data", "visibility.data", data, {}),
                ("fit", "visibility.fit", dict(VISIBILITY_FIT), {"data": "data.data"}),
                ("predict", "visibility.predict", {"order": order}, {"model": "fit.model"}),
                ("model", "hybrid.visibility_transfer", {"order": order},
                 {"visibility": "predict.visibility", "tangents": "predict.tangents"}),
                ("trace", "hybrid.trace", {**params, "control": "model"}, {"control": "model.transfer", **wires}), shade)
    if control == "shexp":
        if local:
            raise ValueError("stages_for: the SHEXP control is a world-frame visibility (use the world frame)")
        so = min(order, SHEXP_CONTROL["order"])
        return (("tables", "shexp.tables", {"order": so}, {}),
                ("blockers", "shexp.blockers", {"budget": SHEXP_CONTROL["budget"]}, {}),
                ("spheres", "shexp.visibility", {"order": so, "method": SHEXP_CONTROL["method"]}, {}),
                ("model", "hybrid.visibility_transfer", {"order": order, "space": "world", "visibility_order": so},
                 {"visibility": "spheres.visibility"}),
                *pre, ("trace", "hybrid.trace", {**params, "control": "model"}, {"control": "model.transfer", **wires}), shade)
    if control == "ldprt":
        return (("bake", "ldprt.transfer", {"order": order, "samples": bake_samples}, {}), *pre,
                ("trace", "hybrid.trace", {**params, "control": "model"}, {"control": "bake.transfer", **wires}), shade)
    raise ValueError(f"stages_for: unknown control {control!r}")


def glossy_stages_for(samples: int, order: int = 4, control: str = "static", bake_samples: int = 256,
                      shade: dict | None = None, trace: dict | None = None) -> tuple:
    """The SH visibility (open below the horizon, tangent frames) from ``samples`` rays per vertex
    and frame with ``rpo.visibility_static`` (``control = "static"``), the last estimate
    (``"previous"``) or nothing (``"none"``) as control, shaded by ``rpo.shade`` (glossy)."""
    params = {"order": order, "samples": samples, "quantity": "visibility", "space": "local", **(trace or {})}
    wires = {"tangents": "tangents.tangents"}
    pre = [("tangents", "ldprt.tangents", {}, {})]
    if control == "static":
        pre.append(("static", "rpo.visibility_static", {"order": order, "samples": bake_samples}, {}))
        params["control"], wires["control"] = "model", "static.visibility"
    elif control in ("previous", "none"):
        params["control"] = control
    else:
        raise ValueError(f"glossy_stages_for: unknown control {control!r}")
    shade_params = {"order": order, "rank": 8, "brdf": "ggx", "roughness": 0.5, **(shade or {})}
    return (*pre, ("trace", "hybrid.trace", params, wires),
            ("shade", "rpo.shade", shade_params, {"visibility": "trace.visibility", "tangents": "tangents.tangents"}))


def harness_rows(quick: bool = False) -> list:
    """K in {8, 16, 32, 64} rays per vertex per frame with each control, on the animated scenes;
    and the SH visibility for RPO (glossy) with the static bake as control."""
    rows = []
    for samples in SAMPLES:
        for control in ("none", "previous", "ldprt"):
            rows.append(HarnessRow(
                "hybrid", f"n6 K{samples} {control}", stages_for(control, samples, trace=CONTROL_TRACE.get(control)),
                "shade.radiance", scenes=SCENES,
                quick=(samples == 16 and control == "none"),
                notes=f"{samples} rays per vertex per frame, control: {control}; residual filtered and averaged over frames",
            ))
        for scene, (training, frames) in DATADRIVEN_SCENES.items():
            rows.append(HarnessRow(
                "hybrid", f"n6 K{samples} datadriven", stages_for("datadriven", samples, training=training, frames=frames),
                "shade.radiance", scenes=(scene,), quick=False,
                notes=f"{samples} rays per vertex per frame, control: data-driven transfer trained on {training.split(':')[-1]}",
            ))
        rows.append(HarnessRow(
            "hybrid", f"n6 K{samples} shexp", stages_for("shexp", samples, trace=CONTROL_TRACE["shexp"]), "shade.radiance",
            scenes=("blockers",), quick=False,
            notes=f"{samples} rays per vertex per frame, control: SHEXP's blocker-sphere visibility (order 6, budget 8); "
                  "short history, 3 filter passes",
        ))
    for scene, (training, frames, rays) in VISIBILITY_TRAINING.items():
        rows.append(HarnessRow(
            "hybrid", "n6 K64 visibility rps",
            stages_for("visibility", 64, training=training, frames=frames, training_samples=rays,
                       trace=VISIBILITY_TRACES.get(scene, {**REPROJECT_SOFT, "filter_iterations": 2})),
            "shade.radiance", scenes=(scene,), quick=False,
            notes=f"64 rays per vertex per frame, control: the data-driven visibility model (as "
                  f"stages/figure_visibility_diffuse.toml, trained on {training.split(':')[-1]}) as transfer; history "
                  "reprojected by the frames' turn, soft reset; "
                  + ("filtered further where it is short" if scene == "figure" else "2 filter passes"),
        ))
    for samples in (16, 32):
        rows.append(HarnessRow(
            "hybrid-glossy", f"n4 K{samples} static", glossy_stages_for(samples, bake_samples=1024), "shade.radiance",
            scenes=("skinned", "deforming"), quick=False,
            notes=f"RPO k8 GGX 0.5 over SH visibility from {samples} rays per vertex per frame, control: the visibility "
                  "baked at the first frame (as rpo static n4 k8)",
        ))
    return rows

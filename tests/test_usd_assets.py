"""The bundled scenes: the generator reproduces their values within stated tolerances
(``tests/asset_compare.py``: exact structure, topology and metadata, floating values to ~1e-6, as
bytes differ by ulps between machines), their structure, `warpshade info`, and the training /
held-out clips of the two characters (figure, wanderer) for data-driven PRT."""

import dataclasses
import os

import numpy as np
import pytest
from pxr import Sdf

from warpshade.cli import main
from warpshade.io import bundled_asset_directory, load_usd
from warpshade.io import read_hdr, write_hdr
from warpshade.scene import Scene
from warpshade.usd_assets import generator
from warpshade.usd_assets.generator import figure, motions, wanderer
from warpshade.usd_assets.generator.bend import bend_joint_rotations
from warpshade.usd_assets.generator.cloth import cloth_points

from asset_compare import MERL_RTOL, RTOL, asset_differences, hdr_step

ASSETS = bundled_asset_directory()
FILES = ["sky.hdr", "blockers.usda", "figure.usda", "figure_orbit.usda", "cloth.usda", "bend.usda", "dish.usda",
         "measured_coating.binary"]
MAX_BYTES = 2 * 1024 * 1024  # issue 3: each bundled file < 2 MB
#: The clips of the data-driven PRT characters: (training clip, held-out clips) per character.
CLIPS = {
    "figure": ("figure_train", ["figure", "figure_walk"]),
    "wanderer": ("wanderer_train", ["wanderer_test"]),
}
CLIP_FILES = ["figure_train.usda", "figure_walk.usda", "wanderer_train.usdc", "wanderer_test.usdc"]
MAX_CLIP_BYTES = 8 * 1024 * 1024
#: Every held-out joint-angle component stays at least this far (radians) inside the training range.
RANGE_MARGIN = 0.02
#: Per character: the generator's joints, joint-limit table and training clip, and the training
#: clip's frames (the range of motion, then the motion library).
TRAINING = {
    "figure": (figure.FIGURE_JOINTS, figure.FIGURE_LIMITS, figure.FIGURE_TRAIN_CLIP, 300, 600),
    "wanderer": (wanderer.WANDERER_JOINTS, wanderer.WANDERER_LIMITS, wanderer.WANDERER_TRAIN_CLIP, 600, 1000),
}
#: The held-out clips stay held out (radians, RMS over all joint-angle components, i.e. the
#: rotation-vector components of every joint): no test frame lies within HELD_OUT_POSE_RMS of a
#: training frame, and no HELD_OUT_WINDOW consecutive test frames (half a second) lie within
#: HELD_OUT_MOTION_RMS of as many consecutive training frames. A copy of a test clip, played
#: at 0.5 to 2 times its speed (at any phase) or subsampled, comes within 0.007 of some test
#: frame; scaled by 0.9, or with a few joints changed by 0.1 rad, its half-seconds come within
#: 0.01-0.03 of the test's. The motion library's natural motions pass through generic poses near
#: some test frames (standing, arms lowering in front): nearest frames 0.027 (wanderer), 0.055
#: (figure_walk) and 0.077 (figure) away, nearest half-seconds 0.052, 0.077 and 0.10.
HELD_OUT_POSE_RMS = 0.015
HELD_OUT_MOTION_RMS = 0.04
HELD_OUT_WINDOW = 12


@pytest.fixture(scope="module")
def clips():
    """Every clip of the two characters, loaded once: name -> (Scene, joint angles (T, J, 3))."""
    out = {}
    for train, tests in CLIPS.values():
        for name in [train, *tests]:
            scene = load_usd(f"bundled:{name}")
            skel = scene.skeletons[0]
            out[name] = scene, np.stack([skel.joint_angles(t) for t in range(len(scene.frames))])
    return out


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    """The generator's output, written once for the module: (directory, written paths)."""
    out = tmp_path_factory.mktemp("generated")
    return out, generator.generate(str(out))


def test_generator_reproduces_the_bundled_files(generated):
    out, written = generated
    assert sorted(os.path.basename(p) for p in written) == sorted(FILES + CLIP_FILES)
    differences = []
    for name in FILES + CLIP_FILES:
        bundled = os.path.join(ASSETS, name)
        size = os.path.getsize(bundled)
        assert size < (MAX_CLIP_BYTES if name in CLIP_FILES else MAX_BYTES), f"{name} is {size} bytes"
        differences += asset_differences(bundled, out / name)
    assert not differences, ("the generator's output differs from the bundled files: rerun python -m "
                             "warpshade.usd_assets.generator\n" + "\n".join(differences))


# ---- the comparison catches real changes, and only those ----------------------------------------
#: A real change of a scene in the checks below: 1e-4 of its size (100 x RTOL).
CHANGE = 1e-4
#: The cloth sheet's size (m), for a change of one of its points.
CLOTH_SIZE = 2.0
SMALL_SPHERE = "/World/Blockers/SmallSphere.xformOp:translate"
BOX_MESH = "/World/Blockers/Box/Mesh"


def _edited_usd(src, dst, edit):
    """``src`` with ``edit(layer)`` applied, written to ``dst`` (its extension picks usda or usdc)."""
    layer = Sdf.Layer.OpenAsAnonymous(str(src))
    edit(layer)
    assert layer.Export(str(dst)), dst
    return dst


def _nudged(value, type_name: str):
    """``value`` moved by an ulp-level amount: float32 and half values by one ulp (towards +inf),
    float64 ones by 1e-12 of themselves; anything else unchanged."""
    if isinstance(value, float):
        if type_name in ("float", "half"):
            x = (np.float32 if type_name == "float" else np.float16)(value)
            return float(np.nextafter(x, type(x)(np.inf)))
        return value * (1.0 + 1e-12)
    if type(value).__module__ not in ("pxr.Vt", "pxr.Gf"):
        return value
    try:
        array = np.asarray(value)
    except Exception:
        return value
    if array.dtype.kind != "f":
        return value
    if array.dtype == np.float64:
        moved = array * (1.0 + 1e-12)
    else:
        moved = np.nextafter(array, np.array(np.inf, array.dtype))
    if type(value).__module__ == "pxr.Vt":
        return type(value).FromNumpy(moved)
    return type(value)(*moved.ravel().tolist())


def _nudge_every_float(layer):
    paths = []
    layer.Traverse(layer.pseudoRoot.path, paths.append)
    for path in paths:
        attr = layer.GetAttributeAtPath(path) if path.IsPropertyPath() else None
        if attr is None:
            continue
        type_name = str(attr.typeName)
        if attr.HasDefaultValue():
            attr.default = _nudged(attr.default, type_name)
        for t in layer.ListTimeSamplesForPath(path):
            layer.SetTimeSample(path, t, _nudged(layer.QueryTimeSample(path, t), type_name))
    layer.pseudoRoot.SetInfo("metersPerUnit", _nudged(layer.pseudoRoot.GetInfo("metersPerUnit"), "double"))


@pytest.mark.parametrize("name", FILES + CLIP_FILES)
def test_comparison_accepts_the_same_file(generated, name):
    assert asset_differences(generated[0] / name, generated[0] / name) == []


@pytest.mark.parametrize("name", ["blockers.usda", "figure_orbit.usda", "cloth.usda", "figure_train.usda", "wanderer_test.usdc"])
def test_comparison_accepts_ulp_level_differences_of_a_scene(generated, tmp_path, name):
    """Every floating value one float32 ulp (float64: 1e-12) away: what another machine may write."""
    src = generated[0] / name
    assert asset_differences(src, _edited_usd(src, tmp_path / f"same_{name}", lambda layer: None)) == []
    nudged = _edited_usd(src, tmp_path / name, _nudge_every_float)
    assert nudged.read_bytes() != src.read_bytes()
    assert asset_differences(src, nudged) == []


def test_comparison_accepts_one_rgbe_step_in_every_pixel(generated, tmp_path):
    """Every value a quantisation step lower (renormalised where the mantissa was 128), as when each
    float radiance lay just at a quantisation boundary and another machine computed it an ulp lower."""
    src = generated[0] / "sky.hdr"
    image = read_hdr(src)
    lower = image.astype(np.float64) - 0.5 * hdr_step(image)[..., None]  # the lower boundary of each value's step
    write_hdr(tmp_path / "sky.hdr", np.nextafter(lower.astype(np.float32), np.float32(0.0)))
    changed = read_hdr(tmp_path / "sky.hdr")
    assert np.mean(changed < image) > 0.9
    assert asset_differences(src, tmp_path / "sky.hdr") == []


def _merl_copy(src, dst, change):
    """``src`` with its float64 values passed through ``change(values)``."""
    raw = src.read_bytes()
    values = np.frombuffer(raw, "<f8", offset=12).copy()
    dst.write_bytes(raw[:12] + np.ascontiguousarray(change(values), "<f8").tobytes())
    return dst


def test_comparison_of_measured_tables(generated, tmp_path):
    src = generated[0] / "measured_coating.binary"
    close = _merl_copy(src, tmp_path / "close.binary", lambda v: np.where(v > 0.0, v * (1.0 + 1e-12), v))
    assert close.read_bytes() != src.read_bytes() and asset_differences(src, close) == []

    def one_value(v):
        k = int(np.flatnonzero(v > 0.0)[len(np.flatnonzero(v > 0.0)) // 2])  # a mid-table value, ~1e-4 of the peak
        v[k] *= 1.0 + 1e-6
        return v

    changed = asset_differences(src, _merl_copy(src, tmp_path / "changed.binary", one_value))
    assert len(changed) == 1 and "relative difference 1e-06" in changed[0] and "1 of 20736 values" in changed[0], changed
    assert 1e-6 > 100 * MERL_RTOL

    def invalid(v):
        v[int(np.flatnonzero(v < 0.0)[0])] = 0.0
        return v

    changed = asset_differences(src, _merl_copy(src, tmp_path / "invalid.binary", invalid))
    assert len(changed) == 1 and "invalid cells differ" in changed[0], changed


def test_comparison_catches_a_changed_pixel(generated, tmp_path):
    src = generated[0] / "sky.hdr"
    image = read_hdr(src)
    image[20, 40] *= 1.03
    write_hdr(tmp_path / "sky.hdr", image)
    changed = asset_differences(src, tmp_path / "sky.hdr")
    assert len(changed) == 1 and "pixel (row 20, column 40)" in changed[0] and "1 of 8192 pixels" in changed[0], changed


def _scene_size(layer) -> float:
    extent = np.asarray(layer.GetAttributeAtPath("/World/Ground.extent").default)
    return float(np.ptp(extent, axis=0).max())  # the ground plane, 6 m


def _move_sample(path, time, offset):
    def edit(layer):
        value = layer.QueryTimeSample(path, time)
        layer.SetTimeSample(path, time, value + type(value)(*(offset * _scene_size(layer))))
    return edit


def _set_element(path, index, change, time=None):
    """Change one element of an array attribute's default (or time sample) by ``change(element, layer)``."""
    def edit(layer):
        attr = layer.GetAttributeAtPath(path)
        value = attr.default if time is None else layer.QueryTimeSample(path, time)
        array = np.array(value)
        array[index] = change(array[index], layer)
        new = type(value).FromNumpy(array)
        if time is None:
            attr.default = new
        else:
            layer.SetTimeSample(path, time, new)
    return edit


def _drop_box(layer):
    del layer.GetPrimAtPath("/World/Blockers").nameChildren["Box"]


def _retime_sample(layer):
    value = layer.QueryTimeSample(SMALL_SPHERE, 12.0)
    layer.EraseTimeSample(SMALL_SPHERE, 12.0)
    layer.SetTimeSample(SMALL_SPHERE, 12.5, value)


def _set_end_time(layer):
    layer.endTimeCode = 60


def _set_up_axis(layer):
    layer.pseudoRoot.SetInfo("upAxis", "Y")


def _rename_texture(layer):
    layer.GetAttributeAtPath("/World/Sky.inputs:texture:file").default = Sdf.AssetPath("./sky2.hdr")


#: Name -> (file, edit, text in every reported difference, text in one of them).
REAL_CHANGES = {
    "translate sample": ("blockers.usda", _move_sample(SMALL_SPHERE, 30.0, np.array([CHANGE, 0, 0])),
                         f"{SMALL_SPHERE} timeSamples[30.0]", "of the largest magnitude"),
    "static point": ("blockers.usda", _set_element(f"{BOX_MESH}.points", (7, 2), lambda x, layer: x + CHANGE * _scene_size(layer)),
                     f"{BOX_MESH}.points default", "at element (7, 2)"),
    "topology index": ("blockers.usda", _set_element(f"{BOX_MESH}.faceVertexIndices", 5, lambda x, layer: (x + 1) % 150),
                       f"{BOX_MESH}.faceVertexIndices default", "1 of 384 values differ (element (5,)"),
    "prim dropped": ("blockers.usda", _drop_box, "/World/Blockers", "spec /World/Blockers/Box is missing"),
    "sample time": ("blockers.usda", _retime_sample, f"{SMALL_SPHERE} timeSamples",
                    "keys differ (bundled only: [12.0], generated only: [12.5])"),
    "end time code": ("blockers.usda", _set_end_time, "<layer> endTimeCode", "bundled 59"),
    "up axis": ("blockers.usda", _set_up_axis, "<layer> upAxis", "bundled 'Z', generated 'Y'"),
    "asset path": ("blockers.usda", _rename_texture, "/World/Sky.inputs:texture:file default", "sky2.hdr"),
    "cloth point in one sample": ("cloth.usda", _set_element("/World/Cloth.points", (123, 1),
                                                             lambda x, layer: x + CHANGE * CLOTH_SIZE, time=17.0),
                                  "/World/Cloth.points timeSamples[17.0]", "1 of 2700 values differ"),
    "joint rotation": ("figure_train.usda", _set_element("/World/Figure/Anim.rotations", (3, 0), lambda x, layer: x + CHANGE, time=100.0),
                       "/World/Figure/Anim.rotations timeSamples[100.0]", "at element (3, 0)"),
    "joint weight (crate)": ("wanderer_test.usdc", _set_element("/World/Wanderer/Body.primvars:skel:jointWeights", 10,
                                                                lambda x, layer: x + CHANGE),
                             "/World/Wanderer/Body.primvars:skel:jointWeights default", "at element (10,)"),
}


@pytest.mark.parametrize("change", sorted(REAL_CHANGES))
def test_comparison_catches_a_real_change_of_a_scene(generated, tmp_path, change):
    name, edit, everywhere, somewhere = REAL_CHANGES[change]
    src = generated[0] / name
    changed = asset_differences(src, _edited_usd(src, tmp_path / name, edit))
    assert changed and all(name in m and everywhere in m for m in changed), changed
    assert any(somewhere in m for m in changed), changed
    assert CHANGE >= 100 * RTOL


def test_blockers_structure():
    scene = load_usd("bundled:blockers")
    assert scene.up_axis == "Z" and len(scene.frames) == 60 and scene.camera is not None
    kinds = {m.path.split("/")[-2] if m.path.endswith("Mesh") else m.path: m.animation for m in scene.meshes}
    assert kinds == {"/World/Ground": "static", "BigSphere": "rigid", "SmallSphere": "rigid", "Box": "rigid"}
    assert scene.meshes[0].vertex_count == 40 * 40
    # the blockers stay above the ground and pass over it
    pts = np.stack([scene.points_at(f)[scene.meshes[1].vertex_offset :] for f in scene.frames])
    assert pts[..., 2].min() > 0.0
    big = scene.meshes[1]
    centre_x = pts[:, : big.vertex_count, 0].mean(axis=1)
    assert np.ptp(centre_x) > 3.0  # the big sphere crosses most of the 6 m plane


def test_figure_structure_and_arms_cross_in_front_of_the_torso(clips):
    scene = clips["figure"][0]
    body = next(m for m in scene.meshes if m.animation == "skinned")
    assert 1000 <= body.vertex_count <= 5000 and len(scene.frames) >= 60
    assert scene.skeletons[0].joint_count >= 10
    skel = scene.skeletons[0]
    names = [n.rsplit("/", 1)[-1] for n in skel.joint_names]
    forearm = np.isin(body.skin.joint_indices[:, 0], [names.index("LElbow"), names.index("RElbow")]) & (
        body.skin.joint_weights[:, 0] > 0.99
    )
    from warpshade.geometry._skinning import skin_points_f64

    in_front = []
    for t in range(len(scene.frames)):
        p = skin_points_f64(body.points, body.skin, skel.skinning_transforms(t))[forearm]
        # skeleton space: the torso is the capsule of radius 0.15 around the z axis, front is -y
        in_front.append(np.mean((np.abs(p[:, 0]) < 0.15) & (p[:, 1] < -0.15) & (p[:, 2] > 1.0) & (p[:, 2] < 1.5)))
    assert max(in_front) > 0.2  # at some frames a good part of a forearm is right in front of the chest


def test_cloth_and_bend_structure():
    cloth = load_usd("bundled:cloth")
    sheet = next(m for m in cloth.meshes if m.animation == "deforming")
    assert sheet.vertex_count == 900 and sheet.uvs is not None and sheet.point_samples.shape == (60, 900, 3)
    np.testing.assert_allclose(sheet.point_samples[7], cloth_points(7), atol=1e-4)
    bend = load_usd("bundled:bend")
    assert bend.skeletons[0].joint_count == 4 and bend.meshes[0].animation == "skinned"
    np.testing.assert_allclose(bend.skeletons[0].joint_angles(20), bend_joint_rotations(20), atol=1e-3)
    for scene in (cloth, bend):
        assert scene.lights and scene.lights[0].path.endswith("sky.hdr") and scene.camera is not None


@pytest.mark.parametrize("spec", ["bundled:figure", "warp-example:bear"])
def test_info_command(capsys, spec):
    assert main(["info", spec]) == 0
    out = capsys.readouterr().out
    if spec == "bundled:figure":
        assert "/World/Figure/Body" in out and "skinned" in out and "12 joints, 60 animated frame(s)" in out
        assert "DomeLight" in out and "sky.hdr" in out and "camera  /World/Camera" in out
        assert "frames 60 (time codes 0..59) at 24 fps" in out
    else:
        assert "/root/bear" in out and "1,986 v" in out and "up axis Y" in out


def test_info_reports_bad_input_without_a_traceback(capsys, tmp_path):
    assert main(["info", str(tmp_path / "missing.usda")]) == 2
    err = capsys.readouterr().err
    assert "error: USD file not found" in err and "missing.usda" in err and "Traceback" not in err


# ---- training and held-out clips ----------------------------------------------------------------
def _character_parts(scene):
    """What must not change between the clips of one character: everything but the animation."""
    skel = scene.skeletons[0]
    meshes = [
        (m.path, m.animation, m.faces, m.points, m.albedo)
        + ((m.skin.joint_indices, m.skin.joint_weights, m.skin.geom_bind_transform) if m.skin is not None else ())
        for m in scene.meshes
    ]
    rig = (skel.path, skel.joint_names, skel.parents, skel.bind_transforms, skel.rest_transforms, skel.skel_to_world[0])
    camera = (scene.camera.position, scene.camera.target, scene.camera.vertical_fov)
    return meshes, rig, camera, [light.path for light in scene.lights], scene.up_axis, scene.fps


def _assert_same(a, b, where):
    if isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b)):
            _assert_same(x, y, f"{where}[{k}]")
    elif isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b, err_msg=where)
    else:
        assert a == b, where


@pytest.mark.parametrize("character", sorted(CLIPS))
def test_clips_share_the_character_exactly(clips, character):
    train, tests = CLIPS[character]
    reference = _character_parts(clips[train][0])
    for name in tests:
        _assert_same(_character_parts(clips[name][0]), reference, f"{name} vs {train}")
    train_angles = clips[train][1]
    for name in tests:  # ... and each clip animates it in its own way
        angles = clips[name][1]
        assert np.ptp(angles, axis=0).max() > 0.3 and np.abs(angles - train_angles[: len(angles)]).max() > 0.3, name


@pytest.mark.parametrize("character", sorted(CLIPS))
def test_held_out_joint_angles_lie_inside_the_training_ranges(clips, character):
    train, tests = CLIPS[character]
    angles = clips[train][1]
    assert angles.shape[0] >= 200
    lo, hi = angles.min(axis=0), angles.max(axis=0)
    names = [n.rsplit("/", 1)[-1] for n in clips[train][0].skeletons[0].joint_names]
    for name in tests:
        test_angles = clips[name][1]
        assert test_angles.shape[0] >= 60
        inside = np.minimum(test_angles.min(axis=0) - lo, hi - test_angles.max(axis=0))  # (J, 3)
        j, k = np.unravel_index(np.argmin(inside), inside.shape)
        assert inside.min() >= RANGE_MARGIN, f"{name}: {names[j]} component {'xyz'[k]} is {inside.min():.3f} rad from the edge"


@pytest.mark.parametrize("character", sorted(CLIPS))
def test_training_clip_moves_the_joints_independently(clips, character):
    """Every joint-angle component varies, and the standardised (frames x components) design matrix
    is well conditioned: a linear regression on joint angles can tell the components apart."""
    angles = clips[CLIPS[character][0]][1]
    design = angles.reshape(len(angles), -1)
    assert design.std(axis=0).min() > 0.005
    z = (design - design.mean(axis=0)) / design.std(axis=0)
    singular = np.linalg.svd(z / np.sqrt(len(z)), compute_uv=False)
    assert singular[0] / singular[-1] < 100.0
    assert np.abs(np.corrcoef(z.T) - np.eye(z.shape[1])).max() < 0.95


def test_wanderer_structure(clips):
    scene = clips["wanderer_test"][0]
    skel = scene.skeletons[0]
    names = [n.rsplit("/", 1)[-1] for n in skel.joint_names]
    body, hat = (next(m for m in scene.meshes if m.path == f"/World/Wanderer/{p}") for p in ("Body", "Hat"))
    ground = next(m for m in scene.meshes if m.path == "/World/Ground")
    assert body.animation == hat.animation == "skinned" and ground.animation == "static"
    assert body.vertex_count + hat.vertex_count >= 10_000 and skel.joint_count >= 20
    assert names == [j[0] for j in wanderer.WANDERER_JOINTS]
    parent = {names[j]: (names[p] if p >= 0 else None) for j, p in enumerate(skel.parents)}
    for chain in (["Hips", "Spine", "Chest", "Neck", "Head"], ["LHip", "LKnee", "LAnkle"], ["RHip", "RKnee", "RAnkle"]):
        assert all(parent[b] == a for a, b in zip(chain, chain[1:])), chain
    for side in "LR":
        assert parent[f"{side}Wrist"] == f"{side}Elbow" and parent[f"{side}Elbow"] == f"{side}Shoulder"
        digits = [n[1:-1] for n in names if n.startswith(side) and n.endswith("1") and parent[n] == f"{side}Wrist"]
        assert len(digits) >= 3 and all(parent[f"{side}{d}2"] == f"{side}{d}1" for d in digits), digits
        for d in digits:  # the fingers are small detail, skinned to their own joints
            tip = names.index(f"{side}{d}2")
            assert np.sum(body.skin.joint_indices[:, 0] == tip) > 20
    # the body: 4 influences, blended smoothly (up to 3 non-zero at once), weights sum to 1
    assert body.skin.joint_indices.shape[1] == 4
    nonzero = (body.skin.joint_weights > 1e-3).sum(axis=1)
    assert nonzero.min() >= 1 and nonzero.max() >= 3 and np.mean(nonzero >= 2) > 0.3
    np.testing.assert_allclose(body.skin.joint_weights.sum(axis=1), 1.0, atol=1e-5)
    # the hat: rigidly on the head joint, and its brim is broad
    assert np.all(hat.skin.joint_indices == names.index("Head")) and np.all(hat.skin.joint_weights == 1.0)
    assert np.ptp(hat.points[:, 0]) > 0.8 and np.ptp(body.points[:, 0]) < 1.0
    assert scene.camera is not None and scene.lights and scene.lights[0].path.endswith("sky.hdr")
    np.testing.assert_allclose(skel.joint_angles(60), wanderer.wanderer_test_rotations(60), atol=1e-3)


def test_the_hat_casts_a_wide_shadow_that_moves_with_the_head(clips):
    """Visibility (ambient occlusion, ray traced) of the upper body with and without the hat: the
    hat darkens it, and where it darkens it changes between looking up (frame 60) and the bow (95)."""
    from warpshade.transfer import compute

    scene = clips["wanderer_test"][0]
    body = next(m for m in scene.meshes if m.path == "/World/Wanderer/Body")
    upper = np.flatnonzero((body.points[:, 2] > 1.25) & (body.points[:, 2] < 1.75))[::6] + body.vertex_offset
    assert 200 <= len(upper) <= 400
    hatless = Scene(
        [dataclasses.replace(m) for m in scene.meshes if not m.path.endswith("/Hat")],
        frames=scene.frames, fps=scene.fps, skeletons=scene.skeletons, lights=scene.lights, up_axis=scene.up_axis,
    )
    assert all(m.vertex_offset == n.vertex_offset for m, n in zip(hatless.meshes, scene.meshes))
    darkening = []
    for frame in (60.0, 95.0):
        with_hat, without = (compute(s, frame, order=1, samples=64, vertices=upper).ambient_occlusion for s in (scene, hatless))
        darkening.append(without - with_hat)
    for d in darkening:
        assert d.mean() > 0.05 and np.mean(d > 0.1) > 0.2
    assert np.mean(np.abs(darkening[1] - darkening[0]) > 0.1) > 0.15  # 64-sample noise alone moves ~1 %


@pytest.mark.parametrize("character", sorted(CLIPS))
def test_training_clip_is_the_range_of_motion_then_the_motion_library(clips, character):
    """The range of motion, unchanged, then natural motions: every pose inside the joint-limit
    table, and no pose jumps anywhere in the library (the segments cross-fade)."""
    joints, table, clip, rom_frames, frames = TRAINING[character]
    limits = motions.joint_limits(joints, table)
    angles = clips[CLIPS[character][0]][1]
    assert clip.shape == (frames, len(joints), 3) and angles.shape == clip.shape
    np.testing.assert_allclose(angles, clip, atol=2e-3)  # the file holds the generator's clip
    mixed = rom_frames - len(joints) * motions.SWEEP_FRAMES
    np.testing.assert_array_equal(clip[:rom_frames], motions.range_of_motion_clip(limits, mixed))
    assert np.all(clip >= limits[..., 0] - 1e-9) and np.all(clip <= limits[..., 1] + 1e-9)
    step = np.diff(clip[rom_frames - 1 :], axis=0)  # from the last frame of the range of motion on
    assert np.abs(step).max() < 0.45
    assert np.sqrt((step.reshape(len(step), -1) ** 2).mean(axis=1)).max() < 0.1


def _nearest_rms(test, train, window=1):
    """RMS (over components and ``window`` consecutive frames) from each stretch of ``window``
    test frames to the nearest stretch of as many training frames; poses (T, J, 3), (N, J, 3)."""
    a, b = test.reshape(len(test), -1), train.reshape(len(train), -1)
    d2 = np.maximum((a * a).sum(1)[:, None] - 2.0 * a @ b.T + (b * b).sum(1)[None], 0.0) / a.shape[1]
    t, n = d2.shape
    stretch = sum(d2[k : t - window + 1 + k, k : n - window + 1 + k] for k in range(window)) / window
    return np.sqrt(stretch.min(axis=1))


@pytest.mark.parametrize("character", sorted(CLIPS))
def test_held_out_clips_are_not_in_the_training_clip(clips, character):
    train, tests = CLIPS[character]
    train_angles = clips[train][1]
    for name in tests:
        test_angles = clips[name][1]
        pose = _nearest_rms(test_angles, train_angles)
        motion = _nearest_rms(test_angles, train_angles, HELD_OUT_WINDOW)
        assert pose.min() > HELD_OUT_POSE_RMS, f"{name}: frame {pose.argmin()} is {pose.min():.4f} rad RMS from a training pose"
        assert motion.min() > HELD_OUT_MOTION_RMS, f"{name}: frames from {motion.argmin()} are {motion.min():.4f} rad RMS from training frames"
        # ... while the checks would catch the clip itself in the training clip, retimed or smaller
        assert _nearest_rms(test_angles, np.concatenate([train_angles, test_angles[::2]])).min() < HELD_OUT_POSE_RMS
        smaller = np.concatenate([train_angles, 0.9 * test_angles])
        assert _nearest_rms(test_angles, smaller, HELD_OUT_WINDOW).min() < HELD_OUT_MOTION_RMS

"""UsdLux lights: dome orientation (asymmetric textures), emission scaling, distant and sphere lights.

The dome textures are painted in the test from the OpenEXR lat-long rule that UsdLux documents
(pixel (0, 0) at latitude +pi/2, longitude +pi; lat 0/lon 0 = +Z, lon pi/2 = +X, +Y up), so the
expected world direction of every painted texel is known without the loader.
"""

import math

import numpy as np
import pytest

from warpshade.io import write_exr, write_hdr
from warpshade.io import load_usd
from warpshade.scene import DistantLight, Environment, SphereLight, usd_dome_texel_directions

#: RGBE stores 8 mantissa bits: relative error 2**-8 of the largest channel.
RGBE_RELATIVE = 2.0**-8

TRI = """
def Mesh "Tri"
{
    int[] faceVertexCounts = [3]
    int[] faceVertexIndices = [0, 1, 2]
    point3f[] points = [(0,0,0), (1,0,0), (0,1,0)]
}
"""

H, W = 16, 32
#: distinct colours painted at the texels of these dome-local directions
MARKS = {
    "+X": ((0.0, math.pi / 2), (1.0, 0.0, 0.0)),
    "+Z": ((0.0, 0.0), (0.0, 1.0, 0.0)),
    "-X": ((0.0, -math.pi / 2), (0.0, 0.0, 1.0)),
    "+Y": ((math.pi / 2 - 1e-9, 0.0), (1.0, 1.0, 0.0)),
}
DOME_AXIS = {"+X": (1, 0, 0), "+Z": (0, 0, 1), "-X": (-1, 0, 0), "+Y": (0, 1, 0)}


def _painted_texture():
    """A dark texture with a colour block around each marked (lat, lon), from the OpenEXR rule."""
    img = np.full((H, W, 3), 0.01, np.float32)
    for name, ((lat, lon), rgb) in MARKS.items():
        if name == "+Y":  # the pole is the whole top row
            img[0] = rgb
            continue
        row = min(int((math.pi / 2 - lat) / math.pi * H), H - 1)
        col = int(round((math.pi - lon) / (2 * math.pi) * W - 0.5)) % W
        rows = range(0, 2) if row == 0 else range(row - 1, row + 1)
        for r in rows:
            for c in ((col - 1) % W, col, (col + 1) % W):
                img[r, c] = rgb
    return img


def _dome_file(tmp_path, prim_text, up="Y", tex="sky.hdr", image=None, writer=write_hdr):
    if image is not None:
        writer(tmp_path / tex, image)
    path = tmp_path / f"dome_{abs(hash(prim_text)) % 10**8}.usda"
    path.write_text(f'#usda 1.0\n(\n    upAxis = "{up}"\n)\n' + TRI + prim_text)
    return str(path)


def _assert_marks(env, dome_to_world):
    for name, (_, rgb) in MARKS.items():
        world = np.asarray(dome_to_world, float) @ np.asarray(DOME_AXIS[name], float)
        np.testing.assert_allclose(env.radiance(world), rgb, atol=0.02, err_msg=f"dome {name}")


DOME = 'def DomeLight "Sky"\n{\n    asset inputs:texture:file = @./sky.hdr@\n%s}\n'
ROT_X_90 = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # +Y -> +Z
ROT_Y_90 = np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])  # +Z -> +X


@pytest.mark.parametrize(
    "case, up, prim, dome_to_world",
    [
        ("identity, Y-up", "Y", DOME % "", np.eye(3)),
        (
            "orientToStageUpAxis, Z-up",
            "Z",
            DOME % '    float xformOp:rotateX:orientToStageUpAxis = 90\n    uniform token[] xformOpOrder = ["xformOp:rotateX:orientToStageUpAxis"]\n',
            ROT_X_90,
        ),
        ("DomeLight_1 poleAxis=scene, Z-up", "Z", DOME.replace("DomeLight", "DomeLight_1") % "", ROT_X_90),
        ("DomeLight_1 poleAxis=Y, Z-up", "Z", DOME.replace("DomeLight", "DomeLight_1") % '    uniform token poleAxis = "Y"\n', np.eye(3)),
        (
            "rotateY 90, Y-up",
            "Y",
            DOME % '    float xformOp:rotateY = 90\n    uniform token[] xformOpOrder = ["xformOp:rotateY"]\n',
            ROT_Y_90,
        ),
    ],
)
def test_dome_orientation_follows_the_usdlux_convention(tmp_path, case, up, prim, dome_to_world):
    scene = load_usd(_dome_file(tmp_path, prim, up=up, image=_painted_texture()))
    env = scene.lights[0]
    assert isinstance(env, Environment)
    _assert_marks(env, dome_to_world)
    # a proper rotation: the texture is not mirrored
    assert np.linalg.det(env.to_world) == pytest.approx(1.0)


def test_texel_directions_match_from_usd_dome(rng):
    img = rng.uniform(0, 1, (8, 16, 3)).astype(np.float32)
    rot = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    rot *= np.linalg.det(rot)
    env = Environment.from_usd_dome(img, rot)
    dirs = usd_dome_texel_directions(8, 16) @ rot.T
    # bilinear lookup at a texel centre returns the texel
    np.testing.assert_allclose(env.radiance(dirs), img, atol=1e-5)


def test_emission_scaling_and_exr_texture(tmp_path):
    img = _painted_texture()
    prim = (
        'def DomeLight "Sky"\n{\n    asset inputs:texture:file = @./sky.exr@\n'
        "    float inputs:intensity = 3\n    float inputs:exposure = 1\n    color3f inputs:color = (1, 0.5, 0.25)\n}\n"
    )
    env = load_usd(_dome_file(tmp_path, prim, tex="sky.exr", image=img, writer=write_exr)).lights[0]
    scale = 3.0 * 2.0 * np.array([1.0, 0.5, 0.25])
    np.testing.assert_allclose(env.radiance([1.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]) * scale, rtol=1e-6)
    np.testing.assert_allclose(env.image.max(axis=(0, 1)), scale, rtol=1e-6)


def test_dome_without_texture_is_constant(tmp_path):
    prim = 'def DomeLight "Sky"\n{\n    float inputs:intensity = 2\n    color3f inputs:color = (0.5, 1, 1)\n}\n'
    env = load_usd(_dome_file(tmp_path, prim)).lights[0]
    np.testing.assert_allclose(env.radiance(np.eye(3)), [[1.0, 2.0, 2.0]] * 3)


def test_missing_and_unreadable_dome_textures(tmp_path):
    with pytest.raises(ValueError, match="dome light /Sky.*'./sky.hdr' not found"):
        load_usd(_dome_file(tmp_path, DOME % ""))
    (tmp_path / "sky.hdr").write_bytes(b"#?RADIANCE\n\n-Y 4 +X 8\n")  # header only, no pixels
    with pytest.raises(ValueError, match="dome light /Sky.*cannot read texture .*sky.hdr"):
        load_usd(_dome_file(tmp_path, DOME % ""))


def test_distant_light(tmp_path):
    prim = (
        'def DistantLight "Sun"\n{\n    float inputs:angle = 2\n    float inputs:intensity = 1000\n'
        '    float xformOp:rotateX = -60\n    uniform token[] xformOpOrder = ["xformOp:rotateX"]\n}\n'
        'def DistantLight "Norm"\n{\n    bool inputs:normalize = 1\n    float inputs:intensity = 5\n    float inputs:angle = 0\n}\n'
    )
    lights = load_usd(_dome_file(tmp_path, prim, up="Z")).lights
    sun, norm = lights
    assert isinstance(sun, DistantLight) and sun.path == "/Sun"
    # local +Z (towards the light) rotated by -60 degrees about X: (0, sin 60, cos 60)
    np.testing.assert_allclose(sun.direction, [0.0, math.sin(math.radians(60)), 0.5], atol=1e-7)
    solid_angle = 2 * math.pi * (1 - math.cos(math.radians(1.0)))
    np.testing.assert_allclose(sun.irradiance, 1000 * solid_angle, rtol=1e-6)
    assert sun.angle_deg == pytest.approx(2.0)
    np.testing.assert_allclose(norm.irradiance, 5.0)  # normalised: intensity is illuminance
    np.testing.assert_allclose(norm.direction, [0, 0, 1])


def test_sphere_light_and_unsupported_lights(tmp_path):
    prim = (
        'def SphereLight "Bulb"\n{\n    float inputs:radius = 0.5\n    float inputs:intensity = 10\n'
        '    double3 xformOp:translate = (1, 2, 3)\n    double3 xformOp:scale = (2, 2, 2)\n'
        '    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]\n}\n'
        'def SphereLight "Normalised"\n{\n    float inputs:radius = 1\n    float inputs:intensity = 8\n    bool inputs:normalize = 1\n}\n'
        'def RectLight "Panel"\n{\n}\n'
    )
    scene = load_usd(_dome_file(tmp_path, prim))
    bulb, normalised = scene.lights
    assert isinstance(bulb, SphereLight)
    np.testing.assert_allclose(bulb.position, [1, 2, 3])
    assert bulb.radius == pytest.approx(1.0)  # radius 0.5 scaled by 2
    np.testing.assert_allclose(bulb.radiance, 10.0)
    np.testing.assert_allclose(normalised.radiance, 8.0 / (4 * math.pi))
    assert ("/Panel", "unsupported light type RectLight") in scene.skipped


def test_bundled_sky_puts_the_sun_where_the_generator_says(tmp_path):
    from warpshade.usd_assets.generator.sky import SUN_DIRECTION

    env = load_usd("bundled:blockers").lights[0]
    from warpshade.basis import quadrature

    q = quadrature.fibonacci(4000)
    brightest = q.directions[np.argmax(env.radiance(q.directions).sum(axis=1))]
    # within the 12 degree sun disc, at the lat-long resolution of the 64 x 128 texture
    assert np.degrees(np.arccos(np.clip(brightest @ SUN_DIRECTION, -1, 1))) < 4.0
    assert env.radiance([0.0, 0.0, 1.0]).sum() > env.radiance([0.0, 0.0, -1.0]).sum()  # sky above ground


# ---- animated light transforms -------------------------------------------------------------
ANIMATED = """#usda 1.0
(
    upAxis = "Y"
    startTimeCode = 0
    endTimeCode = 4
)
""" + TRI + """
def DomeLight "Sky"
{
    asset inputs:texture:file = @./sky.hdr@
    float xformOp:rotateY.timeSamples = {0: 0, 4: 90}
    uniform token[] xformOpOrder = ["xformOp:rotateY"]
}
def DistantLight "Sun"
{
    float inputs:angle = 0
    float xformOp:rotateX.timeSamples = {0: 0, 4: -60}
    uniform token[] xformOpOrder = ["xformOp:rotateX"]
}
def SphereLight "Bulb"
{
    float inputs:radius = 0.25
    double3 xformOp:translate.timeSamples = {0: (0, 1, 0), 4: (2, 1, 0)}
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
def SphereLight "Still"
{
    float inputs:radius = 0.25
}
"""


def _rot(axis, degrees):
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.radians(degrees) * np.asarray(axis, float)).as_matrix()


def test_animated_light_transforms_are_followed(tmp_path):
    from warpshade.scene import LightingSource
    from warpshade.scene import lights_to_sh

    write_hdr(tmp_path / "sky.hdr", _painted_texture())
    (tmp_path / "anim.usda").write_text(ANIMATED)
    scene = load_usd(str(tmp_path / "anim.usda"))
    sky, sun, bulb, still = scene.lights
    assert sky.track is not None and sun.track is not None and bulb.track is not None
    assert still.track is None, "a light without time samples has no track"
    source = LightingSource(scene.lights, scene.up_axis)
    assert source.animated
    for f in scene.frames:
        angle = 90.0 * f / 4.0  # USD interpolates the xformOp value linearly
        env, distant, sphere, fixed = source.lights_at(f)
        assert env.track is None and distant.track is None and sphere.track is None
        # the dome's painted marks sit where UsdLux's rule puts them, rotated about +Y
        _assert_marks(env, _rot((0, 1, 0), angle))
        # local +Z (towards the light) rotated about X by -60 f / 4 degrees
        np.testing.assert_allclose(distant.direction, _rot((1, 0, 0), -60.0 * f / 4.0) @ [0, 0, 1], atol=1e-9)
        np.testing.assert_allclose(sphere.position, [2.0 * f / 4.0, 1.0, 0.0], atol=1e-9)
        np.testing.assert_allclose(fixed.position, 0.0)
        # SH lighting per frame (rotated once-projected coefficients) = projection of the posed lights
        np.testing.assert_allclose(source.sh(4, f), lights_to_sh(source.lights_at(f), 4), atol=1e-9)
    fp = source.fingerprint()
    assert fp == LightingSource(load_usd(str(tmp_path / "anim.usda")).lights, "Y").fingerprint()
    (tmp_path / "anim.usda").write_text(ANIMATED.replace("{0: 0, 4: 90}", "{0: 0, 4: 45}"))
    assert fp != LightingSource(load_usd(str(tmp_path / "anim.usda")).lights, "Y").fingerprint(), \
        "a changed light animation changes the lighting fingerprint (ground-truth caches)"


def test_light_track_interpolation_and_bad_tracks():
    from warpshade.scene import LightTrack

    mats = np.tile(np.eye(4), (3, 1, 1))
    for i, deg in enumerate((0.0, 80.0, 160.0)):
        mats[i, :3, :3] = _rot((0, 0, 1), deg).T * 2.0  # row-vector convention, uniform scale 2
        mats[i, 3, :3] = (i, 0.0, -i)
    track = LightTrack(np.array([0.0, 1.0, 3.0]), mats)
    np.testing.assert_allclose(track.rotation(0.0), np.eye(3), atol=1e-12)
    np.testing.assert_allclose(track.rotation(0.5), _rot((0, 0, 1), 40.0), atol=1e-12)  # slerp, scale removed
    np.testing.assert_allclose(track.rotation(2.0), _rot((0, 0, 1), 120.0), atol=1e-12)
    np.testing.assert_allclose(track.rotation(9.0), _rot((0, 0, 1), 160.0), atol=1e-12)  # held after the end
    np.testing.assert_allclose(track.position(2.0), [1.5, 0.0, -1.5])
    with pytest.raises(ValueError, match="increase"):
        LightTrack(np.array([0.0, 0.0, 1.0]), mats)
    with pytest.raises(ValueError, match=r"\(T, 4, 4\)"):
        LightTrack(np.array([0.0]), mats[:1])
    mirrored = mats.copy()
    mirrored[1, 0, :3] *= -1.0
    with pytest.raises(ValueError, match="mirrored"):
        LightTrack(np.array([0.0, 1.0, 3.0]), mirrored)

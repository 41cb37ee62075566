"""Textures and UsdPreviewSurface maps: bilinear sampling (hand-computed values, wrap modes), the
Warp sampler against the float64 one, sRGB decoding, and reading UsdUVTexture networks from USD
with their failure modes (missing / empty / unreadable / wrong-channel textures, no UVs)."""

import numpy as np
import pytest
from PIL import Image

from warpshade.io import load_usd
from warpshade.scene import Mesh
from warpshade.scene._textures import WRAP_MODES, linear_to_srgb, sample_surface_warp, sample_texture_warp, srgb_to_linear
from warpshade.scene import SurfaceMaps, Texture

#: float32 texel arithmetic (bilinear weights and 4 products) against float64: a few ulps of
#: values of order 1.
ATOL_FLOAT32 = 2e-6
#: 8-bit texture values are exact multiples of 1/255; float32 storage adds ~1e-7.
ATOL_8BIT = 1e-6

# 2 x 2 image, row 0 = top (v = 0.75), row 1 = bottom (v = 0.25).
TOP_LEFT, TOP_RIGHT, BOTTOM_LEFT, BOTTOM_RIGHT = 1.0, 2.0, 3.0, 5.0
SMALL = np.array([[TOP_LEFT, TOP_RIGHT], [BOTTOM_LEFT, BOTTOM_RIGHT]], np.float32)[..., None]


# ---- float64 sampler ---------------------------------------------------------------------------
def test_bilinear_matches_hand_computed_values():
    tex = Texture(SMALL, wrap="clamp")
    uv = [[0.25, 0.75], [0.75, 0.75], [0.25, 0.25], [0.75, 0.25], [0.5, 0.5], [0.5, 0.75], [0.375, 0.25]]
    expected = [
        TOP_LEFT, TOP_RIGHT, BOTTOM_LEFT, BOTTOM_RIGHT,  # texel centres
        (TOP_LEFT + TOP_RIGHT + BOTTOM_LEFT + BOTTOM_RIGHT) / 4,  # the middle of the four
        (TOP_LEFT + TOP_RIGHT) / 2,  # halfway along the top row
        0.75 * BOTTOM_LEFT + 0.25 * BOTTOM_RIGHT,  # a quarter of the way from bottom-left to bottom-right
    ]
    np.testing.assert_allclose(tex.sample(uv)[:, 0], expected, rtol=0, atol=1e-12)
    # v up: the bottom-left corner of the uv square is the bottom-left texel of the image
    assert tex.sample([0.0, 0.0])[0, 0] == BOTTOM_LEFT and tex.sample([0.0, 1.0])[0, 0] == TOP_LEFT


def test_wrap_modes():
    rng = np.random.default_rng(3)
    img = rng.random((4, 6, 3)).astype(np.float32)
    uv = rng.uniform(0.0, 1.0, (200, 2))
    rep = Texture(img, wrap="repeat")
    np.testing.assert_allclose(rep.sample(uv + [3.0, -2.0]), rep.sample(uv), atol=1e-12)
    # repeat at the u = 0 edge: halfway between the last and the first column
    at_edge = rep.sample([[0.0, 1.0 - 0.5 / 4]])[0]
    np.testing.assert_allclose(at_edge, 0.5 * (img[0, 0] + img[0, -1]), atol=1e-7)
    mir = Texture(img, wrap="mirror")
    np.testing.assert_allclose(mir.sample(-uv), mir.sample(uv), atol=1e-12)
    np.testing.assert_allclose(mir.sample(2.0 - uv), mir.sample(uv), atol=1e-12)
    np.testing.assert_allclose(mir.sample(uv + 2.0), mir.sample(uv), atol=1e-12)
    clamp = Texture(img, wrap="clamp")
    np.testing.assert_allclose(clamp.sample([[-7.0, 1.0 - 0.5 / 4]])[0], img[0, 0], atol=1e-7)
    np.testing.assert_allclose(clamp.sample([[1e9, -1e9]])[0], img[-1, -1], atol=1e-7)
    black = Texture(img, wrap="black")
    np.testing.assert_array_equal(black.sample([[-0.5, 0.5], [1.5, 0.5], [0.5, 3.0]]), 0.0)
    np.testing.assert_allclose(black.sample([[0.0, 1.0 - 0.5 / 4]])[0], 0.5 * img[0, 0], atol=1e-7)
    # separate modes per axis: repeat in u, clamp in v
    mixed = Texture(img, wrap=("repeat", "clamp"))
    np.testing.assert_allclose(mixed.sample([[0.3 + 5.0, 7.0]]), clamp.sample([[0.3, 1.0]]), atol=1e-12)
    # huge coordinates stay bounded (reduced to one period before indexing)
    for mode in WRAP_MODES:
        values = Texture(img, wrap=mode).sample([[1e12, -3e11], [-1e15, 1e15]])
        assert np.all(np.isfinite(values)) and values.min() >= 0.0 and values.max() <= img.max() + 1e-6


def test_bad_texture_input_raises_naming_the_parameter():
    with pytest.raises(ValueError, match="1 to 4 channels"):
        Texture(np.zeros((2, 2, 5)), path="five.png")
    with pytest.raises(ValueError, match=r"zero\.png.*H, W >= 1"):
        Texture(np.zeros((0, 4, 3)), path="zero.png")
    with pytest.raises(ValueError, match="NaN"):
        Texture(np.full((2, 2, 1), np.nan))
    with pytest.raises(ValueError, match="wrap_s.*one of black, clamp, repeat, mirror"):
        Texture(SMALL, wrap="tile")
    with pytest.raises(ValueError, match=r"uv must have shape \(N, 2\)"):
        Texture(SMALL).sample(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="uv has NaN"):
        Texture(SMALL).sample([[np.nan, 0.5]])


# ---- Warp --------------------------------------------------------------------------------------
@pytest.mark.parametrize("channels", [1, 3, 4])
def test_warp_sampler_matches_float64(device, channels):
    rng = np.random.default_rng(channels)
    img = rng.random((5, 7, channels)).astype(np.float32)
    uv = rng.uniform(-2.5, 3.5, (500, 2))
    for wrap_s in WRAP_MODES:
        for wrap_t in WRAP_MODES:
            tex = Texture(img, wrap=(wrap_s, wrap_t))
            got = sample_texture_warp(tex, uv, device=device)
            np.testing.assert_allclose(got, tex.sample_rgb(uv), atol=ATOL_FLOAT32, err_msg=f"{wrap_s}/{wrap_t}")
    if channels == 1:  # a grey texture returns (x, x, x)
        assert np.all(got[:, 0] == got[:, 1]) and np.all(got[:, 1] == got[:, 2])


def test_warp_sampler_bounded_for_non_finite_and_huge_uv(device):
    tex = Texture(np.random.default_rng(0).random((3, 3, 3)), wrap="repeat")
    got = sample_texture_warp(tex, [[np.nan, 0.5], [np.inf, 0.2], [1e30, -1e30], [0.5, 0.5]], device=device)
    assert np.all(np.isfinite(got)) and np.all(got[:2] == 0.0) and got.max() <= 1.0


def test_surface_maps_rules_and_warp_kernel(device):
    rng = np.random.default_rng(5)
    colour = Texture(rng.random((6, 4, 3)), wrap="repeat")
    rough = Texture(rng.uniform(0.05, 0.6, (3, 5)), wrap="clamp")
    metal = Texture(rng.random((4, 4, 1)), wrap="mirror")
    uv = rng.uniform(-1.0, 2.0, (300, 2))
    maps = SurfaceMaps(diffuse=colour, roughness=rough, metallic=metal, ior=1.5)
    ref = maps.sample(uv)
    base, m = colour.sample(uv), metal.sample(uv)
    np.testing.assert_allclose(ref["diffuse"], base * (1 - m), atol=1e-12)
    np.testing.assert_allclose(ref["specular"], 0.04 * (1 - m) + base * m, atol=1e-12)  # lerp(F0, diffuse, metallic)
    np.testing.assert_allclose(ref["roughness"], rough.sample(uv)[:, 0], atol=1e-12)
    got = sample_surface_warp(maps, uv, device=device)
    for key in ref:
        np.testing.assert_allclose(got[key], ref[key], atol=ATOL_FLOAT32, err_msg=key)
    spec = SurfaceMaps(diffuse=(0.2, 0.3, 0.4), roughness=rough, specular=colour, use_specular_workflow=True)
    ref, got = spec.sample(uv), sample_surface_warp(spec, uv, device=device)
    np.testing.assert_allclose(ref["specular"], colour.sample(uv), atol=1e-12)
    np.testing.assert_allclose(ref["diffuse"], np.tile([0.2, 0.3, 0.4], (300, 1)), atol=1e-12)
    for key in ref:
        np.testing.assert_allclose(got[key], ref[key], atol=ATOL_FLOAT32, err_msg=key)
    # constants only: no UVs needed; textured maps without UVs are reported
    const = SurfaceMaps(diffuse=(0.5, 0.5, 0.5), roughness=0.3).at_vertices(None, vertex_count=4)
    assert const["diffuse"].shape == (4, 3) and np.all(const["roughness"] == 0.3)
    with pytest.raises(ValueError, match="textured .*roughness.* no texture coordinates"):
        maps.at_vertices(None, vertex_count=3)
    # out-of-range inputs are clipped to the parameters' ranges, never NaN
    wild = SurfaceMaps(diffuse=(3.0, -1.0, 0.5), roughness=-2.0, metallic=7.0).sample(count=1)
    assert np.all(np.isfinite(np.concatenate([v.ravel() for v in wild.values()])))
    assert wild["roughness"][0] == 0.0 and np.all(wild["diffuse"] == 0.0) and np.all(wild["specular"] <= 1.0)
    with pytest.raises(ValueError, match="roughness: texture .* has 3 channels"):
        SurfaceMaps(roughness=colour)
    with pytest.raises(ValueError, match="ior must be finite and > 0"):
        SurfaceMaps(ior=0.0)


def test_mesh_with_textured_surface_needs_uvs():
    maps = SurfaceMaps(roughness=Texture(SMALL))
    with pytest.raises(ValueError, match=r"mesh /M: textured surface maps \(roughness\) need uvs of shape \(3, 2\)"):
        Mesh("/M", np.eye(3), [[0, 1, 2]], surface=maps)
    assert Mesh("/M", np.eye(3), [[0, 1, 2]], uvs=np.zeros((3, 2)), surface=maps).surface is maps


def test_srgb_decode():
    # IEC 61966-2-1 reference points
    np.testing.assert_allclose(srgb_to_linear([0.0, 0.04045, 0.5, 1.0]), [0.0, 0.04045 / 12.92, 0.21404114, 1.0], atol=1e-7)
    x = np.linspace(0, 1, 101)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(x)), x, atol=1e-12)


# ---- USD ---------------------------------------------------------------------------------------
QUAD = """#usda 1.0
def Mesh "Quad" (prepend apiSchemas = ["MaterialBindingAPI"])
{{
    int[] faceVertexCounts = [4]
    int[] faceVertexIndices = [0, 1, 2, 3]
    point3f[] points = [(0,0,0), (1,0,0), (1,1,0), (0,1,0)]
    {uvs}
    rel material:binding = </Mat>
}}
def Material "Mat"
{{
    token outputs:surface.connect = </Mat/Surface.outputs:surface>
    def Shader "Surface"
    {{
        uniform token info:id = "UsdPreviewSurface"
        {surface}
        token outputs:surface
    }}
    def Shader "Reader"
    {{
        uniform token info:id = "UsdPrimvarReader_float2"
        token inputs:varname = "{varname}"
        float2 outputs:result
    }}
    def Shader "Tex"
    {{
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @{file}@
        float2 inputs:st.connect = </Mat/Reader.outputs:result>
        {tex}
        float3 outputs:rgb
        float outputs:r
        float outputs:g
        float outputs:a
    }}
}}
"""
UVS = 'texCoord2f[] primvars:st = [(0.125,0.125), (0.875,0.125), (0.875,0.875), (0.125,0.875)] (interpolation = "vertex")'
ROUGH = "float inputs:roughness.connect = </Mat/Tex.outputs:{channel}>"
DIFFUSE = "color3f inputs:diffuseColor.connect = </Mat/Tex.outputs:rgb>"
# a 2 x 2 RGBA PNG; row 0 = top
PIXELS = np.array([[[10, 20, 30, 40], [50, 60, 70, 80]], [[90, 100, 110, 120], [130, 140, 150, 160]]], np.uint8)


def _stage(tmp_path, surface, file="tex.png", varname="st", uvs=UVS, tex="", pixels=PIXELS, name="scene.usda"):
    if pixels is not None:
        Image.fromarray(pixels).save(tmp_path / "tex.png")
    path = tmp_path / name
    path.write_text(QUAD.format(uvs=uvs, surface=surface, varname=varname, file=file, tex=tex))
    return path


def test_usd_roughness_and_diffuse_textures(tmp_path):
    path = _stage(tmp_path, ROUGH.format(channel="g") + "\n" + DIFFUSE,
                  tex='token inputs:wrapS = "clamp"\ntoken inputs:wrapT = "mirror"\n'
                      "float4 inputs:scale = (2, 0.5, 1, 1)\nfloat4 inputs:bias = (0, 0.1, 0, 0)")
    mesh = load_usd(path).meshes[0]
    surface = mesh.surface
    assert set(surface.textures) == {"diffuse", "roughness"} and surface.uv_primvar == "st"
    rough, colour = surface.roughness, surface.diffuse
    assert rough.channels == 1 and colour.channels == 3 and rough.wrap_s == "clamp" and rough.wrap_t == "mirror"
    # roughness: raw (auto on a scalar input), channel g, scaled and biased
    np.testing.assert_allclose(rough.image[..., 0], PIXELS[..., 1] / 255.0 * 0.5 + 0.1, atol=ATOL_8BIT)
    # diffuse: 8-bit colour with sourceColorSpace auto -> sRGB-decoded, then scale/bias per channel
    expected = srgb_to_linear(PIXELS[..., :3] / 255.0) * [2.0, 0.5, 1.0] + [0.0, 0.1, 0.0]
    np.testing.assert_allclose(colour.image, expected, atol=ATOL_8BIT)
    # vertex (0.125, 0.125) uv lies beyond the bottom-left texel centre: clamped to it
    at = surface.at_vertices(mesh.uvs)
    np.testing.assert_allclose(at["roughness"][0], rough.image[1, 0, 0], atol=1e-7)
    np.testing.assert_allclose(mesh.albedo, np.clip(at["diffuse"], 0, 1), atol=1e-6)  # albedo sampled from the texture
    np.testing.assert_allclose(at["specular"], 0.04, atol=1e-12)  # metallic workflow, metallic 0


def test_usd_color_space_alpha_and_other_primvar(tmp_path):
    uvs = UVS.replace("primvars:st", "primvars:uvAlt") + "\n" + UVS.replace("0.125", "0.5").replace("0.875", "0.5")
    path = _stage(tmp_path, ROUGH.format(channel="a") + "\n" + DIFFUSE, varname="uvAlt", uvs=uvs,
                  tex='token inputs:sourceColorSpace = "raw"')
    mesh = load_usd(path).meshes[0]
    np.testing.assert_allclose(mesh.surface.diffuse.image, PIXELS[..., :3] / 255.0, atol=ATOL_8BIT)  # raw: no decode
    np.testing.assert_allclose(mesh.surface.roughness.image[..., 0], PIXELS[..., 3] / 255.0, atol=ATOL_8BIT)
    # the textures use uvAlt, which becomes Mesh.uvs (the default st is all 0.5)
    assert mesh.surface.uv_primvar == "uvAlt"
    np.testing.assert_allclose(mesh.uvs[2], [0.875, 0.875], atol=1e-7)
    # a grey image: r = g = b = grey, a = 1; sRGB forced on a scalar input decodes it
    grey = PIXELS[..., 0]
    mesh = load_usd(_stage(tmp_path, ROUGH.format(channel="a") + "\n" + DIFFUSE, pixels=grey, name="grey.usda")).meshes[0]
    np.testing.assert_allclose(mesh.surface.roughness.image, 1.0)
    np.testing.assert_allclose(mesh.surface.diffuse.image, np.repeat(srgb_to_linear(grey / 255.0)[..., None], 3, -1), atol=ATOL_8BIT)
    mesh = load_usd(_stage(tmp_path, ROUGH.format(channel="r"), pixels=grey, tex='token inputs:sourceColorSpace = "sRGB"',
                           name="srgb.usda")).meshes[0]
    np.testing.assert_allclose(mesh.surface.roughness.image[..., 0], srgb_to_linear(grey / 255.0), atol=ATOL_8BIT)


def test_usd_constants_only_give_constant_surface_maps(tmp_path):
    path = _stage(tmp_path, "float inputs:roughness = 0.25\ncolor3f inputs:specularColor = (0.5, 0.4, 0.3)\n"
                            "int inputs:useSpecularWorkflow = 1", pixels=None, file="unused.png")
    surface = load_usd(path).meshes[0].surface
    assert not surface.is_textured and surface.use_specular_workflow and surface.roughness == 0.25
    np.testing.assert_allclose(surface.at_vertices(None, 4)["specular"], np.tile([0.5, 0.4, 0.3], (4, 1)))
    np.testing.assert_allclose(surface.diffuse, 0.18)  # the spec's fallback


def _raises(path, *fragments):
    with pytest.raises(ValueError) as info:
        load_usd(path)
    message = str(info.value)
    for fragment in (str(path), "/Quad", "/Mat/Tex", *fragments):
        assert fragment in message, f"{fragment!r} not in {message!r}"


def test_usd_texture_errors_name_the_files(tmp_path):
    _raises(_stage(tmp_path, ROUGH.format(channel="r"), file="missing.png", name="missing.usda"), "missing.png", "not found")
    (tmp_path / "empty.png").write_bytes(b"")
    _raises(_stage(tmp_path, ROUGH.format(channel="r"), file="empty.png", name="empty.usda"), "empty.png", "empty (0 bytes)")
    (tmp_path / "junk.png").write_bytes(b"this is not a PNG file")
    _raises(_stage(tmp_path, ROUGH.format(channel="r"), file="junk.png", name="junk.usda"), "junk.png", "cannot be read")
    # wrong channel count: rgb into a scalar input, g from a one-channel image
    _raises(_stage(tmp_path, ROUGH.format(channel="rgb"), name="rgb.usda"), "roughness", "output rgb (3 channels)")
    _raises(_stage(tmp_path, ROUGH.format(channel="g"), pixels=PIXELS[..., 0], name="grey_g.usda"), "tex.png",
            "1 channel(s); output g needs 3 or 4")


def test_usd_texture_without_uvs_is_reported(tmp_path):
    _raises(_stage(tmp_path, ROUGH.format(channel="r"), uvs="", name="no_uvs.usda"), "tex.png", "primvar 'st'",
            "does not have")
    # an unconnected st falls back to the mesh's default UVs, which it lacks here
    text = QUAD.format(uvs="", surface=ROUGH.format(channel="r"), varname="st", file="tex.png", tex="")
    text = text.replace("float2 inputs:st.connect = </Mat/Reader.outputs:result>", "")
    (tmp_path / "unconnected.usda").write_text(text)
    _raises(tmp_path / "unconnected.usda", "tex.png", "mesh has no texture coordinates")

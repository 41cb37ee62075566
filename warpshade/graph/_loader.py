"""Stage graphs from TOML files: parsing and every check that needs no scene.

:func:`load` reads a graph file (the layout is in :mod:`warpshade.graph._spec`), checks its tables,
keys, value types and ranges, graph and stage names and frame selections, and returns a
:class:`~warpshade.graph._spec.GraphSpec` whose stage types, parameters and wiring are checked.
"""

from __future__ import annotations

import math
import re
import sys
from pathlib import Path

from ._errors import GraphError
from ._spec import GraphSpec, StageSpec

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = [
    "SCENE_OPTIONS",
    "check_frames_spec",
    "check_name",
    "usd_scene_kind",
]


_GRAPH_KEYS = {"name", "description", "scene", "frames", "output", "long_precompute"}
#: Scene options a ``[graph]`` table may carry (passed to :func:`warpshade.io.load_scene`, except
#: ``frame_count``) and their types.
SCENE_OPTIONS = {"ground_plane": bool, "sky": bool, "ground_resolution": int, "frame_count": int}
_TABLES = ("graph", "lighting", "validate", "stage", "material")
_LIGHTING_KEYS = ("source", "rotate_degrees_per_frame", "intensity", "color")
_VALIDATE_KEYS = ("frames", "samples")
#: Graph and stage names: they become file and cache-key names, so no separators, no "..".
NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,99}$")


def check_name(name, where: str) -> str:
    """A graph or stage name usable as a file name: letters, digits, ``_ . -``, at most 100,
    starting with a letter or digit, no ``..`` (nothing is ever written outside ``--out``).

    Raises:
        GraphError: naming ``where``.
    """
    if not isinstance(name, str) or not NAME_PATTERN.match(name) or ".." in name:
        raise GraphError(f"{where}: name {name!r} is not allowed: use letters, digits, '_', '.' and '-' "
                         "(at most 100, starting with a letter or digit, no '..'); it names the output files")
    return name


def _number(value, where: str, minimum: float | None = None, integer: bool = False):
    kind = "an integer" if integer else "a number"
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (integer and not isinstance(value, int)):
        raise GraphError(f"{where} must be {kind}, got {value!r}")
    if not math.isfinite(value):
        raise GraphError(f"{where} must be finite, got {value!r}")
    if minimum is not None and value < minimum:
        raise GraphError(f"{where} must be >= {minimum}, got {value!r}")
    return value


def check_frames_spec(spec, where: str):
    """Syntax of a frame selection (``"A:B"``, ``"A"``, a list of numbers): finite numbers only.

    Raises:
        GraphError: naming ``where``.
    """
    if spec is None:
        return None
    if isinstance(spec, (list, tuple)):
        if not spec:
            raise GraphError(f"{where}: the list of frames is empty")
        for f in spec:
            _number(f, f"{where}: frame")
        return list(spec)
    if not isinstance(spec, str):
        raise GraphError(f"{where} must be a range 'A:B', one time code or a list of numbers, got {spec!r}")
    parts = spec.split(":", 1) if ":" in spec else [spec]
    for part in parts:
        if not part.strip() and len(parts) == 2:
            continue
        try:
            value = float(part)
        except ValueError:
            raise GraphError(f"{where}: {part.strip()!r} in {spec!r} is not a number (expected 'A:B', 'A' or a list)") from None
        if not math.isfinite(value):
            raise GraphError(f"{where}: {spec!r} is not a finite time code")
    return spec


def _check_lighting_table(t, where: str) -> dict:
    if not isinstance(t, dict):
        raise GraphError(f"{where}: [lighting] must be a table")
    unknown = sorted(set(t) - set(_LIGHTING_KEYS))
    if unknown:
        raise GraphError(f"{where}: [lighting] has unknown key(s) {unknown}; known: {list(_LIGHTING_KEYS)}")
    if "source" in t and not isinstance(t["source"], str):
        raise GraphError(f"{where}: [lighting] source must be 'scene', 'sky', 'constant' or an image path, got {t['source']!r}")
    if "rotate_degrees_per_frame" in t:
        _number(t["rotate_degrees_per_frame"], f"{where}: [lighting] rotate_degrees_per_frame")
    if "intensity" in t:
        _number(t["intensity"], f"{where}: [lighting] intensity", minimum=0.0)
    if "color" in t:
        c = t["color"]
        if not isinstance(c, list) or len(c) != 3:
            raise GraphError(f"{where}: [lighting] color must be three numbers, got {c!r}")
        for x in c:
            _number(x, f"{where}: [lighting] color component", minimum=0.0)
    return t


def _check_validate_table(t, where: str) -> dict:
    from .._limits import MAX_RAYS_PER_VERTEX

    if not isinstance(t, dict):
        raise GraphError(f"{where}: [validate] must be a table")
    unknown = sorted(set(t) - set(_VALIDATE_KEYS))
    if unknown:
        raise GraphError(f"{where}: [validate] has unknown key(s) {unknown}; known: {list(_VALIDATE_KEYS)}")
    if "frames" in t:
        if not isinstance(t["frames"], list):
            raise GraphError(f"{where}: [validate] frames must be a list of time codes, got {t['frames']!r}")
        check_frames_spec(t["frames"], f"{where}: [validate] frames")
    if "samples" in t:
        n = _number(t["samples"], f"{where}: [validate] samples", minimum=4, integer=True)
        if n > MAX_RAYS_PER_VERTEX:
            raise GraphError(f"{where}: [validate] samples = {n} exceeds the limit of {MAX_RAYS_PER_VERTEX} rays per vertex")
    return t


def _check_material_tables(tables, where: str, base_dir) -> list:
    """The ``[[material]]`` track: a BRDF (the keys of :func:`warpshade.scene._materials.brdf_from_spec`)
    per frame range (``frames``, default every frame) for every mesh or the meshes ``prims``."""
    from ..scene._brdfs import brdf_from_spec

    if not isinstance(tables, list):
        raise GraphError(f"{where}: [[material]] must be an array of tables")
    out = []
    for i, t in enumerate(tables):
        at = f"{where}: [[material]] #{i + 1}"
        if not isinstance(t, dict):
            raise GraphError(f"{at} must be a table")
        frames = check_frames_spec(t.get("frames"), f"{at} frames")
        prims = t.get("prims")
        if prims is not None and (not isinstance(prims, list) or not all(isinstance(p, str) for p in prims) or not prims):
            raise GraphError(f"{at}: prims must be a non-empty list of mesh prim paths, got {prims!r}")
        try:
            brdf = brdf_from_spec({k: v for k, v in t.items() if k not in ("frames", "prims")}, at, base_dir)
        except ValueError as exc:
            raise GraphError(str(exc)) from None
        out.append({"frames": frames, "prims": prims, "brdf": brdf, "where": at})
    return out


def _check_scene_options(options: dict, where: str) -> dict:
    from .._limits import MAX_TIME_CODES

    for key, value in options.items():
        if key not in SCENE_OPTIONS:
            raise GraphError(f"{where}: [graph] has unknown key {key!r}; known: {sorted(_GRAPH_KEYS | set(SCENE_OPTIONS))}")
        want = SCENE_OPTIONS[key]
        if want is bool and not isinstance(value, bool):
            raise GraphError(f"{where}: [graph] {key} must be true or false, got {value!r}")
        if want is int:
            _number(value, f"{where}: [graph] {key}", minimum=1 if key == "frame_count" else 2, integer=True)
    if options.get("frame_count", 1) > MAX_TIME_CODES:
        raise GraphError(f"{where}: [graph] frame_count = {options['frame_count']} exceeds the limit of {MAX_TIME_CODES} "
                         "time codes a run may step through")
    return options


#: How USD files begin: text (usda), binary (usdc) and zipped (usdz) layers.
_USD_MAGIC = ((b"#usda", "a text USD layer"), (b"PXR-USDC", "a binary USD layer"), (b"PK\x03\x04", "a USDZ package"))


def usd_scene_kind(path, head: bytes | None = None) -> str | None:
    """What USD scene ``path`` is (``"a text USD layer"``, ...), or None when it is none: told by
    its first bytes (``head``, else read), or by its suffix when it cannot be read (a ``.usdz``
    is only a USD package by its suffix, a zip otherwise)."""
    from ..io._scene_specs import USD_SUFFIXES

    suffix = Path(path).suffix.lower()
    if head is None:
        try:
            with open(path, "rb") as f:
                head = f.read(8)
        except OSError:
            return "a USD file" if suffix in USD_SUFFIXES else None
    for magic, kind in _USD_MAGIC:
        if head.startswith(magic) and (magic != b"PK\x03\x04" or suffix == ".usdz"):
            return kind
    return None


def load(path) -> GraphSpec:
    """Load a stage graph from a TOML file (see module docstring for the layout).

    Everything that can be checked without the scene is checked here: the file (a USD scene given
    as a graph is named as such), TOML syntax,
    the tables and their keys, the types and ranges of values, graph and stage names, frame
    selections, stage types, parameters and wiring (:meth:`GraphSpec.check`).

    Raises:
        GraphError: naming the file and the table or key at fault.
    """
    path = Path(path)
    if not path.exists():
        raise GraphError(f"stage graph file {path} does not exist")
    if path.is_dir():
        raise GraphError(f"stage graph file {path} is a directory, not a TOML file")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise GraphError(f"stage graph file {path}: cannot be read ({exc.strerror or exc})") from None
    usd = usd_scene_kind(path, data[:8])
    if usd is not None:
        raise GraphError(f"stage graph file {path}: is a USD scene ({usd}), not a stage graph (TOML); a graph names "
                         f"it as its scene (scene = \"{path}\" in [graph], or warpshade run GRAPH --scene {path})")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise GraphError(f"stage graph file {path}: is not a text (UTF-8 TOML) file") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise GraphError(f"stage graph file {path}: invalid TOML: {exc}") from None
    where = f"stage graph file {path}"
    unknown = sorted(set(doc) - set(_TABLES))
    if unknown:
        raise GraphError(f"{where}: unknown table(s) {unknown}; known: {list(_TABLES)}")
    g = doc.get("graph")
    if not isinstance(g, dict):
        raise GraphError(f"{where}: missing [graph] table")
    if "output" not in g:
        raise GraphError(f"{where}: [graph] needs an 'output = \"stage.port\"' entry")
    for key in ("output", "description", "scene", "long_precompute"):
        if key in g and not isinstance(g[key], str):
            raise GraphError(f"{where}: [graph] {key} must be a string, got {g[key]!r}")
    default_name = re.sub(r"[^A-Za-z0-9_.-]", "_", path.stem).strip("._-") or "graph"
    name = check_name(g.get("name", default_name), f"{where}: [graph]")
    frames = check_frames_spec(g.get("frames"), f"{where}: [graph] frames")
    scene_options = _check_scene_options({k: v for k, v in g.items() if k not in _GRAPH_KEYS}, where)
    raw_stages = doc.get("stage", [])
    if not isinstance(raw_stages, list) or not raw_stages:
        raise GraphError(f"{where}: needs at least one [[stage]] table")
    stages = []
    for i, st in enumerate(raw_stages):
        if not isinstance(st, dict) or "name" not in st or "type" not in st:
            raise GraphError(f"{where}: [[stage]] #{i + 1} needs 'name' and 'type'")
        check_name(st["name"], f"{where}: [[stage]] #{i + 1}")
        if not isinstance(st["type"], str):
            raise GraphError(f"{where}: stage {st['name']!r}: 'type' must be a string, got {st['type']!r}")
        params = {k: v for k, v in st.items() if k not in ("name", "type", "inputs")}
        inputs = st.get("inputs", {})
        if not isinstance(inputs, dict) or not all(isinstance(v, str) for v in inputs.values()):
            raise GraphError(f"{where}: stage {st['name']!r}: 'inputs' must be a table of \"stage.port\" strings")
        stages.append(StageSpec(st["name"], st["type"], params, inputs))
    lighting = _check_lighting_table(doc.get("lighting", {}), where)
    validate = _check_validate_table(doc.get("validate", {}), where)
    material_track = _check_material_tables(doc.get("material", []), where, path.resolve().parent)
    spec = GraphSpec(
        stages=stages,
        output=g["output"],
        name=name,
        description=g.get("description", ""),
        long_precompute=g.get("long_precompute", ""),
        scene=g.get("scene"),
        scene_options=scene_options,
        frames=frames,
        lighting=lighting,
        validate_spec=validate,
        source_path=path.resolve(),
        materials=material_track,
    )
    spec.check()  # stage types, parameters, wiring: before any scene is loaded
    return spec

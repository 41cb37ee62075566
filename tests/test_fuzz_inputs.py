"""Property-based tests of the three loaders a user's files go through: stage-graph TOML, USD
scenes and the artifact cache. Every generated input ends in success or a clear error (the
documented exception type, with a message), never another exception, a crash or wrong data.
"""

import json
import math
import re
import string
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from warpshade.graph import GraphError, load, stage_types
from warpshade.graph import ArtifactCache
from warpshade.io import bundled_asset_directory, load_usd

ASSETS = Path(bundled_asset_directory())
FIGURE = (ASSETS / "figure.usda").read_text()
#: hypothesis budgets: each example is a file written and loaded (USD loads take ~50 ms).
TOML_EXAMPLES = 150
USD_EXAMPLES = 60
CACHE_EXAMPLES = 100
def fuzz(examples: int):
    """Deterministic examples (the same in CI as here), no example database, no deadline."""
    return settings(max_examples=examples, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


# ---- a TOML writer for generated documents ---------------------------------------------------------
def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v == math.inf else "-inf" if v == -math.inf else repr(v))
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{json.dumps(k, ensure_ascii=False)} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(v)


def _toml(doc: dict) -> str:
    lines = []
    for table, body in doc.items():
        if table == "stage":
            for st_ in body:
                lines.append("[[stage]]")
                lines += [f"{json.dumps(k, ensure_ascii=False)} = {_toml_value(v)}" for k, v in st_.items()]
        else:
            lines.append(f"[{json.dumps(table, ensure_ascii=False)}]")
            lines += [f"{json.dumps(k, ensure_ascii=False)} = {_toml_value(v)}" for k, v in body.items()]
    return "\n".join(lines) + "\n"


TYPES = sorted(stage_types())
PARAMS = sorted({p for cls in stage_types().values() for p in cls.parameters})
text = st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=12)


def mostly(good, bad, goods: int = 8):
    """Mostly ``good`` values (so generated graphs get past the first checks), sometimes ``bad``."""
    return st.one_of(*([good] * goods), bad)


scalars = st.one_of(
    st.booleans(), st.integers(min_value=-10**12, max_value=10**12), st.floats(allow_nan=True, allow_infinity=True),
    text, st.sampled_from(["", ".", "..", "/etc/x", "0:10", "scene", "hyb", "cosine"]),
)
values = st.one_of(scalars, scalars, st.lists(scalars, max_size=4), st.dictionaries(text, scalars, max_size=3))
names = mostly(st.sampled_from(["a", "shade", "g", "bake"]), text)


def _stage(base):
    cls = stage_types().get(base["type"])
    keys = st.sampled_from(sorted(cls.parameters)) if cls and cls.parameters else st.sampled_from(PARAMS)
    good = st.dictionaries(keys, st.one_of(st.integers(1, 8), st.floats(0.0, 4.0), st.booleans(), st.sampled_from(
        ["hyb", "table", "cosine", "microfacet", None] if False else ["hyb", "table", "cosine", "microfacet"])), max_size=3)
    return mostly(good, st.dictionaries(mostly(keys, text), values, max_size=4)).map(lambda extra: {**extra, **base})


inputs = mostly(st.dictionaries(st.sampled_from(["transfer", "points", "x"]),
                                st.sampled_from(["bake.transfer", "scene.points", "nope"]), max_size=1), values, goods=3)
stage = st.fixed_dictionaries(
    {"name": names, "type": mostly(st.sampled_from(TYPES), text)}, optional={"inputs": inputs}).flatmap(_stage)
#: A stage that can provide the output "shade.radiance" on its own (no inputs but the scene's).
SHADE_TYPES = ["prt.unshadowed", "prt.trace"]
shade_stage = st.fixed_dictionaries({"name": st.just("shade"), "type": st.sampled_from(SHADE_TYPES)}).flatmap(_stage)
stages = st.tuples(mostly(shade_stage, stage), st.lists(stage, max_size=2)).map(lambda t: [t[0], *t[1]])
graph_table = st.fixed_dictionaries(
    {"output": mostly(st.just("shade.radiance"), st.sampled_from(["x", "a.b", "", "bake.transfer"]))},
    optional={"name": names, "scene": mostly(st.sampled_from(["bundled:figure", "x.usda"]), text), "frames": mostly(st.sampled_from(["0:4", "2", "1:"]), values),
              "description": mostly(text, values), "frame_count": mostly(st.integers(1, 10), values),
              "ground_plane": mostly(st.booleans(), values)}).flatmap(
    lambda g: mostly(st.just(g), st.dictionaries(text, values, min_size=1, max_size=2).map(lambda junk: {**g, **junk})))
lighting = st.fixed_dictionaries({}, optional={
    "source": mostly(st.sampled_from(["scene", "sky", "constant"]), values),
    "intensity": mostly(st.floats(0, 10), values), "rotate_degrees_per_frame": mostly(st.floats(-90, 90), values),
    "color": mostly(st.lists(st.floats(0, 2), min_size=3, max_size=3), values)})
validate = st.fixed_dictionaries({}, optional={
    "frames": mostly(st.lists(st.integers(0, 3), min_size=1, max_size=3), values),
    "samples": mostly(st.integers(4, 4096), values)})
documents = st.fixed_dictionaries(
    {"graph": graph_table, "stage": stages},
    optional={"lighting": lighting, "validate": validate}).flatmap(
    lambda d: mostly(st.just(d), st.dictionaries(text, st.dictionaries(text, scalars, max_size=2), min_size=1, max_size=1)
                     .map(lambda other: {**d, **other})))


@fuzz(TOML_EXAMPLES)
@given(doc=documents)
def test_generated_stage_graphs_load_or_name_the_problem(tmp_path_factory, doc):
    path = tmp_path_factory.mktemp("toml") / "g.toml"
    path.write_text(_toml(doc))
    try:
        spec = load(path)
    except GraphError as exc:
        assert str(exc) and "\n" not in str(exc).strip()[:200]
        return
    assert spec.name and spec.stages
    try:
        spec.build({"V": 8, "T": 2, "F": 12})
    except GraphError as exc:
        assert str(exc)


@fuzz(60)
@given(data=st.one_of(st.binary(max_size=300), st.text(max_size=300)))
def test_arbitrary_bytes_as_a_stage_graph_are_named(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("raw") / "g.toml"
    if isinstance(data, str):
        path.write_text(data)
    else:
        path.write_bytes(data)
    with pytest.raises(GraphError, match=re.escape(str(path))):
        load(path)


# ---- USD: random corruptions of a small generated scene -------------------------------------------
_NUMBER = re.compile(r"-?\d+(\.\d+)?(e-?\d+)?")
#: Replacements of a number: other values (mostly still valid USD) and, less often, broken syntax.
numbers = st.sampled_from(["0", "-1", "1e30", "-0.0", "3", "1e-30", "2", "12", "-7", "0.5", "nan", "inf", "-inf"])
junk = st.one_of(numbers, numbers, numbers, st.sampled_from(["1e309", "-", "abc", "99999999999999999999", "()", "[", '"', ""]))


@st.composite
def corrupted_figure(draw):
    lines = FIGURE.splitlines()
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["number", "number", "number", "number", "delete", "duplicate", "truncate", "swap", "bytes"]))
        i = draw(st.integers(0, len(lines) - 1))
        if kind == "delete":
            del lines[i]
        elif kind == "duplicate":
            lines.insert(i, lines[i])
        elif kind == "swap":
            j = draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
        elif kind == "number":
            hits = list(_NUMBER.finditer(lines[i]))
            if hits:
                m = hits[draw(st.integers(0, len(hits) - 1))]
                lines[i] = lines[i][: m.start()] + draw(junk) + lines[i][m.end():]
        elif kind == "truncate":
            lines = lines[:i]
        else:
            text = lines[i]
            k = draw(st.integers(0, max(len(text) - 1, 0)))
            lines[i] = text[:k] + draw(st.text(alphabet="(){}[]<>@\"'=,;#\x00\x7f", min_size=1, max_size=3)) + text[k + 1:]
        if not lines:
            break
    return "\n".join(lines) + "\n"


@fuzz(USD_EXAMPLES)
@given(text=corrupted_figure())
def test_corrupted_usd_scenes_load_or_name_the_problem(tmp_path_factory, text):
    folder = tmp_path_factory.mktemp("usd")
    (folder / "sky.hdr").write_bytes((ASSETS / "sky.hdr").read_bytes())  # the dome's texture
    path = folder / "figure.usda"
    path.write_text(text, errors="replace")
    try:
        scene = load_usd(path)
    except (ValueError, FileNotFoundError) as exc:
        assert str(exc)
        return
    state = scene.evaluate(scene.frames[0], device="cpu")
    assert np.all(np.isfinite(state.points.numpy())) and np.all(np.isfinite(state.normals.numpy()))


# ---- the artifact cache: random corruptions of a valid entry --------------------------------------
ARRAYS = {"a": np.arange(64, dtype=np.float32).reshape(16, 4), "b": np.array([1, 2, 3], np.int32), "c": np.array("text")}


@fuzz(CACHE_EXAMPLES)
@given(data=st.data())
def test_corrupted_cache_entries_are_misses_never_errors_or_wrong_data(tmp_path_factory, data):
    root = tmp_path_factory.mktemp("cache")
    cache = ArtifactCache(root)
    path = cache.store("k", ARRAYS)
    original = path.read_bytes()
    raw = bytearray(original)
    kind = data.draw(st.sampled_from(["truncate", "flip", "insert", "replace", "empty"]))
    if kind == "truncate":
        raw = raw[: data.draw(st.integers(0, len(raw) - 1))]
    elif kind == "flip":
        for _ in range(data.draw(st.integers(1, 4))):
            raw[data.draw(st.integers(0, len(raw) - 1))] ^= data.draw(st.integers(1, 255))
    elif kind == "insert":
        at = data.draw(st.integers(0, len(raw)))
        raw[at:at] = data.draw(st.binary(min_size=1, max_size=16))
    elif kind == "replace":
        raw = bytearray(data.draw(st.binary(max_size=400)))
    else:
        raw = bytearray()
    path.write_bytes(bytes(raw))
    out = ArtifactCache(root).load("k")
    if bytes(raw) == original:  # e.g. the same byte flipped twice
        assert out is not None and all(np.array_equal(out[k], v) for k, v in ARRAYS.items())
        return
    assert out is None, "a changed entry is never returned"
    assert not path.exists(), "a damaged entry is removed"

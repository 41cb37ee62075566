"""Precompute stages: run once per scene and parameters, cached on disk, checked on every load.

:func:`precompute` runs the graph's precompute stages in order. Each artifact is keyed by a
content hash of the stage type and version, its cache parameters and :meth:`cache_key`, the keys
of its input artifacts and, when it reads the scene, the scene's fingerprint; a cached artifact
is used when it has the declared ports (:func:`artifact_problem`) and passes the stage's
:meth:`~warpshade.methods.stage.PrecomputeStage.check_artifact`, else it is recomputed and the
reason kept (``stale``).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field

import numpy as np

from .._fileio import _json_default
from .._hashing import hash_json
from ..methods.stage import Port, StageError
from ._errors import GraphError

__all__ = ["Precomputed", "StageTiming", "artifact_problem", "precompute"]


@dataclass
class StageTiming:
    precompute_s: float = 0.0
    cache: str = ""  # "hit" | "miss" | "off" for precompute stages
    frame_s: list = field(default_factory=list)  # per-frame stages: from profile()


_REPORT_KEY = "__report__"


def _flatten(out: dict, ports: dict) -> dict:
    """Artifacts as one flat name -> array dict ("arrays" ports become ``port/key`` entries)."""
    flat = {}
    for name, value in out.items():
        if name in ports and ports[name].dtype == "arrays":
            flat.update({f"{name}/{k}": np.asarray(v) for k, v in value.items()})
        else:
            flat[name] = value
    return flat


def _unflatten(flat: dict, ports: dict) -> dict:
    """Inverse of :func:`_flatten`."""
    out: dict = {n: {} for n, p in ports.items() if p.dtype == "arrays"}
    for key, value in flat.items():
        head, _, tail = key.partition("/")
        if tail and head in out:
            out[head][tail] = value
        else:
            out[key] = value
    return out



#: NumPy dtype kind and trailing element shape of the artifact of each array port dtype.
_ARTIFACT_LAYOUT = {"float32": ("f", ()), "float64": ("f", ()), "int32": ("iu", ()), "vec3": ("f", (3,)), "mat33": ("f", (3, 3))}


def artifact_problem(port: Port, value, dims: dict) -> str | None:
    """Why ``value`` is not a valid artifact of ``port`` (None when it is).

    Checks the dtype kind, the shape against the port's (symbols resolved with ``dims``; vec3 and
    mat33 ports hold trailing 3 / 3x3 float axes) and, for floats, that every value is finite.
    An "arrays" port needs a dict of numeric arrays with finite floats.
    """
    if port.dtype == "arrays":
        if not isinstance(value, dict):
            return "is not a set of named arrays"
        for k, v in value.items():
            a = np.asarray(v)
            if a.dtype.kind == "O":
                return f"entry {k!r} holds Python objects"
            if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
                return f"entry {k!r} has NaN or infinite values"
        return None
    if port.dtype not in _ARTIFACT_LAYOUT:
        return None
    kinds, inner = _ARTIFACT_LAYOUT[port.dtype]
    a = np.asarray(value)
    if a.dtype.kind not in kinds:
        return f"has dtype {a.dtype}, the port is {port.dtype}"
    want = tuple(dims.get(d, d) if isinstance(d, str) else int(d) for d in port.shape)
    shape = a.shape
    if inner:
        flat = (int(np.prod(inner)),)
        if shape[len(want):] == flat:
            shape = shape[: len(want)] + inner
        if shape[len(want):] != inner:
            return f"has shape {a.shape}, the port is {port.dtype} of shape {want}"
        shape = shape[: len(want)]
    if len(shape) != len(want) or any(isinstance(w, int) and w != s for w, s in zip(want, shape)):
        return f"has shape {a.shape}, the port needs {want}"
    if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
        return f"has {int(np.count_nonzero(~np.isfinite(a)))} NaN or infinite values"
    return None



@dataclass
class Precomputed:
    """What the precompute stages left.

    Attributes:
        artifacts: stage name -> output name -> NumPy array (or a dict for "arrays" ports).
        keys: stage name -> cache key of its artifact.
        stale: cached artifacts that were rejected (and recomputed), ``"stage: reason"``.
    """

    artifacts: dict = field(default_factory=dict)
    keys: dict = field(default_factory=dict)
    stale: list = field(default_factory=list)


def precompute(stages, wiring, ctx, cache, fingerprint, timings) -> Precomputed:
    """Run (or load from ``cache``) every precompute stage of ``stages``, in order.

    Args:
        stages: the graph's stages in order; wiring: stage name -> {input port: Wire}.
        ctx: the :class:`~warpshade.methods.stage.StageContext` (no state yet).
        cache: the :class:`~warpshade.graph._cache.ArtifactCache`.
        fingerprint: a callable returning the scene's fingerprint (called only when a stage
            reads the scene).
        timings: stage name -> :class:`StageTiming`, filled in.

    Raises:
        GraphError: a stage's cache key cannot be made or its precompute left an invalid artifact.
    """
    done = Precomputed()
    for st in stages:
        if st.kind != "precompute":
            continue
        wires = wiring[st.name]
        inputs = {port: _host_input(ctx.scene, done.artifacts, w) for port, w in wires.items()}
        key = _artifact_key(st, wires, ctx, done.keys, fingerprint)
        done.keys[st.name] = key
        t0 = time.perf_counter()
        damaged_before = len(cache.damaged)
        cached = cache.load(key)
        for path, why in cache.damaged[damaged_before:]:
            done.stale.append(f"{st.name}: cache entry {path} {why}")
        timing = timings[st.name]
        ports = st.output_ports()
        out = _valid_cached(st, key, cached, ports, ctx.dims, cache, done.stale)
        if out is not None:
            timing.cache = "hit"
            if _REPORT_KEY in out:
                st.report = json.loads(str(out.pop(_REPORT_KEY)))
        else:
            out = st.precompute(ctx, inputs)
            problems = _artifact_problems(st, out, ports, ctx.dims)
            if problems:
                raise GraphError(f"stage {st.name!r} ({st.type_name}): its precompute produced an invalid artifact: "
                                 + "; ".join(problems))
            timing.cache = "miss" if cache.enabled else "off"
            stored = _flatten(out, ports)
            if st.report:
                stored[_REPORT_KEY] = np.array(json.dumps(st.report, default=_json_default))
            cache.store(key, stored)
        timing.precompute_s = time.perf_counter() - t0
        done.artifacts[st.name] = out
    return done


def _host_input(scene, artifacts: dict, wire):
    if wire.provider == "scene":
        if wire.port == "albedo":
            return scene.albedo
        raise GraphError(f"scene port {wire.port!r} is per-frame")
    return artifacts[wire.provider][wire.port]


def _artifact_key(st, wires: dict, ctx, keys: dict, fingerprint) -> str:
    """The cache key of ``st``'s artifact (see the module docstring)."""
    key_parts = {
        "type": st.type_name,
        "version": st.version,
        "params": st.cache_params(),
        "inputs": {
            p: (keys[w.provider] + "." + w.port) if w.provider != "scene" else f"scene.{w.port}"
            for p, w in wires.items()
        },
    }
    if st.uses_scene or any(w.provider == "scene" for w in wires.values()):
        key_parts["scene"] = fingerprint()
    try:
        extra = st.cache_key(ctx)
    except StageError:
        raise
    except (OSError, ValueError) as exc:
        raise GraphError(f"stage {st.name!r} ({st.type_name}): {exc}") from None
    if extra:
        key_parts["depends"] = extra
    return f"{st.type_name.replace('.', '-')}-{hash_json(key_parts)[:32]}"


def _artifact_problems(st, out: dict, ports: dict, scene_dims: dict) -> list[str]:
    dims = {**scene_dims, **st.dims()}
    problems = []
    for name, port in ports.items():
        if name not in out:
            problems.append(f"output {name!r} is missing")
            continue
        why = artifact_problem(port, out[name], dims)
        if why:
            problems.append(f"output {name!r} {why}")
    return problems


def _valid_cached(st, key, cached, ports, scene_dims, cache, stale: list):
    """The cached artifact of ``st`` when it matches the stage's ports and passes its check;
    else None, the entry is removed and the reason appended to ``stale``."""
    if cached is None:
        return None
    out = _unflatten(cached, ports)
    problems = _artifact_problems(st, out, ports, scene_dims)
    if not problems:
        try:
            st.check_artifact({k: v for k, v in out.items() if k in ports})
        except (ValueError, KeyError) as exc:
            problems = [str(exc)]
    if problems:
        reason = "; ".join(problems)
        stale.append(f"{st.name}: {reason}")
        cache.discard(key, f"stage {st.name!r}: {reason}")
        return None
    return out

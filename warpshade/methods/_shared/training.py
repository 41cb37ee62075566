"""The training clip of the data-driven methods (:mod:`warpshade.methods.datadriven`,
:mod:`warpshade.methods.visibility`): the stage parameter that names it
(:class:`TrainingClipStage`), the frames it selects (:func:`parse_frame_selection`), the check
that it holds the graph's character (:func:`check_same_character`), the pose columns a fit reads
(:func:`pose_columns`), and its ray-traced training data at every training pose
(:func:`trace_training`).

Each training frame is an independent job (ray tracing every vertex of one pose), so the frames
are split into tasks of a few frames and run by an executor (:mod:`warpshade.tasks`): in this
process, in local worker processes, or on a Dask cluster. A task carries the scene itself
(pickled, without its device caches), its frames and their seeds, so every back end returns
exactly what the serial loop returns.

Seeds: frame ``i`` of the clip traces with seed ``frame_seed(seed, i)``: the per-vertex sample
rotations differ from pose to pose, so the Monte Carlo noise of the training transfer is
independent across poses and the least-squares fit averages it down (a fixed seed would give
every pose the same noise pattern, which the bias term would then learn).

Quantity: ``"transfer"`` (the diffuse transfer, with or without bounces: the training data of the
data-driven transfer model) or ``"visibility"`` (SH of the binary visibility alone, no cosine, directions below the
tangent plane counted open as in :mod:`warpshade.methods.rpo`: the training data of the
data-driven visibility model, :mod:`warpshade.methods.visibility`).

Resuming: given a cache, each task's transfer is stored there as soon as the task finishes,
under a key of everything that determines it (:func:`task_key`), so that a run interrupted
(Ctrl-C, a failing task, a killed process) traces only the tasks it had not finished when run
again. Entries are checked when read (the cache's digest, then shape, dtype and finite values)
and traced again when they fail; they are removed once the whole training set is assembled.
"""

from __future__ import annotations

import contextlib
import hashlib

import numpy as np

from ..._hashing import hash_json
from ..stage import Param, PrecomputeStage, StageError

__all__ = ["FRAMES_PER_TASK", "TrainingClipStage", "check_same_character", "frame_seed", "parse_frame_selection",
           "pose_columns", "topology_key", "trace_task", "trace_training"]

#: Frames per task: enough work per task (seconds) to hide the task overhead, few enough for
#: load balance and for a killed worker to lose little.
FRAMES_PER_TASK = 4
#: Bumped when the transfer a task traces changes (:func:`trace_task` or the ray tracer it calls),
#: so that the cached tasks of an interrupted run of an older version are not reused.
TASK_VERSION = 1


def frame_seed(seed: int, index: int) -> int:
    """The ray seed of training frame ``index`` (distinct per frame, fixed per ``seed``)."""
    return int((int(seed) * 1_000_003 + 7919 * int(index) + 1) % (2 ** 31 - 1))


def topology_key(scene) -> np.ndarray:
    """What a model trained on one clip needs of another: vertex count and order, faces, skin
    weights, skeleton joints, rest and bind transforms. 4 int64 words of a SHA-256."""
    h = hashlib.sha256()
    h.update(np.int64(scene.vertex_count).tobytes())
    h.update(np.ascontiguousarray(scene.faces, np.int64).tobytes())
    for mesh in scene.meshes:
        h.update(mesh.animation.encode())
        if mesh.skin is not None:
            h.update(np.ascontiguousarray(mesh.skin.joint_indices, np.int64).tobytes())
            h.update(np.round(np.asarray(mesh.skin.joint_weights, np.float64), 5).tobytes())
    for skel in scene.skeletons:
        h.update("|".join(skel.joint_names).encode())
        h.update(np.asarray(skel.parents, np.int64).tobytes())
        h.update(np.round(np.asarray(skel.bind_transforms, np.float64), 5).tobytes())
        h.update(np.round(np.asarray(skel.rest_transforms, np.float64), 5).tobytes())
    return np.frombuffer(h.digest(), dtype=np.int64).copy()


def check_same_character(train, test, where: str) -> None:
    """Raise ValueError naming both scenes when ``test`` is not the character ``train`` holds."""
    def name(s):
        return s.source or "<arrays>"

    if train.vertex_count != test.vertex_count:
        raise ValueError(f"{where}: training scene {name(train)} has {train.vertex_count} vertices, "
                         f"{name(test)} has {test.vertex_count}: a model applies to the same character only")
    if [s.joint_names for s in train.skeletons] != [s.joint_names for s in test.skeletons]:
        raise ValueError(f"{where}: the skeletons of {name(train)} and {name(test)} have different joints")
    if not np.array_equal(topology_key(train), topology_key(test)):
        raise ValueError(f"{where}: {name(train)} and {name(test)} differ in faces, skin weights, rest or bind "
                         "transforms: a model applies to the same character only")


def parse_frame_selection(spec, scene, where: str) -> np.ndarray:
    """Frame indices of ``scene`` selected by ``spec``: None (all), ``"start:stop[:step]"`` over
    frame indices, or a list of time codes."""
    count = len(scene.frames)
    if spec is None or spec == "":
        return np.arange(count)
    if isinstance(spec, str):
        parts = spec.split(":")
        try:
            if len(parts) not in (2, 3):
                raise ValueError
            nums = [int(p) if p.strip() else None for p in parts]
        except ValueError:
            raise ValueError(f"{where}: frames {spec!r} must be 'start:stop[:step]' over frame indices") from None
        idx = np.arange(count)[slice(*nums)]
    else:
        idx = np.asarray([scene.frame_index(float(f)) for f in spec], np.int64)
    if idx.size == 0:
        raise ValueError(f"{where}: frames {spec!r} select none of the {count} frames")
    return idx


#: What a task traces (:func:`trace_task`).
QUANTITIES = ("transfer", "visibility")


def trace_task(task: dict) -> np.ndarray:
    """Transfer of the task's frames: (frames, V, C) for the direct transfer, (frames, V, 3 * C)
    with bounces (channel-major per vertex: ``[r coefficients, g ..., b ...]``), float32; or, with
    ``task["quantity"] == "visibility"``, the SH visibility (frames, V, C), open below the horizon."""
    from ...transfer import compute

    scene = task["scene"]
    out = []
    quantity = task.get("quantity", "transfer")
    for index, seed in zip(task["frame_indices"], task["seeds"]):
        frame = float(scene.frames[int(index)])
        if quantity == "visibility":
            res = compute(scene, frame, task["order"], task["samples"], space=task["space"], seed=int(seed),
                          below_horizon="visible")
            out.append(np.asarray(res.visibility, np.float32))
            continue
        res = compute(scene, frame, task["order"], task["samples"], space=task["space"], seed=int(seed),
                      bounces=task["bounces"]) if task["bounces"] else \
            compute(scene, frame, task["order"], task["samples"], space=task["space"], seed=int(seed))
        if task["bounces"]:
            out.append(np.asarray(res.transfer_rgb, np.float32).reshape(scene.vertex_count, -1))
        else:
            out.append(np.asarray(res.transfer, np.float32))
    return np.stack(out)


def task_key(scene_fingerprint: str, task: dict) -> str:
    """The cache key of one task's transfer: the training scene's content, the task's frames and
    their seeds, order, samples, bounces, space, the quantity (when not the transfer) and
    :data:`TASK_VERSION`."""
    key = {"scene": scene_fingerprint, "frame_indices": [int(i) for i in task["frame_indices"]],
           "seeds": [int(s) for s in task["seeds"]], "order": task["order"], "samples": task["samples"],
           "space": task["space"], "bounces": task["bounces"], "version": TASK_VERSION}
    if task.get("quantity", "transfer") != "transfer":
        key["quantity"] = task["quantity"]
    return "datadriven-task-" + hash_json(key)[:32]


def _cached_transfer(cache, key: str, task: dict, vertex_count: int) -> np.ndarray | None:
    """The transfer of ``task`` kept under ``key``, or None when missing or not a valid result
    (the cache removes entries that fail its digest; a wrong shape, dtype or a non-finite value
    is traced again and overwritten)."""
    hit = cache.load(key)
    if hit is None or set(hit) != {"transfer"}:
        return None
    transfer = hit["transfer"]
    coefficients = task["order"] ** 2 * (3 if task["bounces"] else 1)
    if (transfer.dtype != np.float32 or transfer.shape != (len(task["frame_indices"]), vertex_count, coefficients)
            or not np.isfinite(transfer).all()):
        return None
    return transfer


def trace_training(scene, frame_indices, order: int, samples: int, seed: int = 0, bounces: int = 0,
                   space: str = "world", executor=None, progress: bool = False, cache=None,
                   report: dict | None = None, quantity: str = "transfer") -> np.ndarray:
    """Training transfer at ``frame_indices`` of ``scene``, (p, V, C or 3C) float32.

    Args:
        quantity: ``"transfer"`` or ``"visibility"`` (:data:`QUANTITIES`; visibility has no bounces).
        executor: a :class:`warpshade.tasks.Executor` (default: :func:`warpshade.tasks.executor`,
            closed afterwards).
        cache: where each finished task's transfer is kept until all are assembled (an
            :class:`~warpshade.graph._cache.ArtifactCache`: ``load``, ``store``, ``path``), so that
            an interrupted call resumes: tasks found there are not traced again. None: no cache.
        report: a dict that receives ``tasks`` and ``tasks_cached`` (found in ``cache``).

    Raises:
        TaskError: a task failed (the message names its training frames).
    """
    from ...tasks import TaskError, executor as new_executor

    if quantity not in QUANTITIES or (quantity == "visibility" and bounces):
        raise ValueError(f"trace_training: quantity must be one of {QUANTITIES} (visibility without bounces), "
                         f"got {quantity!r} with bounces={bounces}")
    frame_indices = np.asarray(frame_indices, np.int64)
    seeds = [frame_seed(seed, i) for i in frame_indices]
    tasks = []
    for lo in range(0, len(frame_indices), FRAMES_PER_TASK):
        tasks.append({"scene": scene, "frame_indices": frame_indices[lo:lo + FRAMES_PER_TASK].tolist(),
                      "seeds": seeds[lo:lo + FRAMES_PER_TASK], "order": int(order), "samples": int(samples),
                      "space": space, "bounces": int(bounces), "quantity": quantity})
    if cache is not None and not getattr(cache, "enabled", True):
        cache = None
    keys, parts = [], [None] * len(tasks)
    if cache is not None:
        fingerprint = scene.fingerprint()
        keys = [task_key(fingerprint, t) for t in tasks]
        parts = [_cached_transfer(cache, key, t, scene.vertex_count) for key, t in zip(keys, tasks)]
    missing = [i for i, part in enumerate(parts) if part is None]
    cached = len(tasks) - len(missing)
    if report is not None:
        report.update(tasks=len(tasks), tasks_cached=cached)
    desc = f"training {quantity} ({len(frame_indices)} frames" + (f", {cached} of {len(tasks)} tasks from an "
                                                               "interrupted run)" if cached else ")")

    def keep(j: int, transfer) -> None:
        cache.store(keys[missing[j]], {"transfer": transfer})

    own = executor is None and bool(missing)
    ex = new_executor() if own else executor
    try:
        if missing:
            done = ex.map(trace_task, [tasks[i] for i in missing], desc=desc, progress=progress,
                          on_result=keep if cache is not None else None)
            for i, transfer in zip(missing, done):
                parts[i] = transfer
    except TaskError as exc:
        if exc.index is None:
            raise
        frames = tasks[missing[exc.index]]["frame_indices"]
        raise TaskError(f"{exc} (training frames {frames[0]}..{frames[-1]})", missing[exc.index],
                        exc.desc) from exc.__cause__
    finally:
        if own:
            ex.close()
    transfer = np.concatenate(parts)
    for key in keys:  # assembled: the per-task entries are not needed any more
        path = cache.path(key)
        with contextlib.suppress(OSError):  # a read-only cache keeps them
            if path is not None:
                path.unlink()
    return transfer


def pose_columns(data: dict, kind: str, root: str) -> np.ndarray:
    """The pose vectors of training data (``poses_<kind>``, float64 (p, a)) without the root
    joints' columns (``root_<kind>`` flags them) when ``root == "exclude"``."""
    poses = np.asarray(data[f"poses_{kind}"], np.float64)
    if root == "exclude":
        poses = poses[:, np.asarray(data[f"root_{kind}"]) == 0]
    return poses


class TrainingClipStage(PrecomputeStage):
    """A precompute stage that traces a training clip: the ``training`` parameter (a USD file
    relative to the graph, or a scene spec; empty: the graph's own scene), keyed by the clip's
    content rather than its path, and the artifact independent of the graph's scene when the clip
    is another one (``datadriven.data``, ``visibility.data``)."""

    TRAINING = Param("", str, "training clip: a USD file relative to the graph, or a scene spec such as "
                     "'bundled:figure_train' (default: the graph's own scene)")

    def __init__(self, name, params=None):
        super().__init__(name, params)
        # trained on another clip: the artifact does not depend on the scene the graph runs on
        self.uses_scene = not self.params["training"]

    def cache_params(self):
        return {k: v for k, v in self.params.items() if k != "training"}

    def cache_key(self, ctx):
        if not self.params["training"]:
            return {}
        return {"training": self.training_scene(ctx).fingerprint()}

    def training_scene(self, ctx):
        """The training scene (the graph's scene when ``training`` is empty); StageError names
        the parameter and the file."""
        path = self.params["training"]
        if not path:
            return ctx.scene
        from ...io import SCENE_SPEC_PREFIXES, load_scene

        where = f"stage {self.name!r} ({self.type_name}): parameter 'training'"
        if path.startswith(SCENE_SPEC_PREFIXES):
            try:
                return load_scene(path)
            except (OSError, ValueError) as exc:
                raise StageError(f"{where} ({path}): {exc}") from None
        p = ctx.resolve_path(path)
        if not p.exists():
            raise StageError(f"{where}: no such file {p}")
        try:
            return load_scene(str(p))
        except (OSError, ValueError) as exc:
            raise StageError(f"{where} ({p}): {exc}") from None

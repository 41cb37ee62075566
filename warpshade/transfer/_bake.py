"""One frame's transfer bake: the direct quantities and, with bounces, the interreflected transfer.

:func:`compute` is the one-call form of :class:`~warpshade.transfer._raytrace.TransferTracer`
(visibility, transfer and ambient occlusion; definitions in :mod:`warpshade.transfer._raytrace`)
and, with ``bounces > 0``, of :class:`~warpshade.transfer._interreflection.InterreflectionTracer`
(transfer per RGB channel after k diffuse bounces; :mod:`warpshade.transfer._interreflection`).
"""

from ._interreflection import InterreflectionTracer, check_bounces
from ._raytrace import TransferResult, TransferTracer

__all__: list[str] = []


def compute(
    scene,
    frame,
    order: int,
    samples: int,
    space: str = "world",
    device=None,
    seed: int = 0,
    vertices=None,
    workers: int | None = None,
    offset: float | None = None,
    below_horizon: str = "traced",
    progress: bool = False,
    bounces: int = 0,
    albedo=None,
) -> TransferResult:
    """Ray-traced SH visibility, diffuse transfer and ambient occlusion at one frame, and with
    ``bounces > 0`` the interreflected transfer per channel.

    Direct transfer ``t0 = integral V(s) max(0, n.s) y(s) ds``; with k bounces
    ``t^(b)_c = t0 + integral_{occluded s} (rho_q,c / pi) t^(b-1)_q,c max(0, n.s) ds`` (q the
    closest front-face hit; :mod:`warpshade.transfer._interreflection`), and the outgoing
    radiance of channel c is ``rho_c / pi * dot(L_c, t^(k)_c)``.

    Args:
        scene: a :class:`~warpshade.scene.Scene`.
        frame: time code (one of ``scene.frames``).
        order: SH order n (n*n coefficients), 1..MAX_KERNEL_ORDER.
        samples: rays per receiver (a randomly rotated spherical Fibonacci set).
        space: "world" or "local" (per-vertex tangent frame, :mod:`warpshade.geometry._frames`).
        device: Warp device (None = Warp's default).
        seed: seed of the per-vertex random rotations.
        vertices: receiver vertex indices (default: every vertex), any integer array.
        workers: CPU launch threads (default: every core on the CPU device, 1 on CUDA); batches
            under :data:`~warpshade.transfer._raytrace.CHUNK_MIN_RAYS` rays use one launch.
        offset: ray-origin offset in scene units (default: scene-scaled, see geometry.bvh).
        below_horizon: "traced" (visibility of every direction is ray traced; below the
            tangent plane rays mostly hit the receiver's own surface) or "visible" (directions
            below the tangent plane count as visible and cast no ray). Transfer and AO, which
            carry the cosine, are the same either way; "visible" suits visibility that is later
            multiplied by a BRDF that already vanishes below the horizon (glossy LDPRT): an
            unoccluded receiver then has V = 1 exactly, with no horizon step for the truncated
            SH product to ring on.
        progress: show a progress bar (tqdm) over the receivers (and the bounces).
        bounces: diffuse bounces k, 0..MAX_BOUNCES; > 0 fills ``transfer_rgb`` (needs
            ``space="world"``; the direct transfer is then traced at every vertex, which the
            bounces gather from).
        albedo: RGB albedo of the reflecting surfaces for the bounces, (vertex_count, 3) or (3,),
            linear, >= 0 (default ``scene.albedo``); unused without bounces.

    Returns:
        :class:`TransferResult` with NumPy float32 arrays (rows follow ``vertices``).
    """
    if check_bounces(bounces, "transfer") > 0:
        if space != "world":
            raise ValueError(f"transfer: bounces need space='world' (the bounces gather world-frame SH), got {space!r}")
        inter = InterreflectionTracer(scene, order, samples, bounces, albedo=albedo, vertices=vertices, device=device,
                                      seed=seed, workers=workers, offset=offset, below_horizon=below_horizon,
                                      progress=progress)
        inter.trace(frame)
        return inter.result()
    tracer = TransferTracer(scene, order, samples, space=space, vertices=vertices, device=device, seed=seed,
                            workers=workers, offset=offset, below_horizon=below_horizon, progress=progress)
    tracer.trace(frame)
    return tracer.result()

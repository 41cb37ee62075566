"""Warp kernel of SHEXP's ray-traced reference: shading against the blocker spheres.

:func:`sphere_trace_kernel` intersects rays with the same (replaced) blocker spheres and plane
discs the receiver pass accumulates (:func:`._kernels.effective_sphere`,
:func:`._kernels.plane_cap`) instead of the mesh -- the paper's Fig. 7b, which separates the
sphere approximation from SH truncation. :class:`._pipeline.SphereTracer` owns its buffers.
"""

# No "from __future__ import annotations": Warp resolves closure types in annotations.

import functools

from ..._wp import wp
from ...basis.sh_warp import sh_kernels
from ...geometry._frames import onb_tangent
from ...scene._lighting_warp import EnvironmentMap, env_pdf, env_radiance, env_sample
from ._kernels import MODULE_OPTIONS, BlockerSet, ReceiverSet, effective_sphere, plane_cap

wp.set_module_options({"enable_backward": False})

__all__ = ["TraceOutputs", "sphere_trace_kernel"]


@wp.struct
class TraceOutputs:
    """Per-receiver outputs of :func:`sphere_trace_kernel`.

    Fields:
        radiance: Monte Carlo outgoing radiance with the environment, (V,) vec3, linear RGB.
        stderr: its standard error, (V,) vec3.
        transfer: SH transfer ``t = integral V_spheres(s) max(0, N.s) y(s) ds`` (no 1/pi),
            world frame, (V, n*n) float32.
    """

    radiance: wp.array(dtype=wp.vec3)
    stderr: wp.array(dtype=wp.vec3)
    transfer: wp.array2d(dtype=wp.float32)


@wp.func
def sphere_occluded(origin: wp.vec3, d: wp.vec3, blockers: BlockerSet, cluster: int, n: wp.vec3, baked: int, rule: int) -> int:
    # any-hit of the ray origin + t d (t > 0) against the receiver's replaced blocker spheres
    for e in range(blockers.cut_count[cluster]):
        node = blockers.cut_nodes[cluster, e]
        if node < 0:
            break
        if baked != 0 and blockers.is_static[node] != 0:
            continue
        sphere = effective_sphere(origin, n, blockers.centres[node], blockers.radii[node], rule)
        r = sphere[3]
        if r <= 0.0:
            continue
        oc = wp.vec3(sphere[0], sphere[1], sphere[2]) - origin
        b = wp.dot(oc, d)
        c2 = wp.dot(oc, oc) - r * r
        if b > 0.0 and b * b - c2 > 0.0:
            return 1
    if baked == 0:
        for k in range(blockers.plane_radius.shape[0]):
            pc = plane_cap(origin, blockers.plane_centre[k], blockers.plane_normal[k], blockers.plane_radius[k])
            if pc[3] > 0.0 and wp.dot(d, wp.vec3(pc[0], pc[1], pc[2])) > wp.cos(pc[3]):
                return 1
    return 0


@wp.func
def _frame_dir(axis: wp.vec3, x: float, y: float, z: float) -> wp.vec3:
    # (x, y, z) in the orthonormal basis (tangent, bitangent, axis) of a unit axis
    t = onb_tangent(axis)
    b = wp.cross(axis, t)
    return wp.normalize(x * t + y * b + z * axis)


@functools.lru_cache(maxsize=None)
def sphere_trace_kernel(order: int):
    """Ray-traced shading against the blocker spheres instead of the mesh (paper Fig. 7b).

    Per receiver, ``iterations`` MIS iterations (one cosine-weighted and one environment
    importance-sampled ray each, balance heuristic, as :mod:`warpshade.reference`) estimate
    ``albedo / pi * integral L(s) V_spheres(s) max(0, N.s) ds`` with the environment itself,
    and the same rays' cosine-weighted directions estimate the SH transfer
    ``t = integral V_spheres(s) max(0, N.s) y(s) ds`` (no 1/pi), so the spheres can also be
    shaded with the order-n SH lighting (``albedo / pi * dot(L_c, t)``) -- this separates the
    sphere approximation from SH truncation. V uses the same replaced spheres as SHEXP.

    Signature ``(blockers: BlockerSet, receivers: ReceiverSet, env: EnvironmentMap,
    out: TraceOutputs, iterations: int, seed: int, rule: int, start: int)``; thread ``i``
    handles receiver ``start + i`` (``rule``: index into :data:`._kernels.RULES`).
    """
    k = sh_kernels(order)
    sh_eval, vec_t = k.eval, k.vec
    N = order * order

    @wp.kernel(enable_backward=False, module="unique", module_options=MODULE_OPTIONS)
    def kernel(
        blockers: BlockerSet,
        receivers: ReceiverSet,
        env: EnvironmentMap,
        out: TraceOutputs,
        iterations: int,
        seed: int,
        rule: int,
        start: int,
    ):
        v = start + wp.tid()
        p = receivers.points[v]
        n = wp.normalize(receivers.normals[v])
        cluster = receivers.cluster[v]
        baked = receivers.baked[v]
        rho = wp.vec3(receivers.albedo[v, 0], receivers.albedo[v, 1], receivers.albedo[v, 2])
        base = int(wp.rand_init(seed, v))
        mean = wp.vec3(0.0)
        m2 = wp.vec3(0.0)
        t_acc = vec_t()
        for it in range(iterations):
            state = wp.rand_init(base, it)
            u1 = wp.randf(state)
            u2 = wp.randf(state)
            r = wp.sqrt(u1)
            phi = 2.0 * wp.pi * u2
            d = _frame_dir(n, r * wp.cos(phi), r * wp.sin(phi), wp.sqrt(wp.max(0.0, 1.0 - u1)))
            x = wp.vec3(0.0)
            if sphere_occluded(p, d, blockers, cluster, n, baked, rule) == 0:
                # cosine-weighted pdf cos/pi: transfer sample = pi * y(d)
                t_acc = t_acc + sh_eval(d) * wp.pi
                c = wp.max(wp.dot(n, d), 0.0)
                x += env_radiance(env, d) * (c / wp.pi) / (c / wp.pi + env_pdf(env, d))
            s = env_sample(env, wp.randf(state), wp.randf(state), wp.randf(state), wp.randf(state))
            d2 = wp.vec3(s[0], s[1], s[2])
            c2 = wp.dot(n, d2)
            if c2 > 0.0 and s[3] > 0.0:
                if sphere_occluded(p, d2, blockers, cluster, n, baked, rule) == 0:
                    x += env_radiance(env, d2) * (c2 / wp.pi) / (s[3] + c2 / wp.pi)
            x = wp.cw_mul(rho, x)
            delta = x - mean
            mean += delta / float(it + 1)
            m2 += wp.cw_mul(delta, x - mean)
        out.radiance[v] = mean
        var = m2 / float(wp.max((iterations - 1) * iterations, 1))
        out.stderr[v] = wp.vec3(wp.sqrt(wp.max(var[0], 0.0)), wp.sqrt(wp.max(var[1], 0.0)), wp.sqrt(wp.max(var[2], 0.0)))
        for i in range(N):
            out.transfer[v, i] = t_acc[i] / float(iterations)

    return kernel

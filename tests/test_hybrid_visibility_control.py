"""hybrid.visibility_transfer: local SH visibility as world-frame diffuse transfer (the control of
hybrid.trace), against its float64 mirror and the exact clamped cosine of an open vertex."""

import numpy as np

from warpshade._wp import wp
from warpshade.basis import quadrature, sh
from warpshade.basis.sh_warp import sh_kernels
from warpshade.methods.hybrid import visibility_transfer_f64
from warpshade.methods.hybrid.kernels import visibility_transfer_kernel
from warpshade.methods.rpo.model import cosine_sh

from tolerances import assert_close

ORDER = 6
#: float32 product (Gaunt table sums of ~100 terms) and rotation against float64, coefficients <= ~3.
ATOL_TRANSFER = 5e-5
#: An open vertex (visibility 1 everywhere): the order-6 product of 1 and the clamped cosine is the
#: clamped cosine itself (exact), against a 40 000-point quadrature of max(0, n.w).
ATOL_OPEN = 1e-3


def _random_frames(rng, count):
    q, _ = np.linalg.qr(rng.standard_normal((count, 3, 3)))
    q *= np.sign(np.linalg.det(q))[:, None, None]
    return q


def _run(device, vis, frames):
    dev = wp.get_device(device)
    v = vis.shape[0]
    out = wp.zeros((v, ORDER * ORDER), dtype=wp.float32, device=dev)
    wp.launch(visibility_transfer_kernel(ORDER), dim=v, device=dev,
              inputs=[wp.array(vis.astype(np.float32), dtype=wp.float32, device=dev),
                      wp.array(frames.astype(np.float32), dtype=wp.mat33, device=dev),
                      wp.array(cosine_sh(ORDER).astype(np.float32), dtype=wp.float32, device=dev),
                      sh_kernels(ORDER).tables(dev), 0, out])
    return out.numpy()


def test_visibility_transfer_matches_mirror(device, rng):
    v = 16
    vis = 0.3 * rng.standard_normal((v, ORDER * ORDER))
    frames = _random_frames(rng, v)
    assert_close(_run(device, vis, frames), visibility_transfer_f64(vis, frames, ORDER), atol=ATOL_TRANSFER,
                 what="world-frame transfer")


def test_open_vertex_gives_the_clamped_cosine_about_its_normal(device, rng):
    v = 5
    vis = np.zeros((v, ORDER * ORDER))
    vis[:, 0] = 2.0 * np.sqrt(np.pi)  # SH of the constant 1
    frames = _random_frames(rng, v)
    q = quadrature.fibonacci(40000)
    exact = np.maximum(0.0, frames[:, 2, :] @ q.directions.T) @ (sh.basis(q.directions, ORDER) * q.weights[:, None])
    assert_close(_run(device, vis, frames), exact, atol=ATOL_OPEN, what="clamped cosine of an open vertex")

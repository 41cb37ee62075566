"""Data-driven PRT: pose vectors, the regularised fits, the frame kernels, and where it fails.

Oracles: brute-force leave-one-out refits and the normal equations for the closed-form fits;
SciPy rotations and the joint-local (not skeleton-space) transforms for the pose vectors; the
float64 model (``DataDrivenModel.predict``) for the Warp kernels; an exact SVD for the
randomised one; ray-traced transfer for the end-to-end fit.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from warpshade.methods.datadriven import _model as dd
from warpshade.methods.datadriven import PARAMETERISATIONS, novelty, pose_features, pose_layout
from warpshade.methods.datadriven import hemisphere_transfer_error
from warpshade.methods._shared.pose_space import pose_space
from warpshade.methods.datadriven._stages import model_from_arrays, model_to_arrays
from warpshade.scene import Mesh, Scene, Skeleton, SkinBinding

#: float32 kernels: pose features are a few rotations composed (angles ~1 rad).
ATOL_FEATURES = 2e-5
#: float32 products of length <= 100 with values ~1 (relative to the largest output).
RTOL_PRODUCTS = 2e-5
#: closed-form LOO against p refits in float64.
RTOL_LOO = 1e-8


# ---- the fits -------------------------------------------------------------------------------
def _regression_case(rng, p=36, a=7, v=20, c=4, noise=0.2, constant=(5,)):
    A = rng.normal(size=(p, a))
    for j in constant:
        A[:, j] = 0.25
    X = rng.normal(size=(a, v * c))
    B = (A @ X + noise * rng.normal(size=(p, v * c)) + 1.5).reshape(p, v, c)
    return A, B


def _loo_by_refits(Z, y, alpha):
    total = 0.0
    for i in range(Z.shape[0]):
        keep = np.arange(Z.shape[0]) != i
        zm, ym = Z[keep].mean(0), y[keep].mean(0)
        zc = Z[keep] - zm
        x = np.linalg.solve(zc.T @ zc + alpha ** 2 * np.eye(Z.shape[1]), zc.T @ (y[keep] - ym))
        total += np.sum((y[i] - ((Z[i] - zm) @ x + ym)) ** 2)
    return total


def test_closed_form_loo_equals_refits(rng):
    A, B = _regression_case(rng)
    space = pose_space(A, pca=False)
    Z = space.project(A)
    solver = dd.RidgeSolver(Z)
    y = B[:, :, 1]
    yc = y - y.mean(0)
    for rel in (1e-3, 0.05, 0.5):
        alpha = rel * solver.s_max
        want = _loo_by_refits(Z, y, alpha)
        assert solver.loo_from_gram(yc @ yc.T, [alpha])[0] == pytest.approx(want, rel=RTOL_LOO)
        assert solver.loo_columns(yc, [alpha]).sum() == pytest.approx(want, rel=RTOL_LOO)


def test_ridge_solution_is_the_normal_equations(rng):
    A, B = _regression_case(rng)
    model = dd.fit_full(A, B, alpha=0.1)
    Z = model.pose.project(A)
    zc = Z - Z.mean(0)
    alpha = 0.1 * dd.RidgeSolver(Z).s_max
    y = B[:, :, 2]
    x = np.linalg.solve(zc.T @ zc + alpha ** 2 * np.eye(Z.shape[1]), zc.T @ (y - y.mean(0)))
    np.testing.assert_allclose(model.weights[:, 2, :-1], x.T, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(model.weights[:, 2, -1], y.mean(0) - Z.mean(0) @ x, rtol=1e-9, atol=1e-12)


def test_loo_chooses_regularisation_that_generalises(rng):
    """Correlated pose features (a few latent motions plus jitter), few noisy poses: least
    squares overfits the jitter; LOO's alpha generalises nearly as well as the best alpha."""
    latent = rng.normal(size=(60, 3))
    A = latent @ rng.normal(size=(3, 20)) + 0.1 * rng.normal(size=(60, 20))
    B = (latent @ rng.normal(size=(3, 40)) + 0.5 * rng.normal(size=(60, 40)) + 1.0).reshape(60, 10, 4)
    A_test, B_test = A[24:], B[24:]
    A, B = A[:24], B[:24]
    err = lambda m: np.linalg.norm(m.predict(A_test) - B_test)  # noqa: E731
    loo = dd.fit_full(A, B)
    ls = dd.fit_full(A, B, alpha=0.0)
    best = min(err(dd.fit_full(A, B, alpha=float(a))) for a in dd.ALPHA_GRID[1:])
    assert np.all(loo.alphas > 0)
    assert err(loo) < 0.8 * err(ls)
    assert err(loo) < 1.15 * best
    assert np.linalg.norm(ls.predict(A) - B) < np.linalg.norm(loo.predict(A) - B), "the training error rises"


def test_constant_features_are_dropped_and_reported(rng):
    A, B = _regression_case(rng, constant=(2, 5))
    space = pose_space(A, pca=True)
    assert list(np.flatnonzero(~space.active)) == [2, 5]
    assert np.all(space.components[[2, 5]] == 0.0)
    moved = A[:3].copy()
    moved[:, 5] += 0.4
    nov = novelty(space, moved, A)
    np.testing.assert_allclose(nov["constant"], 0.4, rtol=1e-12)
    np.testing.assert_allclose(novelty(space, A[:3], A)["nearest"], 0.0, atol=1e-12)


def test_fewer_poses_than_dimensions_and_alpha_zero_stay_bounded(rng):
    """p < a and collinear features with alpha = 0: the minimum-norm fit, finite and bounded."""
    A, B = _regression_case(rng, p=6, a=30, constant=())
    A[:, 1] = A[:, 0] * (1 + 1e-13)  # exactly ill-conditioned
    for alpha in (0.0, None):
        model = dd.fit_full(A, B, alpha=alpha)
        pred = model.predict(A + rng.normal(scale=3.0, size=A.shape))
        assert np.all(np.isfinite(pred))
        assert np.abs(pred).max() < 50 * np.abs(B).max()
        assert model.info["rank"] <= 5
    reduced = dd.fit_reduced(A, B, ka=64, kv=64, alpha=0.0)
    assert reduced.pose.size <= 6 and np.all(np.isfinite(reduced.predict(A)))
    with pytest.raises(ValueError, match="at least 2 training poses"):
        dd.fit_full(A[:1], B[:1])
    with pytest.raises(ValueError, match="no pose feature varies"):
        dd.fit_full(np.ones((5, 3)), B[:5])


def test_loo_undefined_when_every_alpha_interpolates(rng):
    """Two poses: the fit through both interpolates them, LOO is undefined for alpha = 0 (not NaN)."""
    A, B = _regression_case(rng, p=2, a=3, constant=())
    Z = pose_space(A, pca=False).project(A)
    solver = dd.RidgeSolver(Z)
    yc = B[:, :, 0] - B[:, :, 0].mean(0)
    assert np.isinf(solver.loo_from_gram(yc @ yc.T, [0.0])[0])
    assert np.all(np.isfinite(dd.fit_full(A, B).predict(A)))


def test_randomised_coefficient_basis_matches_exact_svd(rng):
    p, v, c = 40, 1800, 9
    low = rng.normal(size=(p * c, 12)) @ rng.normal(size=(12, v))
    data = (low + 1e-3 * rng.normal(size=low.shape)).reshape(p, c, v).transpose(0, 2, 1)
    basis, s, total = dd.coefficient_basis(data, 12)
    exact = np.linalg.svd(np.transpose(data, (0, 2, 1)).reshape(p * c, v), compute_uv=False)
    np.testing.assert_allclose(s, exact[:12], rtol=1e-6)
    assert total == pytest.approx(np.sum(exact ** 2), rel=1e-10)
    np.testing.assert_allclose(basis.T @ basis, np.eye(12), atol=1e-10)


def test_reduced_model_reaches_full_model_when_nothing_is_cut(rng):
    A, B = _regression_case(rng, p=40, a=6, v=15, c=3, constant=())
    full = dd.fit_full(A, B, alpha=0.01)
    red = dd.fit_reduced(A, B, ka=6, kv=45, alpha=0.01)
    np.testing.assert_allclose(red.predict(A), full.predict(A), rtol=1e-8, atol=1e-8)


def test_size_choice_meets_its_budget_and_validation_is_contiguous(rng):
    A, B = _regression_case(rng, p=48, a=8, v=30, c=4, constant=())
    train, val = dd.validation_split(48, 0.25)
    assert val.size == 12 and np.intersect1d(train, val).size == 0
    assert np.sum(np.diff(val) == 1) >= val.size - 4, "four contiguous blocks"
    choice = dd.choose_sizes(A, B, train, val, ka_grid=(1, 2, 4, 8), kv_grid=(2, 4, 8, 16, 32))
    assert choice.met and choice.error[(choice.ka, choice.kv)] <= choice.target
    cheaper = [k for k, e in choice.error.items() if choice.cost[k] < choice.cost[(choice.ka, choice.kv)]]
    assert all(choice.error[k] > choice.target for k in cheaper)
    # the measured validation error of the chosen candidate is what a direct fit gives
    red = dd.fit_reduced(A[train], B[train], choice.ka, choice.kv, basis=dd.coefficient_basis(B[train], 120),
                         alpha_grid=dd.SEARCH_ALPHA_GRID)
    direct = np.linalg.norm(red.predict(A[val]) - B[val]) / np.linalg.norm(B[val])
    assert direct == pytest.approx(choice.error[(choice.ka, choice.kv)], rel=1e-6)


def test_model_arrays_round_trip_and_reject_damage(rng):
    A, B = _regression_case(rng)
    red = dd.fit_reduced(A, B, ka=3, kv=8)
    arrays = model_to_arrays(red, kind="rotvec", root="include", order=2, channels=1, topology=np.arange(4),
                             root_reference=np.eye(3)[None], training_poses=A)
    back, meta = model_from_arrays(arrays)
    np.testing.assert_allclose(back.predict(A), red.predict(A), rtol=1e-5, atol=1e-5)
    assert meta["kind"] == "rotvec" and meta["order"] == 2
    bad = dict(arrays, coefficients=arrays["coefficients"][:, :, :2])
    with pytest.raises(ValueError, match="do not match"):
        model_from_arrays(bad)


def test_hemisphere_transfer_error_of_a_constant_difference():
    """A difference of d * Y00 integrates to d^2 / (4 pi) * 2 pi over a hemisphere."""
    diff = np.zeros((2, 9))
    diff[:, 0] = [1.0, 0.5]
    e = hemisphere_transfer_error(diff, np.zeros((2, 9)), np.array([[0, 0, 1.0], [1.0, 0, 0]]), directions=20000)
    np.testing.assert_allclose(e, np.array([1.0, 0.25]) / (4 * np.pi) * 2 * np.pi, rtol=2e-3)


# ---- pose vectors -----------------------------------------------------------------------------
def _row(rot: Rotation, t) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = rot.as_matrix().T  # row-vector convention
    m[3, :3] = t
    return m


def _random_skinned_scene(rng, frames=5, root_moves=True):
    """A 4-joint chain with rest rotations, animated local rotations and a moving skeleton."""
    names = ["Root", "Root/A", "Root/A/B", "Root/C"]
    parents = np.array([-1, 0, 1, 0])
    rest = np.stack([_row(Rotation.random(random_state=rng), rng.normal(size=3)) for _ in names])
    bind = np.stack([np.eye(4)] * 4)
    local = np.stack([np.stack([_row(Rotation.from_rotvec(rng.normal(scale=0.7, size=3)) * Rotation.from_matrix(rest[j, :3, :3].T),
                                     rest[j, 3, :3]) for j in range(4)]) for _ in range(frames)])
    s2w = np.stack([_row(Rotation.from_rotvec(rng.normal(scale=0.3, size=3)) if root_moves else Rotation.identity(),
                         rng.normal(size=3) if root_moves else np.zeros(3)) for _ in range(frames)])
    skel = Skeleton("/Skel", names, parents, bind, rest, local, s2w)
    pts = rng.uniform(-1, 1, (6, 3))
    skin = SkinBinding(0, rng.integers(0, 4, (6, 2)).astype(np.int32), np.full((6, 2), 0.5, np.float32))
    mesh = Mesh("/M", points=pts, faces=[[0, 1, 2], [3, 4, 5]], animation="skinned", skin=skin)
    return Scene([mesh], frames=np.arange(frames, dtype=float), skeletons=[skel])


@pytest.mark.parametrize("kind", sorted(PARAMETERISATIONS))
def test_pose_features_host_match_scipy(rng, kind):
    scene = _random_skinned_scene(rng, frames=3)
    layout = pose_layout(scene, kind, "include")
    assert layout.size == 6 + 3 * PARAMETERISATIONS[kind]
    f = pose_features(scene, [2], layout)[0]
    skel = scene.skeletons[0]
    for j in (1, 2, 3):
        rest = Rotation.from_matrix(skel.rest_transforms[j, :3, :3].T)
        cur = Rotation.from_matrix(skel.local_transforms[2, j, :3, :3].T)
        rel = rest.inv() * cur
        o = layout.offsets[j]
        got = f[o:o + layout.widths[j]]
        if kind == "rotvec":
            np.testing.assert_allclose(Rotation.from_rotvec(got).as_matrix(), rel.as_matrix(), atol=1e-10)
            assert np.linalg.norm(got) <= np.pi + 1e-12
        elif kind == "quaternion":
            np.testing.assert_allclose(Rotation.from_quat(got).as_matrix(), rel.as_matrix(), atol=1e-10)
            assert got[3] >= 0
        else:
            np.testing.assert_allclose(got.reshape(3, 3) + np.eye(3), rel.as_matrix(), atol=1e-10)
    # the root: world translation and rotation relative to its world rotation at frame 0
    world = lambda t: skel.local_transforms[t, 0] @ skel.skel_to_world[t]  # noqa: E731
    np.testing.assert_allclose(f[:3], world(2)[3, :3], atol=1e-10)
    rel_root = Rotation.from_matrix(world(0)[:3, :3].T).inv() * Rotation.from_matrix(world(2)[:3, :3].T)
    np.testing.assert_allclose(Rotation.from_rotvec(f[3:6]).as_matrix(), rel_root.as_matrix(), atol=1e-10)
    assert pose_layout(scene, kind, "exclude").size == 3 * PARAMETERISATIONS[kind]


@pytest.mark.parametrize("kind", sorted(PARAMETERISATIONS))
def test_pose_features_kernel_matches_host(rng, device, kind):
    """Device: skeleton-space transforms of the frame state; host: the joint-local samples."""
    from warpshade._wp import wp
    from warpshade.methods._shared.pose import root_references
    from warpshade.methods._shared.pose_kernels import KIND_CODES, pose_features_kernel

    scene = _random_skinned_scene(rng, frames=4)
    layout = pose_layout(scene, kind, "include")
    ref = root_references(scene, 1)
    skel = scene.skeletons[0]
    rest = np.transpose(skel.rest_transforms[:, :3, :3], (0, 2, 1))
    rest_t = np.transpose(rest, (0, 2, 1))
    ref_t = [ref[0].T, np.eye(3), np.eye(3), np.eye(3)]
    for t in range(4):
        state = scene.evaluate(float(t), device=device)
        out = wp.zeros(layout.size, dtype=wp.float32, device=device)
        wp.launch(pose_features_kernel, dim=4, device=device, inputs=[
            state.joint_transforms, state.skin_matrices, wp.array(layout.parents.astype(np.int32), dtype=wp.int32, device=device),
            wp.array(layout.offsets.astype(np.int32), dtype=wp.int32, device=device),
            wp.array(rest_t.astype(np.float32), dtype=wp.mat33, device=device),
            wp.array(np.transpose(skel.bind_transforms, (0, 2, 1)).astype(np.float32), dtype=wp.mat44, device=device),
            wp.array(np.asarray(ref_t, np.float32), dtype=wp.mat33, device=device), KIND_CODES[kind], out])
        np.testing.assert_allclose(out.numpy(), pose_features(scene, [t], layout, root_reference=ref)[0], atol=ATOL_FEATURES)


def test_pose_layout_errors():
    scene = Scene([Mesh("/T", points=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]])])
    with pytest.raises(ValueError, match="has no UsdSkel skeleton"):
        pose_layout(scene)
    with pytest.raises(ValueError, match="parameterisation must be one of"):
        pose_layout(scene, "euler")


# ---- frame kernels against the float64 model ---------------------------------------------------
@pytest.mark.parametrize("reduced", [True, False])
def test_frame_products_match_float64_model(rng, device, reduced):
    from warpshade._wp import wp
    from warpshade.methods.datadriven import _kernels as kernels
    from warpshade.methods.datadriven._stages import _blocks, _vec

    A, B = _regression_case(rng, p=50, a=11, v=300, c=9, constant=(4,))
    model = dd.fit_reduced(A, B, ka=5, kv=19) if reduced else dd.fit_full(A, B)
    pose = A[7] + rng.normal(scale=0.3, size=A.shape[1])
    want = model.predict(pose)[0]
    f = wp.array(pose.astype(np.float32), dtype=wp.float32, device=device)
    z = wp.zeros(-(-(model.pose.size + 1) // kernels.BLOCK), dtype=kernels.vec_block, device=device)
    wp.launch(kernels.project_pose_kernel, dim=1, device=device, inputs=[
        f, wp.array(model.pose.mean.astype(np.float32), device=device),
        wp.array(model.pose.weights.astype(np.float32), device=device), z])
    out = wp.zeros((300, 9), dtype=wp.float32, device=device)
    if reduced:
        basis = _vec(_blocks(model.basis), device)
        y = wp.zeros((9, basis.shape[1]), dtype=kernels.vec_block, device=device)
        wp.launch(kernels.coefficients_kernel, dim=9, device=device, inputs=[_vec(_blocks(model.coefficients), device), z, y])
        wp.launch(kernels.reconstruct_kernel, dim=200, device=device, inputs=[basis, y, 100, out])
        wp.launch(kernels.reconstruct_kernel, dim=100, device=device, inputs=[basis, y, 0, out])
    else:
        wp.launch(kernels.full_kernel, dim=300, device=device, inputs=[_vec(_blocks(model.weights), device), z, 0, out])
    scale = np.abs(want).max()
    np.testing.assert_allclose(out.numpy(), want, atol=RTOL_PRODUCTS * scale * 10)

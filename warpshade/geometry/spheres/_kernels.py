"""Warp kernels of the blocker-sphere package (:mod:`warpshade.geometry.spheres`).

Grouped by concern:

* solid classification against a triangle mesh over its BVH (fast generalised winding number,
  or the unsigned distance for a thickened open shell): signed distances on a grid, and the
  per-sample outside/union-weight evaluation of the outside-volume estimator;
* coverage: how far each point lies outside a sphere set;
* attachment: per-frame sphere centres from skinning matrices (skinned), per-mesh matrices
  (static / rigid), dense vertex weights or triangle frames (deforming), and radii from
  per-mesh scales -- each gathering by index from per-frame device arrays (the
  :class:`~warpshade.scene._state.FrameState` arrays, though nothing here reads a scene);
* hierarchy: leaf copy and bottom-up refit of a sphere tree;
* receiver clusters: per-frame bounding spheres, and the hierarchy cut of eq. 36.

All kernels compute in float32; the float64 mirrors live beside their callers.
Matrices are Warp column-vector ``mat44`` (the transposes of USD's row-vector matrices).
"""

from ..._wp import wp

wp.set_module_options({"enable_backward": False})

#: Refit modes of :func:`tree_refit_kernel`.
REFIT_ANCHORED = 0
REFIT_PAIR = 1
REFIT_MIN = 2


# ---- solid classification ---------------------------------------------------------------
@wp.func
def solid_signed_distance(mesh_id: wp.uint64, x: wp.vec3, shell_thickness: float) -> float:
    """Signed distance of ``x`` to the solid (negative inside), float32, scene units.

    Closed meshes (``shell_thickness <= 0``): distance to the closest surface point, signed by
    the fast generalised winding number (inside where it exceeds 0.5, so overlapping closed
    components form their union). Open meshes: ``distance - shell_thickness``, the solid being
    the shell of that half-thickness around the surface.
    """
    if shell_thickness > 0.0:
        q = wp.mesh_query_point_no_sign(mesh_id, x, 1.0e30)
        if q.result:
            return wp.length(wp.mesh_eval_position(mesh_id, q.face, q.u, q.v) - x) - shell_thickness
        return 1.0e30
    qs = wp.mesh_query_point_sign_winding_number(mesh_id, x, 1.0e30, 2.0, 0.5)
    if qs.result:
        return qs.sign * wp.length(wp.mesh_eval_position(mesh_id, qs.face, qs.u, qs.v) - x)
    return 1.0e30


@wp.func
def solid_contains(mesh_id: wp.uint64, x: wp.vec3, shell_thickness: float) -> bool:
    """True where ``x`` lies in the solid (see :func:`solid_signed_distance`)."""
    if shell_thickness > 0.0:
        # Any face closer than the half-thickness: no need for the closest one.
        q = wp.mesh_query_point_no_sign(mesh_id, x, shell_thickness)
        return q.result
    qs = wp.mesh_query_point_sign_winding_number(mesh_id, x, 1.0e30, 2.0, 0.5)
    return qs.result and qs.sign < 0.0


@wp.kernel
def signed_distance_kernel(
    mesh_id: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    shell_thickness: float,
    offset: int,
    out: wp.array(dtype=wp.float32),
):
    i = offset + wp.tid()
    out[i] = solid_signed_distance(mesh_id, points[i], shell_thickness)


@wp.kernel
def ball_samples_kernel(
    mesh_id: wp.uint64,
    shell_thickness: float,
    centres: wp.array(dtype=wp.vec3),
    radii: wp.array(dtype=wp.float32),
    unit_ball: wp.array(dtype=wp.vec3),
    offset: int,
    outside: wp.array(dtype=wp.float32),
    union_weight: wp.array(dtype=wp.float32),
):
    """Sample ``k`` of sphere ``s`` (flat index ``s * K + k``): ``x = c_s + r_s u_k``.

    ``outside`` = 1 where x is outside the solid; ``union_weight`` = outside / (number of
    spheres containing x), so the per-sphere means of it sum to the union's outside volume.
    """
    idx = offset + wp.tid()
    sample_count = unit_ball.shape[0]
    s = idx // sample_count
    k = idx - s * sample_count
    c = centres[s]
    x = c + radii[s] * unit_ball[k]
    out = 1.0
    if solid_contains(mesh_id, x, shell_thickness):
        out = 0.0
    cover = wp.int32(0)
    for j in range(centres.shape[0]):
        if wp.length(x - centres[j]) <= radii[j]:
            cover += 1
    outside[idx] = out
    union_weight[idx] = out / float(wp.max(cover, 1))


@wp.kernel
def box_samples_kernel(
    mesh_id: wp.uint64,
    shell_thickness: float,
    points: wp.array(dtype=wp.vec3),
    offset: int,
    inside: wp.array(dtype=wp.float32),
):
    i = offset + wp.tid()
    v = 0.0
    if solid_contains(mesh_id, points[i], shell_thickness):
        v = 1.0
    inside[i] = v


@wp.kernel
def cluster_outside_volume_kernel(
    occupancy: wp.array3d(dtype=wp.float32),
    occupancy_prefix: wp.array3d(dtype=wp.float32),
    origin: wp.vec3,
    spacing: float,
    hull_start: wp.array(dtype=wp.int32),
    hull_points: wp.array(dtype=wp.vec3),
    candidate_cluster: wp.array(dtype=wp.int32),
    candidates: wp.array(dtype=wp.vec3),
    offset: int,
    out_radius: wp.array(dtype=wp.float32),
    out_outside: wp.array(dtype=wp.float32),
):
    """Grid estimator of V(S - T) for the smallest sphere about a candidate centre bounding
    its cluster (the objective of the centre update; see the :mod:`._fit` module docstring).

    ``occupancy[i, j, k]`` is the fractional occupancy of the cell centred at
    ``origin + spacing * (i, j, k)`` and ``occupancy_prefix[i, j, k] = sum_{k' < k}
    occupancy[i, j, k']``. The cluster's points are ``hull_points[hull_start[c] :
    hull_start[c + 1]]`` (its convex-hull vertices suffice: the farthest point is one).
    Per grid row along z, cells wholly inside the ramp (``d <= r - h/2``) are summed from
    the prefix in O(1) and only the ramp cells are visited, so a call costs O(r^2 / h^2).
    """
    t = offset + wp.tid()
    cl = candidate_cluster[t]
    c = candidates[t]
    r2 = wp.float32(0.0)
    for k in range(hull_start[cl], hull_start[cl + 1]):
        r2 = wp.max(r2, wp.length_sq(hull_points[k] - c))
    r = wp.sqrt(r2)
    h = spacing
    inv = 1.0 / h
    outer = r + 0.5 * h
    inner = r - 0.5 * h
    nz = occupancy.shape[2]
    i0 = wp.max(0, int(wp.ceil((c[0] - outer - origin[0]) * inv)))
    i1 = wp.min(occupancy.shape[0] - 1, int(wp.floor((c[0] + outer - origin[0]) * inv)))
    j0 = wp.max(0, int(wp.ceil((c[1] - outer - origin[1]) * inv)))
    j1 = wp.min(occupancy.shape[1] - 1, int(wp.floor((c[1] + outer - origin[1]) * inv)))
    acc = wp.float64(0.0)
    for i in range(i0, i1 + 1):
        dx = origin[0] + float(i) * h - c[0]
        for j in range(j0, j1 + 1):
            dy = origin[1] + float(j) * h - c[1]
            dxy = dx * dx + dy * dy
            if dxy < outer * outer:
                z_out = wp.sqrt(outer * outer - dxy)
                k0 = wp.max(0, int(wp.ceil((c[2] - z_out - origin[2]) * inv)))
                k1 = wp.min(nz - 1, int(wp.floor((c[2] + z_out - origin[2]) * inv)))
                # fully covered run [f0, f1] (empty when f1 < f0)
                f0 = k1 + 1
                f1 = k1
                if inner > 0.0 and dxy < inner * inner:
                    z_in = wp.sqrt(inner * inner - dxy)
                    f0 = wp.max(k0, int(wp.ceil((c[2] - z_in - origin[2]) * inv)))
                    f1 = wp.min(k1, int(wp.floor((c[2] + z_in - origin[2]) * inv)))
                if f1 >= f0:
                    acc += wp.float64(occupancy_prefix[i, j, f1 + 1] - occupancy_prefix[i, j, f0])
                else:
                    f0 = k1 + 1
                    f1 = k1
                # the ramp cells: below and above the fully covered run
                for seg in range(2):
                    ka = k0
                    kb = f0 - 1
                    if seg == 1:
                        ka = f1 + 1
                        kb = k1
                    for k in range(ka, kb + 1):
                        o = occupancy[i, j, k]
                        if o > 0.0:
                            dz = origin[2] + float(k) * h - c[2]
                            d = wp.sqrt(dxy + dz * dz)
                            acc += wp.float64(o * wp.clamp(0.5 + (r - d) * inv, 0.0, 1.0))
    inside = float(acc) * h * h * h
    out_radius[t] = r
    out_outside[t] = 4.0 / 3.0 * wp.pi * r * r * r - inside


# ---- coverage ---------------------------------------------------------------------------
@wp.kernel
def coverage_gap_kernel(
    points: wp.array(dtype=wp.vec3),
    centres: wp.array(dtype=wp.vec3),
    radii: wp.array(dtype=wp.float32),
    gap: wp.array(dtype=wp.float32),
):
    """gap[i] = min_s (|p_i - c_s| - r_s): <= 0 where some sphere covers the point."""
    i = wp.tid()
    p = points[i]
    best = wp.float32(1.0e30)
    for s in range(centres.shape[0]):
        best = wp.min(best, wp.length(p - centres[s]) - radii[s])
    gap[i] = best


# ---- attachment -------------------------------------------------------------------------
@wp.kernel
def skinned_centres_kernel(
    joint_index: wp.array2d(dtype=wp.int32),
    joint_point: wp.array2d(dtype=wp.vec3),
    joint_weight: wp.array2d(dtype=wp.float32),
    skin_matrices: wp.array(dtype=wp.mat44),
    joint_offset: int,
    sphere_index: wp.array(dtype=wp.int32),
    centres: wp.array(dtype=wp.vec3),
):
    """Centre = sum_k M[j_k] (q_k, b_k): mean value coordinates pushed through the bones.

    ``q_k`` (vec3, bind space) and ``b_k`` (scalar) are the bone-premultiplied coordinates of
    thread ``i``'s sphere; with b_k the homogeneous weight the affine map is ``R q + b t``.
    ``joint_index[i, k]`` is a joint of one skeleton (-1: unused entry) and its matrix is
    ``skin_matrices[joint_offset + joint_index[i, k]]``: skeleton-to-world times skeleton-space
    joint times inverse bind, column-vector. Writes ``centres[sphere_index[i]]``.
    """
    i = wp.tid()
    acc = wp.vec3(0.0, 0.0, 0.0)
    for k in range(joint_index.shape[1]):
        j = joint_index[i, k]
        if j >= 0:
            m = skin_matrices[joint_offset + j]
            acc += wp.transform_vector(m, joint_point[i, k]) + joint_weight[i, k] * wp.vec3(m[0, 3], m[1, 3], m[2, 3])
    centres[sphere_index[i]] = acc


@wp.kernel
def rigid_centres_kernel(
    local_centres: wp.array(dtype=wp.vec3),
    matrix_index: wp.array(dtype=wp.int32),
    matrices: wp.array(dtype=wp.mat44),
    sphere_index: wp.array(dtype=wp.int32),
    centres: wp.array(dtype=wp.vec3),
):
    """Centre = the mesh-local centre through its mesh's local-to-world matrix.

    ``matrices`` holds one column-vector local-to-world per mesh; thread ``i`` reads entry
    ``matrix_index[i]`` and writes ``centres[sphere_index[i]]``.
    """
    i = wp.tid()
    centres[sphere_index[i]] = wp.transform_point(matrices[matrix_index[i]], local_centres[i])


@wp.kernel
def vertex_weight_centres_kernel(
    weights: wp.array2d(dtype=wp.float32),
    points: wp.array(dtype=wp.vec3),
    vertex_offset: int,
    sphere_index: wp.array(dtype=wp.int32),
    centres: wp.array(dtype=wp.vec3),
):
    """Centre = sum_v w[i, v] points[vertex_offset + v] (dense mean value coordinates)."""
    i = wp.tid()
    acc = wp.vec3(0.0, 0.0, 0.0)
    for v in range(weights.shape[1]):
        w = weights[i, v]
        if w != 0.0:
            acc += w * points[vertex_offset + v]
    centres[sphere_index[i]] = acc


@wp.func
def triangle_frame(a: wp.vec3, b: wp.vec3, c: wp.vec3) -> wp.mat33:
    """Orthonormal frame of a triangle, rows (unit edge a->b, normal x edge, unit normal)."""
    e = b - a
    n = wp.cross(e, c - a)
    ln = wp.length(n)
    le = wp.length(e)
    if ln > 1.0e-30 and le > 1.0e-30:
        n = n / ln
        e = e / le
    else:
        n = wp.vec3(0.0, 0.0, 1.0)
        e = wp.vec3(1.0, 0.0, 0.0)
    return wp.matrix_from_rows(e, wp.cross(n, e), n)


@wp.kernel
def triangle_frame_centres_kernel(
    triangle: wp.array2d(dtype=wp.int32),
    bary: wp.array(dtype=wp.vec3),
    local_offset: wp.array(dtype=wp.vec3),
    points: wp.array(dtype=wp.vec3),
    vertex_offset: int,
    sphere_index: wp.array(dtype=wp.int32),
    centres: wp.array(dtype=wp.vec3),
):
    """Centre = barycentric point of a triangle + an offset fixed in the triangle's frame."""
    i = wp.tid()
    a = points[vertex_offset + triangle[i, 0]]
    b = points[vertex_offset + triangle[i, 1]]
    c = points[vertex_offset + triangle[i, 2]]
    w = bary[i]
    frame = triangle_frame(a, b, c)
    centres[sphere_index[i]] = w[0] * a + w[1] * b + w[2] * c + wp.transpose(frame) * local_offset[i]


@wp.kernel
def scale_radii_kernel(
    rest_radii: wp.array(dtype=wp.float32),
    sphere_mesh: wp.array(dtype=wp.int32),
    mesh_scales: wp.array(dtype=wp.float32),
    radii: wp.array(dtype=wp.float32),
):
    """radius = rest radius (mesh-local units) * the largest singular value of its mesh's
    transform, ``mesh_scales[sphere_mesh[i]]``."""
    i = wp.tid()
    radii[i] = rest_radii[i] * mesh_scales[sphere_mesh[i]]


# ---- hierarchy --------------------------------------------------------------------------
@wp.func
def merge_sphere_pair(c0: wp.vec3, r0: float, c1: wp.vec3, r1: float) -> wp.vec4:
    """Smallest sphere containing two spheres, packed as (centre, radius)."""
    d = wp.length(c1 - c0)
    if d + r1 <= r0:
        return wp.vec4(c0[0], c0[1], c0[2], r0)
    if d + r0 <= r1:
        return wp.vec4(c1[0], c1[1], c1[2], r1)
    r = 0.5 * (d + r0 + r1)
    c = c0 + ((r - r0) / d) * (c1 - c0)
    return wp.vec4(c[0], c[1], c[2], r)


@wp.kernel
def tree_leaves_kernel(
    leaf_sphere: wp.array(dtype=wp.int32),
    leaf_node: wp.array(dtype=wp.int32),
    sphere_centres: wp.array(dtype=wp.vec3),
    sphere_radii: wp.array(dtype=wp.float32),
    node_centres: wp.array(dtype=wp.vec3),
    node_radii: wp.array(dtype=wp.float32),
):
    k = wp.tid()
    s = leaf_sphere[k]
    node_centres[leaf_node[k]] = sphere_centres[s]
    node_radii[leaf_node[k]] = sphere_radii[s]


@wp.kernel
def tree_refit_kernel(
    level_nodes: wp.array(dtype=wp.int32),
    level_start: int,
    child_start: wp.array(dtype=wp.int32),
    child_count: wp.array(dtype=wp.int32),
    child_index: wp.array(dtype=wp.int32),
    anchor_weight: wp.array(dtype=wp.float32),
    mode: int,
    radius_pad: float,
    node_centres: wp.array(dtype=wp.vec3),
    node_radii: wp.array(dtype=wp.float32),
):
    """Refit one height level of a sphere tree from its (already refit) children.

    Anchored (mode 0): centre = fixed convex weights times the child centres. Pair (mode 1): the
    children merged one at a time by :func:`merge_sphere_pair`. Min (mode 2): whichever of the
    two gives the smaller radius. The radius is always re-taken as the max over children of
    (|centre - child centre| + child radius), so every child is bounded for any positions;
    ``radius_pad`` (relative) absorbs float32 rounding.
    """
    node = level_nodes[level_start + wp.tid()]
    first = child_start[node]
    count = child_count[node]
    anchored = wp.vec3(0.0, 0.0, 0.0)
    for k in range(count):
        anchored += anchor_weight[first + k] * node_centres[child_index[first + k]]
    ch0 = child_index[first]
    pair = node_centres[ch0]
    pr = node_radii[ch0]
    for k in range(1, count):
        ch = child_index[first + k]
        m = merge_sphere_pair(pair, pr, node_centres[ch], node_radii[ch])
        pair = wp.vec3(m[0], m[1], m[2])
        pr = m[3]
    ra = wp.float32(0.0)
    rp = wp.float32(0.0)
    for k in range(count):
        ch = child_index[first + k]
        ra = wp.max(ra, wp.length(anchored - node_centres[ch]) + node_radii[ch])
        rp = wp.max(rp, wp.length(pair - node_centres[ch]) + node_radii[ch])
    c = anchored
    r = ra
    if mode == 1 or (mode == 2 and rp < ra):
        c = pair
        r = rp
    node_centres[node] = c
    node_radii[node] = r * (1.0 + radius_pad)


# ---- receiver clusters and the cut --------------------------------------------------------
@wp.kernel
def cluster_bounds_kernel(
    points: wp.array(dtype=wp.vec3),
    cluster_start: wp.array(dtype=wp.int32),
    cluster_vertices: wp.array(dtype=wp.int32),
    representative: wp.array(dtype=wp.int32),
    radius_pad: float,
    centres: wp.array(dtype=wp.vec3),
    radii: wp.array(dtype=wp.float32),
    representative_points: wp.array(dtype=wp.vec3),
):
    """Bounding sphere of each receiver cluster: centre = mean point, radius = max distance."""
    c = wp.tid()
    first = cluster_start[c]
    last = cluster_start[c + 1]
    acc = wp.vec3(0.0, 0.0, 0.0)
    for k in range(first, last):
        acc += points[cluster_vertices[k]]
    centre = acc / float(wp.max(last - first, 1))
    r = wp.float32(0.0)
    for k in range(first, last):
        r = wp.max(r, wp.length(points[cluster_vertices[k]] - centre))
    centres[c] = centre
    radii[c] = r * (1.0 + radius_pad)
    representative_points[c] = points[representative[c]]


@wp.func
def cut_accept(node_centre: wp.vec3, node_radius: float, cluster_centre: wp.vec3, cluster_radius: float, sin_theta_max: float) -> bool:
    """Eq. 36: the node subtends less than theta_max over the whole receiver cluster.

    ``r_i < sin(theta_max) * (|P_i - p_R| - r_R)``.
    """
    return node_radius < sin_theta_max * (wp.length(node_centre - cluster_centre) - cluster_radius)


@wp.kernel
def cut_kernel(
    cluster_centres: wp.array(dtype=wp.vec3),
    cluster_radii: wp.array(dtype=wp.float32),
    node_centres: wp.array(dtype=wp.vec3),
    node_radii: wp.array(dtype=wp.float32),
    child_count: wp.array(dtype=wp.int32),
    skip: wp.array(dtype=wp.int32),
    sin_theta_max: float,
    cut_nodes: wp.array2d(dtype=wp.int32),
    cut_count: wp.array(dtype=wp.int32),
    cut_overflow: wp.array(dtype=wp.int32),
):
    """Per receiver cluster, the cut of the tree (nodes in depth-first preorder).

    Stackless traversal: nodes are stored in preorder, a node's first child is the next node
    and ``skip[i]`` is the first node after its subtree. A node that passes eq. 36, or a leaf,
    is emitted and its subtree skipped; otherwise the walk descends. Entries after the last
    are -1; a cut longer than the row sets ``cut_overflow`` to the full length.
    """
    c = wp.tid()
    pc = cluster_centres[c]
    rc = cluster_radii[c]
    capacity = cut_nodes.shape[1]
    n = wp.int32(0)
    i = wp.int32(0)
    node_count = node_centres.shape[0]
    while i < node_count:
        if child_count[i] == 0 or cut_accept(node_centres[i], node_radii[i], pc, rc, sin_theta_max):
            if n < capacity:
                cut_nodes[c, n] = i
            n += 1
            i = skip[i]
        else:
            i = i + 1
    for k in range(n, capacity):
        cut_nodes[c, k] = -1
    cut_count[c] = wp.min(n, capacity)
    cut_overflow[c] = wp.where(n > capacity, n, 0)

"""Blocker sphere sets: construction, attachment, hierarchy and receiver clusters (SHEXP, sec. 6).

Ren et al. 2006 ("Real-time soft shadows in dynamic scenes using spherical harmonic
exponentiation") shadow with sets of spheres that *bound* each blocker: every point of the
solid lies in some sphere, so no light leaks through, while the outside volume is small so
shadows are not too big. This package fits those spheres to a triangle mesh, computes the
coordinates that attach them to it, and builds the hierarchy and receiver clusters; the SHEXP
maths (log-space accumulation) and the scene's blocker model live in
:mod:`warpshade.methods.shexp`.

Construction (:func:`fit_spheres`). The variational Lloyd-style construction of sec. 6.2
(:mod:`._fit` has the details): flood-fill clustering of surface
and interior samples by outside-volume cost, Powell centre updates minimising the outside volume
of each cluster's bounding sphere (all clusters in lockstep, the objective evaluated by a Warp
kernel on an occupancy grid; scipy's Powell is the reference it is tested against), and cluster
teleportation accepted only when the error drops.
The error reported is the paper's

    E = sum_i V(S_i - T) / V(T)          (eq. 35 over the object's volume, as in Figure 4)

and also the union form ``V(union_i S_i - T) / V(T)`` (no double counting where spheres
overlap outside T). Both come from :func:`outside_volume`, a randomised quasi-Monte Carlo
estimator independent of the grid estimator the optimisation uses: scrambled-Sobol points
mapped volume-preservingly into each ball are classified inside/outside T by a Warp kernel
(fast generalised winding number over the mesh BVH, so overlapping closed components form
their union); the standard error is taken across independent scramblings. V(T) is estimated
the same way in the bounding box.

Closed meshes only, by default: a sphere set bounds a *solid*. An open mesh (a cloth sheet, a
ground plane) raises ValueError naming the mesh, unless ``open_mesh="shell"``, which bounds the
shell of half-thickness ``shell_thickness`` around the surface instead (for thin blockers that
must cast shadows).

Attachment (:mod:`._attach`). Coordinates that carry a fitted centre along with its mesh:
mean value coordinates (MVC) w.r.t. the fit-pose mesh (on a mesh of several closed parts, the
part holding most of the sphere's samples), optionally pre-multiplied by per-vertex bone
weights into a few (bone, weighted bind-space point) pairs -- exactly the MVC of the skinned
mesh when every bone is kept; linear blend skinning of the centre with its cluster's mean skin
weights; or, for open shells, a barycentric point plus an offset fixed in the nearest
triangle's frame. Which mesh of a scene gets which, and the per-frame animation on the device,
are SHEXP's blocker model (:mod:`warpshade.methods.shexp._spheres`); nothing in this package
reads a scene.

Hierarchy (:func:`build_sphere_tree`, :class:`SphereTree`, :class:`SphereTreeRefit`).
Bottom-up Lloyd clustering of sphere centres with branching about 4 (sec. 6.3), each parent's
centre optimised by Powell to minimise the radius bounding its children; per frame a Warp
kernel refits parents bottom-up with a bound that is valid for any child positions.

Receivers (:func:`cluster_receivers`, :class:`ReceiverBounds`, :class:`HierarchyCut`). Lloyd
clusters of receiver vertices with per-frame bounding spheres and representative vertices, and
the per-cluster cut of eq. 36 as flat arrays the shading kernel loops over.

Every kernel has a float64 NumPy reference (``*_reference``,
:meth:`ReceiverClusters.bounds_f64`) that the tests compare with.

Typical use (precompute once, cache the ``to_arrays()`` dicts; then per frame)::

    sphere_set = fit_spheres(points, faces, 32, name="/World/Body")
    tree = build_sphere_tree(sphere_set.centres, sphere_set.radii)
    clusters = cluster_receivers(receiver_points, mesh_offsets, vertices_per_cluster=300)
    refit = SphereTreeRefit(tree, device)
    bounds = ReceiverBounds(clusters, device)
    cut = HierarchyCut(refit, clusters.cluster_count, theta_max_degrees=25.0)
    # per frame: kernels on fixed buffers only
    refit.launch(sphere_centres, sphere_radii)   # wp arrays (S,) vec3 / float32
    bounds.launch(points)                        # wp.array(vec3) (V,)
    cut.launch(bounds.centres, bounds.radii)     # cut.cut_nodes (C, capacity), cut.cut_count (C,)
"""

from ._core import (
    DEFAULT_GRID_CELLS,
    GRID_CELLS_PER_SPHERE,
    OutsideVolume,
    SphereSet,
    coverage_gap,
    coverage_gap_f64,
    fit_spheres,
    outside_volume,
    solid_volume,
)
from ._fit import Solid, make_solid
from ._kernels import cut_accept, merge_sphere_pair
from ._tree import (
    DEFAULT_THETA_MAX_DEGREES,
    REFIT_MODES,
    HierarchyCut,
    ReceiverBounds,
    ReceiverClusters,
    SphereTree,
    SphereTreeRefit,
    build_sphere_tree,
    cluster_receivers,
    cut_f64,
    refit_f64,
)

__all__ = [
    "DEFAULT_GRID_CELLS",
    "DEFAULT_THETA_MAX_DEGREES",
    "GRID_CELLS_PER_SPHERE",
    "REFIT_MODES",
    "HierarchyCut",
    "OutsideVolume",
    "ReceiverBounds",
    "ReceiverClusters",
    "Solid",
    "SphereSet",
    "SphereTree",
    "SphereTreeRefit",
    "build_sphere_tree",
    "cluster_receivers",
    "coverage_gap",
    "coverage_gap_f64",
    "cut_accept",
    "cut_f64",
    "fit_spheres",
    "make_solid",
    "merge_sphere_pair",
    "outside_volume",
    "refit_f64",
    "solid_volume",
]

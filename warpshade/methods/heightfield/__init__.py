"""Dynamic height fields shaded with reflectance product operators (Nowrouzezahrai et al. 2009,
eq. 4-5 and sec. 7 / Fig. 11, after Snyder and Nowrouzezahrai 2008).

A height field is a regular G x G grid mesh (row-major vertices, row r along +y, column c along
+x, Z-up; :mod:`warpshade.io._heightfield`) whose heights change every frame. Two frame stages:

``heightfield.visibility`` -- world-frame SH visibility from horizon angles (eq. 4-5), all in
Warp kernels per frame:

1. the frame's heights (the z of ``points``) -> a max pyramid: level k holds the maximum height
   over 2^k x 2^k vertices (:func:`._model.pyramid_levels`);
2. at every texel of an R x R visibility grid (``resolution``: sub-sampled, corners on the grid
   corners) and for each of A azimuths ``phi_i = 2 pi i / A`` (``azimuths``), the horizon: the
   largest slope ``(H - h0) / d`` of the pyramid over a march with doubling distance
   (``d_j = spacing * 2^(j / q)``, q = ``samples_per_octave``), each sample reading the
   maximum of the pyramid cell holding it, on the level whose cell side is ``footprint`` times
   the step to the next sample (:func:`._model.march_plan`; ``footprint = 1`` is conservative: no gaps
   along the march, but the cell's maximum raises the horizon by about 3.5 degrees on the
   water; the default 0.5 halves that bias; ``benchmarks/bench_heightfield.py`` measured
   q = 1, 0.5 as cheapest with no loss against the glossy reference). The march ends at the
   grid's edge: beyond it nothing blocks;
3. the visibility of the azimuthal wedge ``[phi_i - pi/A, phi_i + pi/A]`` is 0 below the horizon
   elevation and 1 above (eq. 4); its SH comes from a canonical wedge about phi = 0 tabulated
   over the sine of the horizon elevation (:func:`._model.wedge_table`, float64 Gauss-Legendre in
   cos(theta) with the azimuthal integral in closed form, built once at set-up) and placed by a
   z-rotation (``sh_rotate_z``); the wedges are summed (eq. 5). The kernel reads the canonical
   wedge's cosine coefficients (the sine terms vanish about phi = 0) and turns each azimuth's
   wedge with that azimuth's ``cos m phi``, ``sin m phi``. A march ends early once
   ``(top - h0) / d`` (``top`` the grid's highest height) cannot beat the slope found so far
   nor, with ``below = "open"``, the tangent plane's slope: no later sample could change the
   wedge. The kernel marches four azimuths in one pass over the samples (four independent
   chains of work per sample, which the CPU overlaps).

   Below the local tangent plane (``below``): ``"open"`` (default) counts directions under the
   tangent plane as open, the convention of ``rpo.visibility_traced`` and of eq. 1: per wedge
   ``W(z_h) + W(-1) - W(min(z_t, z_h))`` with ``z_t`` the sine of the tangent plane's elevation
   in that azimuth (so an unoccluded texel has V = 1 exactly); ``"blocked"`` keeps what the
   horizon says (the surface's first march step follows its tangent plane, so the lower
   hemisphere is mostly 0). The BRDF light factors vanish there either way; what differs is
   the SH ringing the truncated product sees (measured in ``benchmarks/bench_heightfield.py``).
4. outputs: ``texel_visibility`` (R*R, n*n) and, with ``per_vertex`` (default), ``visibility``
   (V, n*n): bilinear at every grid vertex, world frame, for ``rpo.shade`` with
   ``visibility_space = "world"`` and frames from ``ldprt.tangents``.

``heightfield.shade`` -- eq. 11 at every vertex, arranged for a height field (the paper
shades 512^2 vertices at full resolution over sub-sampled visibility):

* the lighting product ``g_c = l_c * v`` (one order-n SH product per channel) is formed at the
  *visibility* resolution and interpolated bilinearly (it is linear in v, so this equals the
  product of the interpolated visibility); radiance is then ``L_c = F_w(wo) . g_c`` since
  ``l . (F * v) = F . (l * v)`` (the Gaunt coefficients are symmetric). The lighting is the
  same at every texel, so each frame first writes the product with ``l_c`` as an n^2 x n^2
  matrix (by columns) and a texel's product is then n^2 vector multiply-adds per channel;
* one shading thread covers a run of vertices along a grid row: the products are interpolated
  along the texel columns once per column the run crosses, then along the row per vertex;
* per vertex, the tangent frame is chosen about the normal so that the view lies in its x-z
  plane: the local view is ``(sin t, 0, cos t)`` and ``F(wo)`` of the operators (``sum_b (w_b .
  y(wo)) u_b``) is a 1-D table over ``cos t`` (``view_table`` entries, linear interpolation),
  built once per BRDF; for an isotropic BRDF this is the same F as in any other frame about the
  normal. ``factors = "exact"`` tabulates the cosine-weighted BRDF's own SH projection instead
  of its rank-k factors (no SVD truncation, no view-factor fit);
* ``F`` is turned to the world by one SH rotation per vertex (trig-free zxzxz: the cosines and
  sines of the Euler angles come from the frame, the multiple angles by recurrence).

Views at or below a vertex's tangent plane give 0 (counted); negative radiance from SH ringing
is clamped (counted): :meth:`._stages.HeightFieldShadeStage.diagnostics`.

Modules, as in every method (``docs/adding-a-method.md``):

* :mod:`._stages` -- the two graph stages (the shading one shares RPO's glossy-stage base);
* :mod:`._kernels` -- the Warp kernels;
* :mod:`._model` -- what the stages build at set-up: the checked grid layout, the march, the
  wedge and view tables (a height field has no artifact that outlives a run);
* :mod:`._mirror` -- the float64 mirror of the kernels, the tests' oracle;
* :mod:`._rows` -- the settings the speed-vs-accuracy harness runs;
* :mod:`._budget` -- the candidate settings an error budget chooses from.

A declared dependency on a sibling method: the only one among the method packages
(:mod:`warpshade.methods`). This method is RPO on a height field, so it builds on
:mod:`warpshade.methods.rpo`: the operators (``OPERATORS``), the shading parameters
(``SHADE_PARAMS``) and the glossy-stage base (``GlossyStage``), and, for ``factors = "exact"``,
RPO's BRDF-table quadrature (``rpo._model.Z_NODES``, ``PHI_NODES``), so that both methods shade
one BRDF from one table.
"""

from ._model import GridLayout, grid_layout, march_plan, pyramid_levels, view_table, wedge_table
from ._mirror import shade_f64, visibility_f64
from ._rows import harness_rows
from ._stages import HeightFieldShadeStage, HeightFieldVisibilityStage

__all__ = [
    "GridLayout",
    "HeightFieldShadeStage",
    "HeightFieldVisibilityStage",
    "grid_layout",
    "harness_rows",
    "march_plan",
    "pyramid_levels",
    "shade_f64",
    "view_table",
    "visibility_f64",
    "wedge_table",
]

"""``brushed_aniso.anisobrdf`` -- a tabulated anisotropic BRDF in warpshade's own 4-D layout
(:mod:`warpshade.scene._tabulated_aniso`), written from an analytic anisotropic microfacet model with
a shadowing term (no measured anisotropic file can be fetched here), for the measured anisotropic
material of Wang et al. 2009 (sec. 4.2, eq. 13; ``stages/dish_sg_aniso_measured.toml``).

The model is :class:`warpshade.scene._materials.AnisotropicMicrofacet`, a brushed-metal-like
anisotropic Beckmann surface: ``D(h) F(v.h) G(v, s) / (4 (n.v)(n.s))`` with slope
``ANISO_ROUGHNESS`` along the tangent (+x, the UV tangent on the dish: around it, where brush marks
run) and ``ANISO_ROUGHNESS_Y`` across it, Schlick's Fresnel of ``ANISO_F0`` and Smith's separable
masking of the anisotropic Beckmann surface (the rational Lambda of each direction's projected
roughness; azimuth-dependent, so eq. 13's 1-D shadowing factor only approximates it). Grey (one
channel). Table size ``ANISO_DIMS`` (n_theta_h, n_phi_h, n_theta_d, n_phi_d): 1.3 MB. theta_d is the finest axis:
measured (linear look-up against the model over 40000 random direction pairs), relative RMS 0.26 at
(32, 32, 24, 12), 0.06 at (32, 32, 48, 12) and 0.052 at (24, 24, 48, 12); doubling phi_h or theta_h
instead changes nothing.
"""

from __future__ import annotations

import os

from ...scene._materials import AnisotropicMicrofacet
from ...scene._tabulated_aniso import tabulate_anisotropic, write_anisotropic_table

ANISO_FILE = "brushed_aniso.anisobrdf"
ANISO_DIMS = (24, 24, 48, 12)
ANISO_ROUGHNESS = 0.08
ANISO_ROUGHNESS_Y = 0.32
ANISO_F0 = 0.5


def aniso_model() -> AnisotropicMicrofacet:
    """The analytic model the bundled table samples."""
    return AnisotropicMicrofacet(roughness=ANISO_ROUGHNESS, roughness_y=ANISO_ROUGHNESS_Y, f0=ANISO_F0)


def make_aniso_table(out_dir: str) -> str:
    table = tabulate_anisotropic(aniso_model(), ANISO_DIMS)
    return str(write_anisotropic_table(os.path.join(out_dir, ANISO_FILE), table))

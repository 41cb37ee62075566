"""``measured_coating.binary`` -- a tabulated isotropic BRDF in the MERL binary layout, written from
an analytic model with a shadowing term (no measured file can be fetched here), for the measured
materials of Wang et al. 2009 (sec. 4.2, eq. 13; ``stages/dish_sg_measured.toml``).

The model is eq. 13 itself (:class:`warpshade.methods.sg._brdf.TabulatedMicrofacet`):
``F(|i.h|, 1.33) S(o) S(i) D(h) / (pi (n.i)(n.o))`` with the normalised Beckmann NDF of slope
``MEASURED_ROUGHNESS``, ``D = exp(-tan^2 theta_h / m^2) / (pi m^2 cos^4 theta_h)``, and the Smith
shadowing factor of a Beckmann surface of slope ``MEASURED_SHADOW_ROUGHNESS`` (the rational
Lambda), ``S(theta) = 1 / (1 + Lambda(theta))``, both sampled at 721 angles over [0, pi/2]; grey
(the same in the three channels). Table size ``MEASURED_DIMS`` (n_theta_h, n_theta_d, n_phi_d):
a coarse MERL-layout grid (the database's is 90 x 90 x 180, 35 MB) that keeps the bundled file at
166 kB; its theta_h cells are the MERL ones (square-root spacing, fine near the peak).
"""

from __future__ import annotations

import os

import numpy as np

from ...methods.sg._brdf import TabulatedMicrofacet
from ...scene._tabulated import write_merl

MEASURED_FILE = "measured_coating.binary"
MEASURED_DIMS = (24, 12, 24)
MEASURED_ROUGHNESS = 0.2
MEASURED_SHADOW_ROUGHNESS = 0.35
MEASURED_ETA = 1.33


def measured_ndf(theta_h) -> np.ndarray:
    """The model's normalised Beckmann NDF at polar angles of h (radians)."""
    m = MEASURED_ROUGHNESS
    c = np.cos(np.minimum(theta_h, 0.5 * np.pi - 1e-6))
    tan2 = (1.0 - c * c) / (c * c)
    return np.exp(-tan2 / m**2) / (np.pi * m**2 * c**4)


def measured_shadowing(theta) -> np.ndarray:
    """The model's Smith shadowing factor ``1 / (1 + Lambda)`` (Beckmann, rational fit), in [0, 1]."""
    tan = np.tan(np.minimum(theta, 0.5 * np.pi - 1e-6))
    a = 1.0 / (MEASURED_SHADOW_ROUGHNESS * np.maximum(tan, 1e-12))
    lam = np.where(a < 1.6, (1.0 - 1.259 * a + 0.396 * a * a) / (3.535 * a + 2.181 * a * a), 0.0)
    return np.clip(1.0 / (1.0 + np.maximum(lam, 0.0)), 0.0, 1.0)


def measured_model() -> TabulatedMicrofacet:
    theta = np.linspace(0.0, 0.5 * np.pi, 721)
    return TabulatedMicrofacet(theta_h=theta, ndf_values=measured_ndf(theta), shadow_theta=theta,
                               shadow_values=measured_shadowing(theta), eta=MEASURED_ETA)


def make_measured(out_dir: str) -> str:
    return str(write_merl(os.path.join(out_dir, MEASURED_FILE), measured_model(), MEASURED_DIMS))

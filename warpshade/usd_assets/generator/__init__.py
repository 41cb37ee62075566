"""The generator of the bundled scenes in ``warpshade/usd_assets/`` (:func:`warpshade.io.bundled_asset_directory`).

Run ``python -m warpshade.usd_assets.generator [--scenes NAME ...] [--out DIR]``: by default it
writes ``sky.hdr`` and every scene of ``SCENES`` into the bundled directory; ``ripples`` and
``sunlit`` are written only on request (``--scenes ripples sunlit``), and so are the Newton-simulated
cloth clips ``cloth_train`` and ``cloth_heldout`` (they need the ``sim`` extra and minutes of CPU) and
the SVBRDF texture of measured materials ``svbrdf_rings.svbrdf`` (``--scenes svbrdf``, :mod:`.svbrdf`;
not a USD scene).

Every scene is Z-up, in metres (``metersPerUnit = 1``), 24 frames per second, time codes
0..59 (60 frames) for animated scenes unless said otherwise below, and has:

* a ``DomeLight`` (/World/Sky) whose lat-long texture ``sky.hdr`` (64 x 128, Radiance RGBE) is
  a procedural sky with a soft sun, written by :mod:`.sky`; the dome carries USD's
  ``rotateX:orientToStageUpAxis`` op so its +Y pole points up (+Z);
* a ``Camera`` (/World/Camera) framing the action;
* meshes only (no implicit prims), with per-vertex ``displayColor`` or a UsdPreviewSurface.

Modules: :mod:`.writing` (stages, meshes, ground, camera, rounding, saving), :mod:`.sky`,
:mod:`.shapes` (mesh builders), :mod:`.skeletons` (rigs, skinning, characters), :mod:`.motions`
(range-of-motion clips and motion libraries), and one module per scene, whose docstring
describes it: :mod:`.blockers`, :mod:`.figure` (``figure``, ``figure_train``, ``figure_walk``),
:mod:`.figure_orbit`, :mod:`.cloth`, :mod:`.cloth_clips` (``cloth_train``, ``cloth_heldout``), :mod:`.bend`,
:mod:`.wanderer` (``wanderer_train``, ``wanderer_test``), :mod:`.ripples`, :mod:`.sunlit`, :mod:`.dish`, :mod:`.measured`
(a MERL-layout table, not a USD scene), :mod:`.aniso_table` (``--scenes aniso_table``: an anisotropic
table in warpshade's own layout, :mod:`warpshade.scene._tabulated_aniso`; not a USD scene; its
reproduction is tested in ``tests/test_aniso_table.py``).

Output is deterministic on one machine: coordinates, weights and quaternions are rounded to 1e-4
(camera matrices to 1e-6) before they are written, so the files only change when the generator
changes. Across machines numpy's SIMD transcendental functions and the BLAS kernels differ by an
ulp or so, which can reach the bytes of the unrounded float tables (the MERL file's doubles differ
by 1e-13 between an AVX-512 and an AVX2 host); ``tests/test_usd_assets.py``,
``tests/test_sunlit_asset.py`` and the tests of the tables regenerate the files and compare their
values (``tests/asset_compare.py``: structure, topology and metadata exactly, floating values
within stated tolerances), not their bytes. The binary ``.usdc`` (crate) files may change with a
USD release that writes another crate version.

This package writes USD, so it imports ``pxr``: it is a tool at the top of the layer order, beside
:mod:`warpshade.cli` (``warpshade/__init__.py``), and nothing in warpshade imports it.
"""

from __future__ import annotations

import os

from ...io import bundled_asset_directory
from .bend import make_bend
from .blockers import make_blockers
from .cloth import make_cloth
from .cloth_clips import make_cloth_heldout, make_cloth_train
from .dish import make_dish
from .measured import make_measured
from .aniso_table import make_aniso_table
from .figure import make_figure, make_figure_train, make_figure_walk
from .figure_orbit import make_figure_orbit
from .ripples import make_ripples
from .sky import write_sky
from .sunlit import make_sunlit
from .svbrdf import make_svbrdf
from .wanderer import make_wanderer_test, make_wanderer_train

#: The scenes written by default (``ripples``, ``sunlit``, ``cloth_train``, ``cloth_heldout``, the
#: SVBRDF texture ``svbrdf`` and the anisotropic table ``aniso_table`` are written on request).
SCENES = ("blockers", "figure", "figure_train", "figure_walk", "figure_orbit", "cloth", "bend", "wanderer_train", "wanderer_test",
          "dish", "measured")

#: Scene name -> the function that writes it into a directory (returns the written path(s)).
MAKERS = {
    "ripples": make_ripples,
    "blockers": make_blockers,
    "figure_orbit": make_figure_orbit,
    "figure": make_figure,
    "figure_train": make_figure_train,
    "figure_walk": make_figure_walk,
    "cloth": make_cloth,
    "cloth_train": make_cloth_train,
    "cloth_heldout": make_cloth_heldout,
    "bend": make_bend,
    "wanderer_train": make_wanderer_train,
    "wanderer_test": make_wanderer_test,
    "sunlit": make_sunlit,
    "dish": make_dish,
    "measured": make_measured,
    "aniso_table": make_aniso_table,
    "svbrdf": make_svbrdf,
}


def generate(out_dir: str | None = None, scenes=SCENES) -> list[str]:
    """Write the sky texture and the named scenes into ``out_dir`` (default: the bundled
    directory); returns the written paths."""
    out_dir = bundled_asset_directory() if out_dir is None else out_dir
    os.makedirs(out_dir, exist_ok=True)
    written = [write_sky(out_dir)]
    for name in scenes:
        result = MAKERS[name](out_dir)
        written.extend([result] if isinstance(result, str) else result)
    return written


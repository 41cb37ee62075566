"""warpshade: soft shadows and relighting for animated USD scenes on NVIDIA Warp.

The package is layered; a module imports only modules of its own layer or of layers to its
left, at module level and inside functions alike (``tests/test_layers.py`` checks it, and that
there is no import cycle)::

    _wp, _fileio, _hashing, _limits, tasks -> basis -> geometry -> scene -> io -> render -> transfer -> methods -> reference -> graph -> measure -> cli, usd_assets

* ``_wp``, ``_fileio``, ``_hashing``, ``_limits``, ``tasks``: Warp set-up and launch helpers,
  atomic files, content hashes, the sizes refused before allocating, the executor that runs
  precompute tasks serially, in local worker processes or on a Dask cluster;
* ``basis``: spherical functions (SH, ZH, quadrature), no scene objects;
* ``geometry``: meshes on the device: BVH, normals, skinning, tangent frames, sphere sets;
* ``scene``: the static ``Scene``, the per-frame ``FrameState`` and the kernels that fill it,
  lights and their per-frame device form, materials;
* ``io``: USD and images in and out (with the asset generator, the only place that imports ``pxr``);
* ``render``: the ray-cast camera (G-buffers of primary hits), tone mapping, PNG previews: below
  the methods and the reference, which shade its G-buffers per pixel;
* ``transfer``: ray-traced visibility and transfer, SSDFs;
* ``methods``: one package per technique, each ``stages``/``kernels``/``model``/``reference``/
  ``rows``/``budget``;
* ``reference``: brute-force ray-traced ground truth;
* ``graph``: the stage-graph runtime (TOML specs, cache, precompute, the recorded frame);
* ``measure``: ground-truth caches, errors, pictures, outputs, error budgets, harness settings;
* ``cli``: the ``warpshade`` command;
* ``usd_assets``: the bundled scenes (package data, ``bundled:NAME``) and their generator
  (``python -m warpshade.usd_assets.generator``), a tool at the top like ``cli`` that writes USD
  and so imports ``pxr``; nothing in warpshade imports it.

The top-level ``warpshade`` module holds only ``__version__``: every public name has one import path, in
the package of its layer (``warpshade.io.load_usd``, ``warpshade.graph.load``, ...; ``tests/test_public_surface.py``).
"""

from __future__ import annotations

__version__ = "0.1.0"

__all__ = ["__version__"]

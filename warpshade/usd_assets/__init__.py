"""The bundled scenes, shipped as package data: ``*.usda`` / ``*.usdc`` stages with their skies
(``*.hdr``) and textures (``*.png``), loaded with the scene spec ``bundled:NAME``
(:func:`warpshade.io.resolve_scene_path`; the directory is :func:`warpshade.io.bundled_asset_directory`).

:mod:`warpshade.usd_assets.generator` writes them: ``python -m warpshade.usd_assets.generator``.
"""

"""BRDFs by name: what stage graphs (``[[material]]``) and stage parameters (``brdf = "ggx"``) build.

The analytic models of :mod:`.materials` and tabulated BRDFs read from a file in the MERL binary
layout (:mod:`.tabulated`).
"""

from __future__ import annotations

from .materials import BRDF, BlinnPhong, Lambert, Microfacet, Phong

__all__ = ["BRDF_KEYS", "BRDF_KINDS", "brdf_from_spec", "make_brdf"]

#: BRDF kinds :func:`make_brdf` builds ("microfacet" is GGX).
BRDF_KINDS = ("lambert", "phong", "blinn-phong", "ggx", "microfacet", "beckmann", "tabulated")
#: Keys of a BRDF description (:func:`make_brdf`).
BRDF_KEYS = ("brdf", "roughness", "exponent", "f0", "specular", "albedo", "file", "channel", "interpolation")


def make_brdf(kind: str, roughness: float = 0.3, exponent: float = 30.0, f0: float = 0.04, specular: float = 1.0,
              albedo: float = 1.0, file=None, channel: str = "luminance", interpolation: str = "nearest",
              where: str = "brdf") -> BRDF:
    """A BRDF by name: "lambert" (albedo), "phong" / "blinn-phong" (exponent, specular), "ggx" or
    "microfacet" / "beckmann" (roughness, f0, specular), "tabulated" (``file`` in the MERL binary
    layout, :mod:`warpshade.scene.tabulated`; channel, interpolation).

    Raises:
        ValueError: naming ``where``, for an unknown kind, a bad value or a bad file.
    """
    try:
        if kind == "lambert":
            return Lambert(albedo=float(albedo))
        if kind == "phong":
            return Phong(exponent=float(exponent), specular=float(specular))
        if kind == "blinn-phong":
            return BlinnPhong(exponent=float(exponent), specular=float(specular))
        if kind in ("ggx", "microfacet", "beckmann"):
            return Microfacet(roughness=float(roughness), distribution="beckmann" if kind == "beckmann" else "ggx",
                              f0=float(f0), specular=float(specular))
        if kind == "tabulated":
            if file is None:
                raise ValueError("a tabulated BRDF needs 'file' (a BRDF in the MERL binary layout)")
            from .tabulated import read_merl

            return read_merl(file, channel=channel, interpolation=interpolation)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: {exc}") from None
    raise ValueError(f"{where}: unknown BRDF {kind!r}; known: {', '.join(BRDF_KINDS)}")


def brdf_from_spec(table: dict, where: str = "brdf", base_dir=None) -> BRDF:
    """A BRDF from a table of :data:`BRDF_KEYS` (``brdf`` the kind; ``file`` relative to
    ``base_dir``). Unknown keys raise ValueError naming ``where``."""
    from pathlib import Path

    unknown = sorted(set(table) - set(BRDF_KEYS))
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; known: {list(BRDF_KEYS)}")
    if "brdf" not in table:
        raise ValueError(f"{where}: needs 'brdf = \"<kind>\"' ({', '.join(BRDF_KINDS)})")
    args = {k: v for k, v in table.items() if k != "brdf"}
    if args.get("file") is not None:
        p = Path(str(args["file"]))
        if not p.is_absolute() and base_dir is not None:
            p = Path(base_dir) / p
        args["file"] = str(p)
    return make_brdf(str(table["brdf"]), where=where, **args)

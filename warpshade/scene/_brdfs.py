"""BRDFs by name: what stage graphs (``[[material]]``) and stage parameters (``brdf = "ggx"``) build.

The analytic models of :mod:`._materials` and tabulated BRDFs read from a file in the MERL binary
layout (:mod:`._tabulated`).
"""

from __future__ import annotations

from ._materials import BRDF, BlinnPhong, Lambert, Microfacet, Phong

__all__ = ["BRDF_KEYS", "BRDF_KINDS", "BRDF_USES", "brdf_from_spec", "make_brdf"]

#: BRDF kinds :func:`make_brdf` builds ("microfacet" is GGX).
BRDF_KINDS = ("lambert", "phong", "blinn-phong", "ggx", "microfacet", "beckmann", "tabulated")
#: Keys of a BRDF description (:func:`make_brdf`).
BRDF_KEYS = ("brdf", "roughness", "exponent", "f0", "specular", "albedo", "file", "channel", "interpolation")
#: The keys each kind reads; a value given for another key is refused (it would be ignored).
BRDF_USES = {
    "lambert": ("albedo",),
    "phong": ("exponent", "specular"),
    "blinn-phong": ("exponent", "specular"),
    "ggx": ("roughness", "f0", "specular"),
    "microfacet": ("roughness", "f0", "specular"),
    "beckmann": ("roughness", "f0", "specular"),
    "tabulated": ("file", "channel", "interpolation"),
}
_DEFAULTS = {"roughness": 0.3, "exponent": 30.0, "f0": 0.04, "specular": 1.0, "albedo": 1.0, "file": None,
             "channel": "rgb", "interpolation": "nearest"}


def make_brdf(kind: str, roughness: float | None = None, exponent: float | None = None, f0: float | None = None,
              specular: float | None = None, albedo: float | None = None, file=None, channel: str | None = None,
              interpolation: str | None = None, where: str = "brdf") -> BRDF:
    """A BRDF by name: "lambert" (albedo), "phong" / "blinn-phong" (exponent, specular), "ggx" or
    "microfacet" / "beckmann" (roughness, f0, specular), "tabulated" (``file`` in the MERL binary
    layout, :mod:`warpshade.scene._tabulated`; channel, interpolation). Values left None take
    their defaults (roughness 0.3, exponent 30, f0 0.04, specular 1, albedo 1).

    Raises:
        ValueError: naming ``where``, for an unknown kind, a value the kind does not use
            (:data:`BRDF_USES`), a bad value or a bad file.
    """
    given = {"roughness": roughness, "exponent": exponent, "f0": f0, "specular": specular, "albedo": albedo,
             "file": file, "channel": channel, "interpolation": interpolation}
    if kind not in BRDF_USES:
        raise ValueError(f"{where}: unknown BRDF {kind!r}; known: {', '.join(BRDF_KINDS)}")
    unused = sorted(k for k, v in given.items() if v is not None and k not in BRDF_USES[kind])
    if unused:
        raise ValueError(f"{where}: brdf = {kind!r} does not use {unused} (it reads {list(BRDF_USES[kind])})")
    v = {k: _DEFAULTS[k] if x is None else x for k, x in given.items()}
    try:
        if kind == "lambert":
            return Lambert(albedo=float(v["albedo"]))
        if kind == "phong":
            return Phong(exponent=float(v["exponent"]), specular=float(v["specular"]))
        if kind == "blinn-phong":
            return BlinnPhong(exponent=float(v["exponent"]), specular=float(v["specular"]))
        if kind in ("ggx", "microfacet", "beckmann"):
            return Microfacet(roughness=float(v["roughness"]), distribution="beckmann" if kind == "beckmann" else "ggx",
                              f0=float(v["f0"]), specular=float(v["specular"]))
        if v["file"] is None:
            raise ValueError("a tabulated BRDF needs 'file' (a BRDF in the MERL binary layout)")
        from ._tabulated import read_merl

        return read_merl(v["file"], channel=v["channel"], interpolation=v["interpolation"])
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: {exc}") from None


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

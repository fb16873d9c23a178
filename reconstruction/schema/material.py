"""A material (``[material]`` of a simulated bench, a material TOML file), declared once: a name and a list of
lobes, each a table with ``type`` and that type's keys. :mod:`reconstruction.core.models` reads it (the keys of each
lobe type and what they are come from here). Colours are a number, 1 or 3 numbers, a list matching
``wavelengths_nm``, or ``{wavelengths_nm = [...], values = [...]}``."""

from typing import Annotated, Any

import msgspec
from msgspec import Meta

__all__ = ["LOBES", "MaterialFile", "lobe_keys"]


class Spectrum(msgspec.Struct, forbid_unknown_fields=True):
    wavelengths_nm: list[float]
    values: list[Annotated[float, Meta(ge=0.0)]]


ColourValue = Annotated[Annotated[float, Meta(ge=0.0)] | list[Annotated[float, Meta(ge=0.0)]] | Spectrum,
                        Meta(description="a number (grey), 3 numbers (RGB), or a spectrum", extra={"kind": "colour"})]
Number = Annotated[float, Meta(extra={"kind": "float"})]
Wavelengths = Annotated[list[float], Meta(description="the wavelengths (nm) of the colours given as plain lists")]


def _lobe(tag: str) -> dict[str, Any]:
    return {"tag": tag, "tag_field": "type", "forbid_unknown_fields": True}


class Lambert(msgspec.Struct, **_lobe("lambert")):
    albedo: ColourValue
    wavelengths_nm: Wavelengths | None = None


class OrenNayar(msgspec.Struct, **_lobe("oren_nayar")):
    albedo: ColourValue
    sigma_deg: Annotated[float, Meta(ge=0.0, le=90.0, description="roughness (degrees)", extra={"kind": "float"})]
    wavelengths_nm: Wavelengths | None = None


class Ggx(msgspec.Struct, **_lobe("ggx")):
    alpha: Annotated[float, Meta(gt=0.0, extra={"kind": "float"})]
    specular: ColourValue
    f0: Annotated[float, Meta(ge=0.0, le=1.0, description="Schlick Fresnel at normal incidence",
                              extra={"kind": "float"})] | None = None
    wavelengths_nm: Wavelengths | None = None


class Beckmann(msgspec.Struct, **_lobe("beckmann")):
    alpha: Annotated[float, Meta(gt=0.0, extra={"kind": "float"})]
    specular: ColourValue
    f0: Annotated[float, Meta(ge=0.0, le=1.0, extra={"kind": "float"})] | None = None
    wavelengths_nm: Wavelengths | None = None


class Phong(msgspec.Struct, **_lobe("phong")):
    exponent: Annotated[float, Meta(ge=0.0, extra={"kind": "float"})]
    specular: ColourValue
    wavelengths_nm: Wavelengths | None = None


class Retro(msgspec.Struct, **_lobe("retro")):
    exponent: Annotated[float, Meta(ge=0.0, extra={"kind": "float"})]
    amount: ColourValue
    wavelengths_nm: Wavelengths | None = None


class Tabulated(msgspec.Struct, **_lobe("tabulated")):
    path: Annotated[str, Meta(description="a MERL .binary table, relative to the file", extra={"kind": "path"})]
    scale: ColourValue | None = None
    wavelengths_nm: Wavelengths | None = None


class Nbrdf(msgspec.Struct, **_lobe("nbrdf")):
    path: Annotated[str, Meta(description="prefix of a neural BRDF's npy files (NAME_fc1.npy ...), relative to "
                                          "the file", extra={"kind": "prefix"})]
    scale: ColourValue | None = None
    wavelengths_nm: Wavelengths | None = None


LOBES = (Lambert, OrenNayar, Ggx, Beckmann, Phong, Retro, Tabulated, Nbrdf)
Lobe = Lambert | OrenNayar | Ggx | Beckmann | Phong | Retro | Tabulated | Nbrdf


class MaterialFile(msgspec.Struct, forbid_unknown_fields=True):
    """``[material]``: a sum of lobes."""

    name: Annotated[str, Meta(description="the material's name")] = "material"
    lobes: Annotated[list[Lobe], Meta(min_length=1)] = msgspec.field(default_factory=list)


def lobe_keys() -> dict[str, dict[str, tuple[bool, str]]]:
    """For each lobe type, its keys (``wavelengths_nm`` aside): (required, kind), kind "colour", "float", "path"
    or "prefix"."""
    import msgspec.inspect as mi

    out: dict[str, dict[str, tuple[bool, str]]] = {}
    for cls in LOBES:
        spec: dict[str, tuple[bool, str]] = {}
        for f in mi.type_info(cls).fields:
            if f.encode_name == "wavelengths_nm":
                continue
            t = f.type
            while isinstance(t, mi.UnionType) and any(isinstance(x, mi.NoneType) for x in t.types):
                t = next(x for x in t.types if not isinstance(x, mi.NoneType))
            kind = t.extra.get("kind", "float") if isinstance(t, mi.Metadata) and t.extra else "float"
            spec[f.encode_name] = (f.required, kind)
        out[cls.__struct_config__.tag] = spec
    return out

"""Material tags of :mod:`scenes` parts → Mitsuba BSDF dictionaries.

Every part carries one of four tags; each maps to a Mitsuba 3 BSDF:

========== ================================ ===========================================
tag        BSDF                              parameters (defaults, :class:`MaterialSettings`)
========== ================================ ===========================================
cardboard  Lambertian ``diffuse``            albedo 0.35 — brown kraft board in the blue
                                             (≈0.3–0.4 at 450 nm, ≈0.5 in the red)
tape       Lambertian ``diffuse``            albedo 0.55 — a roll of light paper/packing tape
metal      ``roughconductor`` GGX, Al        α = 0.25 (machined/bead-blasted aluminium)
knurled-   ``roughconductor`` GGX, Al        α = 0.5 — the knurl's facets at the scale of
metal                                        a pixel footprint, lumped into a rougher lobe
========== ================================ ===========================================

The albedos are assumptions (documented here and overridable), not
measurements.  All BSDFs are wrapped in ``twosided`` so that a mesh with an
inconsistent winding is still lit on both faces.

The renderer runs in an RGB variant; it evaluates a BSDF at the laser
wavelength by taking the RGB channel that contains it (blue < 490 nm ≤ green
< 580 nm ≤ red), see :func:`channel_for_wavelength`.  For the grey diffuse
materials this is exact; for aluminium it is the band-averaged complex index
of refraction of Mitsuba's ``Al`` data.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from scheimpflug.errors import MeshError

__all__ = [
    "MATERIALS",
    "MaterialSettings",
    "bsdf_dict",
    "channel_for_wavelength",
]

MATERIALS = ("cardboard", "knurled-metal", "metal", "tape")


@dataclass(frozen=True)
class MaterialSettings:
    """Parameters of the four material tags.

    Frozen; the defaults are the table of the module docstring (assumptions,
    not measurements).

    Parameters
    ----------
    cardboard_albedo : float, default 0.35
        Lambertian albedo of ``cardboard`` at the laser wavelength, in [0, 1] [-].
    tape_albedo : float, default 0.55
        Lambertian albedo of ``tape`` at the laser wavelength, in [0, 1] [-].
    metal_alpha : float, default 0.25
        GGX roughness α (≈ RMS facet slope) of ``metal``, in (0, 1] [-].
    knurled_alpha : float, default 0.5
        GGX roughness α of ``knurled-metal``, in (0, 1] [-].
    conductor : str, default "Al"
        Mitsuba conductor name for both metals (``Al``, ``Cr``, ``Ni`` ...).

    Raises
    ------
    ValueError
        When an albedo is outside [0, 1] or a roughness outside (0, 1].
    """

    cardboard_albedo: float = 0.35
    tape_albedo: float = 0.55
    metal_alpha: float = 0.25
    knurled_alpha: float = 0.5
    conductor: str = "Al"

    def __post_init__(self) -> None:
        for name in ("cardboard_albedo", "tape_albedo"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"MaterialSettings.{name} = {value!r}: an albedo must be in [0, 1]")
        for name in ("metal_alpha", "knurled_alpha"):
            value = getattr(self, name)
            if not 0.0 < value <= 1.0:
                raise ValueError(f"MaterialSettings.{name} = {value!r}: GGX α must be in (0, 1]")


def _diffuse(albedo: float) -> dict[str, Any]:
    return {"type": "diffuse", "reflectance": {"type": "rgb", "value": [albedo] * 3}}


def _conductor(alpha: float, material: str) -> dict[str, Any]:
    return {"type": "roughconductor", "material": material, "distribution": "ggx", "alpha": alpha}


def bsdf_dict(material: str, settings: MaterialSettings | None = None) -> dict[str, Any]:
    """Mitsuba BSDF dictionary (two-sided) for a material tag.

    Parameters
    ----------
    material : str
        One of ``cardboard``, ``tape``, ``metal``, ``knurled-metal``.
    settings : MaterialSettings, optional
        Albedos and roughnesses (defaults: the table in the module docstring).

    Returns
    -------
    dict
        ``{"type": "twosided", "material": {...}}``: a ``diffuse`` BSDF with a
        grey RGB reflectance for ``cardboard``/``tape``, a GGX
        ``roughconductor`` for ``metal``/``knurled-metal``.

    Raises
    ------
    MeshError
        For an unknown material tag.
    """
    s = settings or MaterialSettings()
    table = {
        "cardboard": lambda: _diffuse(s.cardboard_albedo),
        "tape": lambda: _diffuse(s.tape_albedo),
        "metal": lambda: _conductor(s.metal_alpha, s.conductor),
        "knurled-metal": lambda: _conductor(s.knurled_alpha, s.conductor),
    }
    if material not in table:
        raise MeshError(f"unknown material {material!r} (known: {', '.join(MATERIALS)})")
    return {"type": "twosided", "material": table[material]()}


def channel_for_wavelength(wavelength_nm: float) -> int:
    """RGB channel whose band holds a wavelength.

    Bands: blue < 490 nm ≤ green < 580 nm ≤ red.

    Parameters
    ----------
    wavelength_nm : float
        Laser wavelength [nm].

    Returns
    -------
    int
        Channel index (0 = R, 1 = G, 2 = B).
    """
    if wavelength_nm < 490.0:
        return 2
    return 1 if wavelength_nm < 580.0 else 0

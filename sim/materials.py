"""Material tags of :mod:`scenes` parts → Mitsuba BSDF dictionaries and interior media.

Every part carries one material tag.  Metals are opaque rough conductors;
the other tags are *translucent*: light enters them, scatters inside and
leaves again somewhere else.  The rig key ``[twin] subsurface`` chooses how the
twin renders a translucent tag: as an opaque Lambertian surface of the same
total reflectance (``false``, the ideal twin), or as a rough dielectric
boundary over a homogeneous scattering interior in which the light
random-walks (``true``, :mod:`sim.subsurface`).

Opaque surfaces
---------------
============= ================================ ============================================
tag           BSDF                              parameters (:class:`MaterialSettings`)
============= ================================ ============================================
metal         ``roughconductor`` GGX, Al        α = 0.25 (machined/bead-blasted aluminium)
knurled-metal ``roughconductor`` GGX, Al        α = 0.5 — the knurl's facets at the scale of
                                                a pixel footprint, lumped into a rougher lobe
cardboard     Lambertian ``diffuse``            albedo 0.35 — brown kraft board in the blue
                                                (≈ 0.3–0.4 at 450 nm, ≈ 0.5 in the red)
tape          Lambertian ``diffuse``            albedo 0.55 — a roll of light paper tape
paper         Lambertian ``diffuse``            the translucent medium's own total diffuse
                                                reflectance (table below); the same for
                                                ``white-plastic`` and ``marble``
============= ================================ ============================================

All opaque BSDFs are wrapped in ``twosided`` so that a mesh with an
inconsistent winding is still lit on both faces.

Translucent media (``subsurface = true``)
-----------------------------------------
Boundary: Mitsuba ``roughdielectric`` (GGX roughness α, relative index η) for
the light arriving from outside (its reflection is the surface gloss, its
transmission the light that enters).  Interior: homogeneous, reduced
scattering coefficient σ_s', absorption σ_a, Henyey–Greenstein g = 0 (the
similarity relation σ_s' = σ_s·(1 − g) replaces the strongly forward-peaked
scattering of fibres and pigments by an isotropic one of the same transport
mean free path 1/(σ_s' + σ_a); van de Hulst, *Multiple Light Scattering*,
1980).  Values at 450 nm:

============= ======== ========= ===== ===== ============ ===================================
tag           σ_s'     σ_a       η     α     R (normal    source
              [1/mm]   [1/mm]                incidence)
============= ======== ========= ===== ===== ============ ===================================
marble        3.00     0.0071    1.5   0.10  0.77         Jensen et al. 2001 (Table 1, blue
                                                          channel); α assumed (honed stone)
paper         53       0.12      1.5   0.30  0.76         KM coefficients of bleached office
                                                          paper at 457 nm (ISO brightness
                                                          ≈ 90 %): s ≈ 50 m²/kg, k ≈ 0.3 m²/kg
                                                          at 800 kg/m³, converted with
                                                          σ_s' ≈ 4/3·S, σ_a ≈ K/2 (assumed:
                                                          typical values, not one paper)
cardboard     23       1.26      1.5   0.30  0.35         assumed: KM s ≈ 25 m²/kg of
                                                          unbleached kraft at 700 kg/m³;
                                                          σ_a set so that R = the opaque
                                                          tag's albedo 0.35
tape          20       0.286     1.5   0.20  0.55         assumed: a crepe-paper (masking)
                                                          tape; σ_a set so that R = 0.55
white-plastic 2.5      0.003     1.49  0.10  0.83         assumed: white acetal (POM)-like
                                                          polymer; no measured set used
============= ======== ========= ===== ===== ============ ===================================

R is the total diffuse reflectance (surface gloss + subsurface) at normal
incidence computed by the twin's own walk (:func:`sim.subsurface.total_reflectance`,
2·10⁵ paths, walks up to 1024 events; ``benchmarks/bench_optics.py`` prints it); the
opaque stand-ins use it as their albedo.
Jensen, Marschner, Levoy, Hanrahan, "A practical model for subsurface light
transport", SIGGRAPH 2001.  No measured optical data set for kraft board,
masking tape or a particular white plastic was found; those rows are
order-of-magnitude assumptions and say so.

Speckle contrast (:data:`SPECKLE_CONTRAST`): light scattered once by a rough
metal keeps its polarisation (fully developed speckle, contrast 1); light that
scattered many times inside a translucent material is depolarised: two
independent speckle patterns of equal power in orthogonal polarisations give
contrast 1/√2 (Goodman, *Speckle Phenomena in Optics*, 2007, §3.4 / §4.x).  The
dielectric boundary's own gloss keeps contrast 1.

The renderer runs in an RGB variant; it evaluates a BSDF at the laser
wavelength by taking the RGB channel that contains it (blue < 490 nm ≤ green
< 580 nm ≤ red), see :func:`channel_for_wavelength`.  For the grey diffuse
materials this is exact; for aluminium it is the band-averaged complex index
of refraction of Mitsuba's ``Al`` data.  The media above are given at 450 nm
and used at any wavelength (a stated limitation).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from scheimpflug.errors import MeshError

__all__ = [
    "MATERIALS",
    "SPECKLE_CONTRAST",
    "TRANSLUCENT",
    "MaterialSettings",
    "Translucent",
    "bsdf_dict",
    "channel_for_wavelength",
    "is_translucent",
]

MATERIALS = ("cardboard", "knurled-metal", "marble", "metal", "paper", "tape", "white-plastic")

#: Depolarisation factor of the speckle contrast of each material's volume-scattered light
#: (metals: surface scattering, 1).  The rough dielectric boundary's gloss keeps 1.
SPECKLE_CONTRAST = {"metal": 1.0, "knurled-metal": 1.0, "cardboard": 1 / math.sqrt(2),
                    "tape": 1 / math.sqrt(2), "paper": 1 / math.sqrt(2),
                    "white-plastic": 1 / math.sqrt(2), "marble": 1 / math.sqrt(2)}


@dataclass(frozen=True)
class Translucent:
    """A translucent material: rough dielectric boundary over a homogeneous medium.

    Parameters
    ----------
    sigma_s_per_mm : float
        Scattering coefficient σ_s (reduced σ_s' when ``g`` = 0) [1/mm].
    sigma_a_per_mm : float
        Absorption coefficient σ_a [1/mm].
    g : float
        Henyey–Greenstein asymmetry, −1 < g < 1 [-].
    eta : float
        Refractive index of the interior relative to the outside (1 = matched) [-].
    alpha : float
        GGX roughness of the boundary [-].
    albedo : float
        Lambertian albedo of the opaque stand-in (``subsurface`` off) [-].
    source : str
        Where the numbers come from.

    Raises
    ------
    ValueError
        For a negative coefficient, |g| ≥ 1, η < 1 or α outside (0, 1].
    """

    sigma_s_per_mm: float
    sigma_a_per_mm: float
    g: float = 0.0
    eta: float = 1.5
    alpha: float = 0.3
    albedo: float = 0.5
    source: str = ""

    def __post_init__(self) -> None:
        if not (self.sigma_s_per_mm >= 0 and self.sigma_a_per_mm >= 0
                and self.sigma_s_per_mm + self.sigma_a_per_mm > 0):
            raise ValueError(f"Translucent: σ_s = {self.sigma_s_per_mm}, σ_a = "
                             f"{self.sigma_a_per_mm}: must be ≥ 0 with σ_s + σ_a > 0 [1/mm]")
        if not -1.0 < self.g < 1.0:
            raise ValueError(f"Translucent.g = {self.g}: must be in (−1, 1)")
        if not self.eta >= 1.0:
            raise ValueError(f"Translucent.eta = {self.eta}: must be ≥ 1 (interior denser)")
        if not 0.0 < self.alpha <= 1.0:
            raise ValueError(f"Translucent.alpha = {self.alpha}: GGX α must be in (0, 1]")
        if not 0.0 <= self.albedo <= 1.0:
            raise ValueError(f"Translucent.albedo = {self.albedo}: must be in [0, 1]")

    @property
    def sigma_t_per_mm(self) -> float:
        """Extinction σ_t = σ_s + σ_a [1/mm]."""
        return self.sigma_s_per_mm + self.sigma_a_per_mm

    @property
    def single_scattering_albedo(self) -> float:
        """σ_s / σ_t [-]."""
        return self.sigma_s_per_mm / self.sigma_t_per_mm


#: Translucent tags and their media at 450 nm (module docstring for the sources).
TRANSLUCENT: dict[str, Translucent] = {
    "marble": Translucent(3.00, 0.0071, 0.0, 1.5, 0.10, 0.77,
                          "Jensen et al. 2001, Table 1 (blue); α assumed"),
    "paper": Translucent(53.0, 0.12, 0.0, 1.5, 0.30, 0.76,
                         "KM s ≈ 50 m²/kg, k ≈ 0.3 m²/kg at 457 nm, 800 kg/m³ (typical, assumed)"),
    "cardboard": Translucent(23.0, 1.26, 0.0, 1.5, 0.30, 0.35,
                             "assumed (unbleached kraft); σ_a gives R = 0.35"),
    "tape": Translucent(20.0, 0.286, 0.0, 1.5, 0.20, 0.55,
                        "assumed (crepe-paper tape); σ_a gives R = 0.55"),
    "white-plastic": Translucent(2.5, 0.003, 0.0, 1.49, 0.10, 0.83,
                                 "assumed (white acetal-like polymer)"),
}


@dataclass(frozen=True)
class MaterialSettings:
    """Parameters of the material tags.

    Frozen; the defaults are the tables of the module docstring (assumptions,
    not measurements, except where a source is named).

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
    translucent : Mapping[str, Translucent], default TRANSLUCENT
        Interior media of the translucent tags (:data:`TRANSLUCENT`).

    Raises
    ------
    ValueError
        When an albedo is outside [0, 1], a roughness outside (0, 1] or a translucent
        tag unknown.
    """

    cardboard_albedo: float = 0.35
    tape_albedo: float = 0.55
    metal_alpha: float = 0.25
    knurled_alpha: float = 0.5
    conductor: str = "Al"
    translucent: Mapping[str, Translucent] = field(default_factory=lambda: dict(TRANSLUCENT))

    def __post_init__(self) -> None:
        for name in ("cardboard_albedo", "tape_albedo"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"MaterialSettings.{name} = {value!r}: an albedo must be in [0, 1]")
        for name in ("metal_alpha", "knurled_alpha"):
            value = getattr(self, name)
            if not 0.0 < value <= 1.0:
                raise ValueError(f"MaterialSettings.{name} = {value!r}: GGX α must be in (0, 1]")
        unknown = sorted(set(self.translucent) - set(TRANSLUCENT))
        if unknown:
            raise ValueError(f"MaterialSettings.translucent: unknown tag {unknown[0]!r} "
                             f"(translucent tags: {', '.join(sorted(TRANSLUCENT))})")

    def medium(self, material: str) -> Translucent | None:
        """The interior medium of a tag, or None for the metals.

        Parameters
        ----------
        material : str
            A material tag.

        Returns
        -------
        Translucent or None
            Its medium (also when ``subsurface`` is off).
        """
        return self.translucent.get(material) if is_translucent(material) else None


def is_translucent(material: str) -> bool:
    """Whether a material tag has a scattering interior (everything but the metals).

    Parameters
    ----------
    material : str
        A material tag.

    Returns
    -------
    bool
        True for cardboard, tape, paper, white plastic and marble.
    """
    return material in TRANSLUCENT


def _diffuse(albedo: float) -> dict[str, Any]:
    return {"type": "diffuse", "reflectance": {"type": "rgb", "value": [albedo] * 3}}


def _conductor(alpha: float, material: str) -> dict[str, Any]:
    return {"type": "roughconductor", "material": material, "distribution": "ggx", "alpha": alpha}


def _boundary(medium: Translucent) -> dict[str, Any]:
    if medium.eta == 1.0:
        return {"type": "null"}
    return {"type": "roughdielectric", "distribution": "ggx", "alpha": medium.alpha,
            "int_ior": medium.eta, "ext_ior": 1.0}


def _opaque_albedo(material: str, s: MaterialSettings) -> float:
    if material == "cardboard":
        return s.cardboard_albedo
    if material == "tape":
        return s.tape_albedo
    return s.translucent[material].albedo


def bsdf_dict(material: str, settings: MaterialSettings | None = None,
              subsurface: bool = False) -> dict[str, Any]:
    """Mitsuba BSDF dictionary for a material tag.

    Parameters
    ----------
    material : str
        One of :data:`MATERIALS`.
    settings : MaterialSettings, optional
        Albedos, roughnesses and media (defaults: the tables in the module docstring).
    subsurface : bool
        Translucent tags: the boundary of the scattering interior (one-sided
        ``roughdielectric``, or ``null`` for a matched index η = 1) instead of an opaque
        two-sided Lambertian surface.

    Returns
    -------
    dict
        A dictionary for ``mitsuba.load_dict``: ``{"type": "twosided", "material":
        {...}}`` with a grey ``diffuse`` BSDF for an opaque translucent tag or a GGX
        ``roughconductor`` for ``metal``/``knurled-metal``; with ``subsurface``, a
        one-sided ``roughdielectric`` (``null`` for η = 1) for a translucent tag.

    Raises
    ------
    MeshError
        For an unknown material tag.
    """
    s = settings or MaterialSettings()
    if material not in MATERIALS:
        raise MeshError(f"unknown material {material!r} (known: {', '.join(MATERIALS)})")
    if material in ("metal", "knurled-metal"):
        alpha = s.metal_alpha if material == "metal" else s.knurled_alpha
        return {"type": "twosided", "material": _conductor(alpha, s.conductor)}
    if subsurface:
        return _boundary(s.translucent[material])
    return {"type": "twosided", "material": _diffuse(_opaque_albedo(material, s))}


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

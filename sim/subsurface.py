"""Subsurface scattering: the random walk of laser light inside a translucent material.

Model
-----
A translucent part (:data:`sim.materials.TRANSLUCENT`) is a homogeneous medium
(scattering σ_s, absorption σ_a, Henyey–Greenstein phase function with
asymmetry g) below a dielectric boundary of relative index η.  Light that the
boundary transmits (Mitsuba's ``roughdielectric`` sampled at the entry point,
:mod:`sim.transport`) walks inside:

1. free flight t ~ σ_t·exp(−σ_t·t), σ_t = σ_s + σ_a;
2. if the flight reaches the boundary first, Fresnel decides (smooth boundary,
   unpolarised; total internal reflection beyond the critical angle): reflect
   back inside, or leave (the walk ends; the light may continue outside as a
   further bounce);
3. else the light scatters: weight × σ_s/σ_t, new direction from the phase
   function; before that, *next-event estimation* sends the vertex's
   contribution to the camera (below).

Walks are stopped after ``max_steps`` events (the energy of longer walks is
lost: at the renderer's default 512 events, 1–2 % of the reflectance of marble,
paper and white plastic, nothing for cardboard and tape) and by Russian
roulette once the weight has fallen below 5 % of its start.

Geometry: the walk runs in the half-space below the tangent plane of the
entry point (local frame: lateral t1, t2, depth z ≥ 0).  This is exact for a
plane face thicker than the light's penetration (≈ 1/√(3σ_a σ_t'): 0.2 mm for
cardboard, 6 mm for marble) and an approximation on curved surfaces (exit
points lie on the entry's tangent plane, off the true surface by r²/(2R) at a
lateral distance r on a radius R) and near edges, where real light would leave
through the neighbouring face.  It needs no ray casts inside the material,
which keeps a full frame fast.

Next-event estimation through the boundary (camera connection)
--------------------------------------------------------------
From a scattering vertex x at depth z the light reaches the lens point A by
refraction at the exit point e of the plane: outside direction ω_o = (A − e)/|A − e|,
inside direction ω_i with the same azimuth and sin θ_i = sin θ_o/η, path
s = z/cos θ_i inside (e is found by two fixed-point iterations from e = x
projected on the plane; A lies ~10⁵ depths away).  Power scattered into dω_i
leaves into dω_o = η² cos θ_i / cos θ_o · dω_i (étendue n² cos θ dω is
conserved), so the vertex's intensity toward A is::

    I = w · p(d, ω_i) · exp(−σ_t s) · T(θ_i) · cos θ_o / (η² cos θ_i)   [W/sr]

(T = 1 − F the Fresnel transmittance; for η = 1 this is plain next-event
estimation), and the flux into the aperture I·Ω_ap is splatted at the image of
e (:class:`sim.lens.LensConnection`).  Whether e sees the lens is decided once
per walk, for the entry point (one shadow ray per walk).

Accumulation: inside the walk's single Dr.Jit loop the splats are added to a
uint32 image in fixed point (1/64 e⁻, deterministically dithered) with
integer atomics, which are order-independent: the image is bit-identical for
any number of threads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = [
    "FIXED_POINT_SCALE",
    "WalkMedium",
    "WalkResult",
    "hg_eval",
    "hg_sample",
    "random_walk",
]

#: Fixed-point units of the subsurface splat image per electron.
FIXED_POINT_SCALE = 64.0


@dataclass
class WalkMedium:
    """Per-lane medium parameters of a walk (Dr.Jit ``Float`` arrays or Python floats).

    sigma_s, sigma_a : scattering and absorption coefficients [1/mm].
    g : Henyey–Greenstein asymmetry [-].
    eta : relative refractive index of the interior [-].
    """

    sigma_s: object
    sigma_a: object
    g: object
    eta: object


@dataclass
class WalkResult:
    """Where the walks ended (Dr.Jit arrays, local frame of each walk's entry point).

    exited : ``Bool``, the light left through the boundary.
    position : ``Point3f``, exit point (t1, t2, 0) [mm].
    direction : ``Vector3f``, direction outside (z < 0 points away from the material).
    weight : ``Float``, power carried out [W].
    steps : ``UInt32``, events of each walk.
    """

    exited: object
    position: object
    direction: object
    weight: object
    steps: object


def hg_eval(dr, g, cos_theta):
    """Henyey–Greenstein phase function p(cos θ) [1/sr].

    Parameters
    ----------
    dr : module
        ``drjit``.
    g : Float
        Asymmetry [-].
    cos_theta : Float
        Cosine of the scattering angle [-].

    Returns
    -------
    Float
        (1 − g²) / (4π (1 + g² − 2 g cos θ)^{3/2}).
    """
    denom = 1.0 + g * g - 2.0 * g * cos_theta
    return (1.0 - g * g) / (4.0 * math.pi * denom * dr.sqrt(denom))


def hg_sample(mi, dr, g, d, u1, u2):
    """Sample a new direction from the Henyey–Greenstein phase function around ``d``.

    Parameters
    ----------
    mi, dr : modules
        ``mitsuba`` and ``drjit``.
    g : Float
        Asymmetry [-].
    d : Vector3f
        Current direction (unit).
    u1, u2 : Float
        Uniform samples.

    Returns
    -------
    Vector3f
        The scattered direction (unit).
    """
    small = dr.abs(g) < 1e-3
    gg = dr.select(small, 0.5, g)
    sq = (1.0 - gg * gg) / (1.0 - gg + 2.0 * gg * u1)
    cos_hg = (1.0 + gg * gg - sq * sq) / (2.0 * gg)
    cos_t = dr.clip(dr.select(small, 1.0 - 2.0 * u1, cos_hg), -1.0, 1.0)
    sin_t = dr.safe_sqrt(1.0 - cos_t * cos_t)
    phi = 2.0 * math.pi * u2
    local = mi.Vector3f(sin_t * dr.cos(phi), sin_t * dr.sin(phi), cos_t)
    return dr.normalize(mi.Frame3f(d).to_world(local))


def _fresnel_inside(mi, dr, cos_i, eta):
    """Fresnel reflectance for light inside (cos_i > 0 toward the boundary), η = n_in/n_out."""
    f, _, _, _ = mi.fresnel(-cos_i, eta)
    return dr.select(eta == 1.0, 0.0, f)


def random_walk(mi, dr, medium: WalkMedium, direction, weight, rng, active, max_steps: int,
                nee=None) -> WalkResult:
    """Random walks in the half-space z ≥ 0 below a boundary plane (one Dr.Jit loop).

    Parameters
    ----------
    mi, dr : modules
        ``mitsuba`` (JIT variant) and ``drjit``.
    medium : WalkMedium
        Coefficients per lane [1/mm].
    direction : Vector3f
        Initial direction of each walk in its local frame (z > 0 into the material).
    weight : Float
        Power entering [W].
    rng : mitsuba.PCG32
        One random stream per lane (advanced in place).
    active : Bool
        Lanes that walk.
    max_steps : int
        Events after which a walk is abandoned (≥ 1).
    nee : callable, optional
        ``nee(x, d, w, active, u)``: called at every scattering vertex x (local ``Point3f``,
        before the new direction is drawn) with the incoming direction d, the weight w
        after the albedo and a uniform sample u of the walk's stream (for dithering); used
        to splat the vertex's light toward the camera.

    Returns
    -------
    WalkResult
    """
    sigma_t = medium.sigma_s + medium.sigma_a
    albedo = medium.sigma_s / sigma_t
    w_rr = 0.05 * mi.Float(weight)  # Russian-roulette threshold and survivor weight
    state = (rng, mi.Point3f(0.0, 0.0, 0.0), mi.Vector3f(direction), mi.Float(weight),
             mi.UInt32(0), mi.Bool(active), mi.Bool(False), mi.Vector3f(0.0, 0.0, -1.0))

    def cond(rng, x, d, w, it, act, out, d_out):
        return act

    def body(rng, x, d, w, it, act, out, d_out):
        t = -dr.log(1.0 - rng.next_float32()) / sigma_t
        t_b = dr.select(d.z < 0.0, -x.z / dr.minimum(d.z, -1e-12), dr.inf)
        at_boundary = t_b <= t
        x = mi.Point3f(x + dr.select(at_boundary, t_b, t) * d)
        x.z = dr.select(at_boundary, 0.0, dr.maximum(x.z, 0.0))
        # boundary: Fresnel reflection (TIR included) or exit
        cos_i = -d.z
        reflect = rng.next_float32() < _fresnel_inside(mi, dr, cos_i, medium.eta)
        leave = act & at_boundary & ~reflect
        tan_out = mi.Vector2f(d.x, d.y) * medium.eta
        z_out = -dr.safe_sqrt(1.0 - dr.squared_norm(tan_out))
        d_out = dr.select(leave, mi.Vector3f(tan_out.x, tan_out.y, z_out), d_out)
        out |= leave
        # scattering vertex
        scatter = act & ~at_boundary
        w = dr.select(scatter, w * albedo, w)
        if nee is not None:
            nee(x, d, w, scatter, rng.next_float32())
        d_new = hg_sample(mi, dr, medium.g, d, rng.next_float32(), rng.next_float32())
        d = dr.select(scatter, d_new, dr.select(at_boundary, mi.Vector3f(d.x, d.y, -d.z), d))
        low = scatter & (it >= 8) & (w < w_rr)
        survive = rng.next_float32() * w_rr < w
        w = dr.select(low, dr.select(survive, w_rr, 0.0), w)
        it += 1
        act &= ~leave & ~(low & ~survive) & (it < max_steps)
        return rng, x, d, w, it, act, out, d_out

    rng, x, d, w, it, act, out, d_out = dr.while_loop(state, cond, body)
    return WalkResult(out, x, d_out, w, it)


def total_reflectance(medium, n_paths: int = 200_000, cos_incidence: float = 1.0, seed: int = 0,
                      max_steps: int = 1024) -> float:
    """Directional-hemispherical reflectance of a thick slab of a translucent material.

    Light arrives at ``cos_incidence``; the boundary (Mitsuba ``roughdielectric``, or
    none for η = 1) reflects part of it (surface gloss) and transmits the rest, which
    random-walks (:func:`random_walk`) until it leaves or is absorbed.

    Parameters
    ----------
    medium : sim.materials.Translucent
        The material.
    n_paths : int
        Light paths.
    cos_incidence : float
        Cosine of the angle of incidence (0, 1] [-].
    seed : int
        Random seed.
    max_steps : int
        Event limit of a walk.

    Returns
    -------
    float
        Reflected fraction of the incident power (gloss + subsurface) [-].

    Raises
    ------
    ValueError
        If ``cos_incidence`` is not in (0, 1].
    """
    if not 0.0 < cos_incidence <= 1.0:
        raise ValueError(f"cos_incidence = {cos_incidence}: must be in (0, 1]")
    import drjit as dr
    import mitsuba as mi

    from .materials import _boundary

    n = int(n_paths)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
    si.wi = mi.Vector3f(math.sqrt(1.0 - cos_incidence**2), 0.0, cos_incidence)
    rng = mi.PCG32(size=n, initstate=mi.UInt64(seed), initseq=dr.arange(mi.UInt64, n))
    bsdf = mi.load_dict(_boundary(medium))
    bs, w = bsdf.sample(mi.BSDFContext(mi.TransportMode.Importance), si, rng.next_float32(),
                        mi.Point2f(rng.next_float32(), rng.next_float32()))
    weight = w[0]
    enter = mi.Frame3f.cos_theta(bs.wo) < 0.0
    gloss = dr.sum(dr.select(enter, 0.0, weight))[0]
    f = mi.Float
    walk = random_walk(mi, dr, WalkMedium(f(medium.sigma_s_per_mm), f(medium.sigma_a_per_mm),
                                          f(medium.g), f(medium.eta)),
                       mi.Vector3f(bs.wo.x, bs.wo.y, -bs.wo.z), weight, rng, enter, max_steps)
    out = dr.sum(dr.select(walk.exited, walk.weight, 0.0))[0]
    return float(gloss + out) / n

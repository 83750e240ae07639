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
roulette once the weight has fallen below 20 % of its start (survivors carry
20 %: unbiased, and weights never grow).

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

Accumulation: inside the walk's Dr.Jit loop the splats are added to a uint32
image in fixed point (1/64 e⁻, deterministically dithered) with integer
atomics, which are order-independent: the image is bit-identical for any
number of threads.

Tabulated response (what the renderer uses)
-------------------------------------------
Splatting walks is noisy: each walk's light lands at random over the halo, so
with the renderer's ~30 paths per row the stripe centre on cardboard scattered
by 0.15–0.3 px from frame to frame (measured), far above the surface stripe's
0.005 px.  For isotropic scattering (g = 0, which the similarity relation gives
every medium here) the camera-bound light of a vertex depends only on where the
vertex is, so :class:`SubsurfaceTable` runs the walks once per medium and angle
of incidence, keeps the density of their vertices' weights in the half-space,
and turns it, for any view direction, into the 2-D intensity leaving the surface
(the next-event weights above, summed along the refracted line of sight).  The
renderer (:mod:`sim.transport`) convolves the light entering the surface — per
16-pixel tile and material, with the tile's mean angles and projection — with
that response mapped onto the sensor.  The subsurface light is then as smooth as
the surface light (stripe-centre render noise 0.002–0.01 px on cardboard and
tape), the response is exact for the model up to the table's grid
(128 × 128 × 24 cells over ±max(16 ℓ, 6 L_d) and 8 ℓ in depth), its angle steps
(incidence interpolated between 0, 15, …, 75°; view 2.5°, azimuth 10°) and the
faintest 0.2 % of the halo, which is dropped.  Walks still run, for the light
that leaves a material and goes on to another surface (``bounces`` > 1), and for
media with g ≠ 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

__all__ = [
    "FIXED_POINT_SCALE",
    "SubsurfaceTable",
    "TABLE_INCIDENCE_DEG",
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

    Parameters
    ----------
    sigma_s : Float
        Scattering coefficient [1/mm].
    sigma_a : Float
        Absorption coefficient [1/mm].
    g : Float
        Henyey–Greenstein asymmetry [-].
    eta : Float
        Relative refractive index of the interior [-].
    """

    sigma_s: object
    sigma_a: object
    g: object
    eta: object


@dataclass
class WalkResult:
    """Where the walks ended (Dr.Jit arrays, local frame of each walk's entry point).

    Parameters
    ----------
    exited : Bool
        The light left through the boundary.
    position : Point3f
        Exit point (t1, t2, 0) [mm].
    direction : Vector3f
        Direction outside (z < 0 points away from the material).
    weight : Float
        Power carried out [W].
    steps : UInt32
        Events of each walk.
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
                nee=None, chunk: int = 128) -> WalkResult:
    """Random walks in the half-space z ≥ 0 below a boundary plane.

    The walks run in Dr.Jit loops of ``chunk`` events; between chunks the finished walks
    are removed (compaction), so that the cost follows the total number of events and
    not the longest walk of each SIMD packet.

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
        One random stream per lane.
    active : Bool
        Lanes that walk.
    max_steps : int
        Events after which a walk is abandoned (≥ 1).
    nee : callable, optional
        ``nee(x, d, w, active, u, lane)``: called at every scattering vertex x (local
        ``Point3f``, before the new direction is drawn) with the incoming direction d, the
        weight w after the albedo, a uniform sample u of the walk's stream (for dithering)
        and the walk's original lane index (``UInt32``, to gather per-walk data); used to
        splat the vertex's light toward the camera.
    chunk : int
        Events per loop between compactions.

    Returns
    -------
    WalkResult
        One entry per input lane (zeros for lanes that did not walk).
    """
    n = max(dr.width(weight), dr.width(active), dr.width(direction), dr.width(rng.state))
    weight = mi.Float(weight) + dr.zeros(mi.Float, n)
    res = WalkResult(dr.zeros(mi.Bool, n), dr.zeros(mi.Point3f, n),
                     mi.Vector3f(dr.zeros(mi.Float, n), dr.zeros(mi.Float, n), dr.full(mi.Float, -1.0, n)),
                     dr.zeros(mi.Float, n), dr.zeros(mi.UInt32, n))
    lanes = dr.compress(mi.Bool(active) & (mi.Float(weight) > 0))
    if dr.width(lanes) == 0:
        return res
    params = [mi.Float(p) + dr.zeros(mi.Float, n) for p in (medium.sigma_s, medium.sigma_a,
                                                            medium.g, medium.eta)]
    state = _walk_state(mi, dr, lanes, direction, weight, rng, params)
    done = 0
    while done < max_steps:
        done = min(done + chunk, max_steps)
        state = _walk_chunk(mi, dr, state, done, nee)
        _store_finished(mi, dr, state, res, done >= max_steps)
        keep = dr.compress(state["act"])
        if dr.width(keep) == 0:
            break
        state = {k: _gather(mi, dr, v, keep) for k, v in state.items()}
    return res


def _gather(mi, dr, value, index):
    if isinstance(value, mi.PCG32):
        out = mi.PCG32(size=dr.width(index))
        out.state = dr.gather(mi.UInt64, value.state, index)
        out.inc = dr.gather(mi.UInt64, value.inc, index)
        return out
    return dr.gather(type(value), value, index)


def _walk_state(mi, dr, lanes, direction, weight, rng, params) -> dict:
    """Compacted per-walk state of the lanes that walk."""
    m = dr.width(lanes)
    w0 = dr.gather(mi.Float, mi.Float(weight), lanes)
    return {"lane": lanes, "rng": _gather(mi, dr, rng, lanes),
            "x": dr.zeros(mi.Point3f, m),
            "d": dr.gather(mi.Vector3f, mi.Vector3f(direction) + dr.zeros(mi.Vector3f, dr.width(rng.state)), lanes),
            "w": w0, "w_rr": 0.2 * w0, "it": dr.zeros(mi.UInt32, m),
            "act": dr.full(mi.Bool, True, m), "out": dr.zeros(mi.Bool, m),
            "d_out": mi.Vector3f(dr.zeros(mi.Float, m), dr.zeros(mi.Float, m), dr.full(mi.Float, -1.0, m)),
            "ss": dr.gather(mi.Float, params[0], lanes), "sa": dr.gather(mi.Float, params[1], lanes),
            "g": dr.gather(mi.Float, params[2], lanes), "eta": dr.gather(mi.Float, params[3], lanes)}


def _store_finished(mi, dr, st, res, last: bool) -> None:
    """Write the results of the walks that ended (or hit the event limit) to their lanes."""
    fin = ~st["act"] | last
    lane = st["lane"]
    dr.scatter(res.exited, st["out"], lane, fin)
    dr.scatter(res.position, st["x"], lane, fin)
    dr.scatter(res.direction, st["d_out"], lane, fin)
    dr.scatter(res.weight, st["w"], lane, fin)
    dr.scatter(res.steps, st["it"], lane, fin)
    dr.eval(res.exited, res.position, res.direction, res.weight, res.steps)


def _walk_chunk(mi, dr, st: dict, until: int, nee) -> dict:
    """Advance every walk of ``st`` until it ends or has made ``until`` events."""
    sigma_t = st["ss"] + st["sa"]
    albedo = st["ss"] / sigma_t
    medium = WalkMedium(st["ss"], st["sa"], st["g"], st["eta"])
    lane, w_rr = st["lane"], st["w_rr"]
    until = dr.opaque(mi.UInt32, until)        # not a literal: one kernel for every chunk
    names = ("rng", "x", "d", "w", "it", "act", "out", "d_out")

    def cond(rng, x, d, w, it, act, out, d_out):
        return act & (it < until)

    def body(rng, x, d, w, it, act, out, d_out):
        act = act & (it < until)
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
            nee(x, d, w, scatter, rng.next_float32(), lane)
        d_new = hg_sample(mi, dr, medium.g, d, rng.next_float32(), rng.next_float32())
        d = dr.select(scatter, d_new, dr.select(at_boundary, mi.Vector3f(d.x, d.y, -d.z), d))
        low = scatter & (it >= 8) & (w < w_rr)
        survive = rng.next_float32() * w_rr < w
        w = dr.select(low, dr.select(survive, w_rr, 0.0), w)
        it = dr.select(act, it + 1, it)
        act &= ~leave & ~(low & ~survive)
        return rng, x, d, w, it, act, out, d_out

    result = dr.while_loop(tuple(st[k] for k in names), cond, body)
    st = dict(st, **dict(zip(names, result)))
    dr.eval(*[v for k, v in st.items() if k != "rng"], st["rng"].state, st["rng"].inc)
    return st


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


# ------------------------------------------------------------------ tabulated response

#: Angles of incidence [deg] at which :class:`SubsurfaceTable` tabulates a medium.
TABLE_INCIDENCE_DEG = (0.0, 15.0, 30.0, 45.0, 60.0, 75.0)


class SubsurfaceTable:
    """The light that leaves a semi-infinite slab toward a camera, tabulated once per medium.

    For isotropic scattering (g = 0; the media of :mod:`sim.materials` use the
    similarity relation) the camera-bound light of a scattering vertex depends on its
    position only, so the walks of light entering at incidence θ_in are summarised by
    the density H(x, y, z) of their vertices' weights (x along the incidence plane,
    forward; y across; z depth), per unit incident power, for the angles
    :data:`TABLE_INCIDENCE_DEG` (the boundary's entry sampled as in the renderer).
    :meth:`kernel` turns it, for a view direction, into the 2-D distribution of the
    intensity leaving the surface toward that direction (the next-event weights of
    :mod:`sim.subsurface`'s module docstring): a deterministic subsurface response that
    the renderer convolves with the light entering, instead of splatting noisy walks.
    The same walks' exits (point, direction, weight) are kept as a sample set, from
    which the renderer draws the light that goes on to other surfaces.

    Parameters
    ----------
    medium : sim.materials.Translucent
        The material (g must be 0).
    n_walks : int
        Walks per angle of incidence.
    max_steps : int
        Event limit of a walk.
    seed : int
        Random seed (the table is deterministic for a seed).

    Raises
    ------
    ValueError
        If the medium's g is not 0.

    Attributes
    ----------
    tables : (angles, NX, NX, NZ) float64
        Vertex weight per cell (x, y, z) per unit incident power.
    exit_albedo : (angles,) float64
        Power leaving through the boundary per unit power entering [-].
    exit_samples : (angles, EXIT_SAMPLES, 5) float32
        Exits drawn in proportion to their power: point (x, y) [mm] and direction
        (x, y, z; z < 0 leaves the material), the walk's local frame.

    Notes
    -----
    The box holds |x|, |y| ≤ X = max(16 ℓ, 6 L_d) and z ≤ 8 ℓ (ℓ = 1/(σ_s + σ_a) the
    transport mean free path, L_d = 1/√(3 σ_a σ_t) the diffusion length) on a
    128 × 128 × 24 grid; vertices outside it (the far halo, deep vertices whose light
    is attenuated below e⁻⁸) are not counted.
    """

    NX, NZ = 128, 24
    EXIT_SAMPLES = 4096

    def __init__(self, medium, n_walks: int = 50_000, max_steps: int = 1024, seed: int = 0) -> None:
        if medium.g != 0.0:
            raise ValueError(f"SubsurfaceTable: g = {medium.g}: tabulation needs isotropic scattering")
        self.medium = medium
        sigma_t = medium.sigma_t_per_mm
        mfp = 1.0 / sigma_t
        diffusion = 1.0 / math.sqrt(3.0 * max(medium.sigma_a_per_mm, 1e-9) * sigma_t)
        self.half_width_mm = max(16.0 * mfp, 6.0 * diffusion)
        self.cell_mm = 2.0 * self.half_width_mm / self.NX
        self.depth_cell_mm = 8.0 * mfp / self.NZ
        runs = [self._tabulate(a, n_walks, max_steps, seed + i)
                for i, a in enumerate(TABLE_INCIDENCE_DEG)]
        self.tables = np.stack([r[0] for r in runs])
        self.exit_albedo = np.array([r[1] for r in runs])
        self.exit_samples = np.stack([r[2] for r in runs])
        self._kernels: dict = {}
        self._tables_merged: dict = {}

    def _tabulate(self, incidence_deg: float, n: int, max_steps: int, seed: int):
        """Vertex table, exit albedo and exit samples of ``n`` walks at one incidence."""
        import drjit as dr
        import mitsuba as mi

        from .materials import _boundary

        m = self.medium
        t = math.radians(incidence_deg)
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
        si.wi = mi.Vector3f(-math.sin(t), 0.0, math.cos(t))          # light travels toward +x
        rng = mi.PCG32(size=n, initstate=mi.UInt64(seed), initseq=dr.arange(mi.UInt64, n))
        bs, w = mi.load_dict(_boundary(m)).sample(mi.BSDFContext(mi.TransportMode.Importance), si,
                                                  rng.next_float32(),
                                                  mi.Point2f(rng.next_float32(), rng.next_float32()))
        acc = dr.zeros(mi.UInt64, self.NX * self.NX * self.NZ)
        scale = float(1 << 32)
        nx, nz, cell, dcell = self.NX, self.NZ, self.cell_mm, self.depth_cell_mm

        def nee(x, d, wt, act, u, lane):
            ix = mi.Int32(dr.floor(x.x / cell + 0.5 * nx))
            iy = mi.Int32(dr.floor(x.y / cell + 0.5 * nx))
            iz = mi.Int32(dr.floor(x.z / dcell))
            ok = act & (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < nx) & (iz >= 0) & (iz < nz)
            idx = mi.UInt32((ix * nx + iy) * nz + iz)
            dr.scatter_reduce(dr.ReduceOp.Add, acc, mi.UInt64(wt * scale + u), idx, ok)

        medium = WalkMedium(mi.Float(m.sigma_s_per_mm), mi.Float(m.sigma_a_per_mm), mi.Float(0.0),
                            mi.Float(m.eta))
        enter = mi.Frame3f.cos_theta(bs.wo) < 0.0
        walk = random_walk(mi, dr, medium, mi.Vector3f(bs.wo.x, bs.wo.y, -bs.wo.z), w[0], rng,
                           enter, max_steps, nee)
        dr.eval(acc)
        table = (np.asarray(acc, np.float64) / (scale * n)).reshape(nx, nx, nz)
        w_in = np.where(np.asarray(enter), np.asarray(w[0], np.float64), 0.0)
        w_out = np.where(np.asarray(walk.exited), np.asarray(walk.weight, np.float64), 0.0)
        albedo = float(w_out.sum() / max(w_in.sum(), 1e-300))
        samples = np.zeros((self.EXIT_SAMPLES, 5), np.float32)
        if w_out.sum() > 0:
            pick = np.random.default_rng(seed).choice(n, self.EXIT_SAMPLES, p=w_out / w_out.sum())
            pos, d = np.asarray(walk.position), np.asarray(walk.direction)
            samples[:] = np.concatenate([pos[:2, pick], d[:, pick]]).T
        return table, albedo, samples

    def kernel(self, incidence_deg: float, view_deg: float, view_azimuth_deg: float,
               merge: int = 1) -> np.ndarray:
        """Intensity leaving the surface toward a view direction, per unit incident power.

        Parameters
        ----------
        incidence_deg : float
            Angle of incidence θ_in of the light entering [deg] (linear interpolation
            between the tabulated angles).
        view_deg : float
            Angle θ_o between the view direction and the surface normal [deg].
        view_azimuth_deg : float
            Azimuth of the view direction from the incidence plane's forward direction
            [deg].
        merge : int
            Cells merged by this factor per axis before the projection (a divisor of
            ``NX``; cells of ``merge·cell_mm``).

        Returns
        -------
        (NX/merge, NX/merge) float64
            Per cell of ``merge·cell_mm`` (x forward along the incidence plane, y across, both
            centred on the entry point): radiant intensity toward the view direction per
            unit incident power [1/sr]; zero beyond the critical direction.
        """
        angles = np.asarray(TABLE_INCIDENCE_DEG)
        a = float(np.clip(incidence_deg, angles[0], angles[-1]))
        k = min(int(np.searchsorted(angles, a, side="right")) - 1, len(angles) - 2)
        f = (a - angles[k]) / (angles[k + 1] - angles[k])
        view = round(float(view_deg) / 2.5) * 2.5
        azim = round(float(view_azimuth_deg) / 10.0) * 10.0
        return ((1.0 - f) * self._projected(k, view, azim, merge)
                + f * self._projected(k + 1, view, azim, merge))

    def _merged(self, k: int, merge: int) -> np.ndarray:
        """Table k with cells merged by ``merge`` per axis, depth first: (NZ, n, n)."""
        key = (k, merge)
        if key not in self._tables_merged:
            n = self.NX // merge
            merged = self.tables[k].reshape(n, merge, n, merge, self.NZ).sum(axis=(1, 3))
            self._tables_merged[key] = np.ascontiguousarray(np.moveaxis(merged, 2, 0))
        return self._tables_merged[key]

    def _projected(self, k: int, view_deg: float, azimuth_deg: float, merge: int) -> np.ndarray:
        key = (k, view_deg, azimuth_deg, merge)
        if key not in self._kernels:
            if len(self._kernels) >= 4096:        # ≤ 64 MB per table (merge ≥ 2)
                self._kernels.clear()
            m = self.medium
            cos_o = math.cos(math.radians(min(view_deg, 89.0)))
            sin_t = math.sqrt(1.0 - cos_o * cos_o) / m.eta
            cos_t = math.sqrt(1.0 - sin_t * sin_t)
            if m.eta == 1.0:
                trans = 1.0
            else:
                import mitsuba as mi

                trans = 1.0 - float(np.asarray(mi.fresnel(mi.Float(-cos_t), mi.Float(m.eta))[0])[0])
            weight = trans * cos_o / (m.eta * m.eta * cos_t) / (4.0 * math.pi)
            phi = math.radians(azimuth_deg)
            self._kernels[key] = _project_table(
                self._merged(k, merge), self.cell_mm * merge, self.depth_cell_mm, m.sigma_t_per_mm / cos_t,
                sin_t / cos_t * math.cos(phi), sin_t / cos_t * math.sin(phi), weight)
        return self._kernels[key]


@numba.njit(cache=True, nogil=True, parallel=True)
def _project_table(table, cell, dcell, atten, shift_x, shift_y, weight):  # pragma: no cover
    """Sum the vertex table (depth first: (nz, nx, ny)) along the refracted view direction.

    Layer z moves by z·(shift_x, shift_y) (bilinear; a uniform shift, so gathering per
    output cell equals splatting per table cell); rows of the output in parallel, each
    summed in a fixed order (per cell: layers, then the two source rows).
    """
    nz, nx, ny = table.shape
    out = np.zeros((nx, ny))
    for qx in numba.prange(nx):
        for iz in range(nz):
            z = (iz + 0.5) * dcell
            w = weight * math.exp(-atten * z)
            fx = qx - z * shift_x / cell
            jx = int(math.floor(fx))
            ax = fx - jx
            fy0 = -z * shift_y / cell
            jy0 = int(math.floor(fy0))
            ay = fy0 - jy0
            for dx in range(2):
                sx = jx + dx
                if sx < 0 or sx >= nx:
                    continue
                wx = w * (ax if dx else 1.0 - ax)
                _shifted_row(out[qx], table[iz, sx], jy0, ay, wx)
    return out


@numba.njit(cache=True, nogil=True)
def _shifted_row(out, row, jy0, ay, wx):  # pragma: no cover - compiled
    """out[q] += wx·((1 − ay)·row[q + jy0] + ay·row[q + jy0 + 1]), terms outside row left out."""
    ny = out.shape[0]
    q_left = -jy0 - 1                       # only row[0] (as the second term)
    if 0 <= q_left < ny:
        out[q_left] += wx * (ay * row[0])
    lo, hi = max(0, -jy0), min(ny, ny - jy0 - 1)
    if hi > lo:
        o, a, b = out[lo:hi], row[lo + jy0:hi + jy0], row[lo + jy0 + 1:hi + jy0 + 1]
        for j in range(hi - lo):
            o[j] += wx * ((1.0 - ay) * a[j] + ay * b[j])
    q_right = ny - jy0 - 1                  # only row[ny − 1] (as the first term)
    if 0 <= q_right < ny:
        out[q_right] += wx * ((1.0 - ay) * row[ny - 1])

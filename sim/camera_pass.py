"""The camera pass: what the camera sees of the flood-lit scene, through the tilted thin lens.

A path tracer driven from the sensor, for all light but the laser's (the laser
is light-traced by :mod:`sim.render`).  Per frame and pixel, ``spp`` samples:

1. **Pixel area.**  A point q of the pixel's square (u ± ½, v ± ½) on the
   sensor plane (:func:`scheimpflug.model.camera.sensor_pose`: the tilted
   Scheimpflug pose with its misalignments, or any pose given).
2. **Aperture.**  A point A of the aperture disc (radius f/(2N), in the lens
   plane through the real lens's centre c, :func:`scheimpflug.model.camera.lens_state`).
3. **Thin lens.**  Every ray through A whose image-side part heads for q comes
   from the object point Q conjugate to q (the Gaussian lens equation about c:
   x = f·x'/(x' + f) for the axial image distance x' < 0, the lateral offset
   scaled by x/x' and undistorted — the inverse of
   :func:`scheimpflug.model.camera.conjugate_point`).  The object-side ray is
   A → Q.  (With distortion k1, k2 ≠ 0 this is exact for the in-focus point Q
   and a first-order approximation for defocused ones; the paper rig has none.)
   Defocus, the sharp plane of the tilted sensor and the blur's shape follow
   from this geometry alone.
4. **Shading** (``bounces`` vertices deep; 1 = direct light only): at each
   hit, next-event estimation of the flood light (:mod:`sim.lights`: one point
   of the square, a shadow ray) and one BSDF sample toward the environment
   (uniform radiance L_env; a shadow ray, or the next vertex when more bounces
   are asked for).  Rays that miss everything see L_env.  A textured part's
   BSDF is a Lambertian of albedo 1 times its texture (:mod:`sim.textures`).
   BSDFs are evaluated in the RGB channel of the laser's wavelength
   (:func:`sim.materials.channel_for_wavelength`), as the ambient pass does.
5. **Radiometry.**  A thin lens in air keeps radiance, so the flux from the
   scene onto the pixel is the étendue integral::

       Φ = ∫_pixel ∫_aperture L · cos θ_q · cos θ_A / |q − A|² dA dA_q
         ≈ A_pix · A_ap · mean( L · cos θ_q · cos θ_A / |q − A|² )

   (θ_q to the sensor normal, θ_A to the lens axis): the cos⁴ falloff, the
   tilted sensor's obliquity and the aperture's projection come out of the
   samples.  Electrons: Φ · t_exp · QE · λ/(h·c) (:class:`sim.render.Renderer`'s
   ``electrons_per_watt``).  The sensor model (:mod:`sim.sensor`) then adds its
   noise as for any frame.

Sampling: each of a pixel's four sample pairs (pixel square, aperture disc,
flood-light square, BSDF) runs through the ``spp`` points of the R₂ lattice
{frac(i·α + s)} (Roberts' plastic-number sequence), with a random shift s
(Cranley–Patterson rotation) and a random index permutation per pixel and pair
(from a PCG32 stream seeded by the frame seed and the pixel index), so that
every pair is stratified over its square and the pairs are combined at random;
deeper vertices draw from PCG32.  One sample per pixel is traced per kernel
launch (``spp`` launches of one compiled kernel: the seed, the pass index, the
scene transform and the light levels are opaque values), accumulated in
sample order: the same seed gives the same image, bit for bit.

Noise: at 1 sample per pixel a uniform matte surface under the environment
alone is exact (the BSDF sample's weight is the albedo); the flood light's
next-event estimate is unbiased with a relative scatter set by the light's
extent seen from the point; edges anti-alias as 1/spp with the low-discrepancy
samples.  ``benchmarks/bench_camera_pass.py`` measures time and noise.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from scheimpflug.errors import RenderError
from scheimpflug.model.camera import SensorPose, lens_state, sensor_pose
from scheimpflug.model.distortion import is_radial
from scheimpflug.model.rig import Rig

from .lens import floats, undistort_tangents_dr
from .lights import flood_light
from .materials import channel_for_wavelength
from .scene import SimScene
from .variant import is_jit_variant

__all__ = [
    "DEFAULT_SPP",
    "CameraPass",
    "CameraSettings",
    "camera_pass_of",
    "kronecker_constants",
    "sensor_window",
    "uses_camera_pass",
]

#: Samples per pixel where a camera pass is needed and the rig asks for none ([twin] camera_spp = 0).
DEFAULT_SPP = 16

PLANCK_J_S = 6.62607015e-34
LIGHT_SPEED_M_S = 299792458.0
_DIMS = 2
_PRIMES = (3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37, 41, 43, 47, 53, 59, 61, 67, 71, 73, 79, 83, 89, 97, 101,
           103, 107, 109, 113, 127, 131, 137, 139, 149, 151, 157, 163, 167, 173, 179, 181, 191, 193, 197, 199)


def kronecker_constants(dims: int = _DIMS) -> np.ndarray:
    """The additive constants α_j = φ_d^−(j+1) mod 1 of the R_d sequence, as 32-bit fixed point.

    Parameters
    ----------
    dims : int, default 2
        Dimension d [-]; φ_d is the real root > 1 of x^(d+1) = x + 1 (d = 2: the plastic number).

    Returns
    -------
    (dims,) uint64
        round(α_j · 2³²) [-].
    """
    phi = 2.0
    for _ in range(200):   # fixed point of x = (1 + x)^(1/(d+1))
        phi = (1.0 + phi) ** (1.0 / (dims + 1))
    alpha = np.array([(phi ** -(j + 1)) % 1.0 for j in range(dims)])
    return np.round(alpha * 2**32).astype(np.uint64) & 0xFFFFFFFF


def uses_camera_pass(rig: Rig) -> bool:
    """Whether a rig's frames take their non-laser light from the camera pass.

    Parameters
    ----------
    rig : Rig
        The instrument.

    Returns
    -------
    bool
        True when ``[twin] camera_spp`` > 0 or the rig has a flood light
        (``[environment] flood_irradiance_w_m2`` > 0); else the coarse ambient pass of
        :mod:`sim.render` lights the frames, as it always did.
    """
    return rig.twin.camera_spp > 0 or rig.environment.flood_irradiance_w_m2 > 0


def camera_pass_of(rig: Rig, sim_scene, pixel_filter: str = "tent") -> CameraPass:
    """The camera pass a rig's frames use (:func:`uses_camera_pass`).

    Parameters
    ----------
    rig : Rig
        The instrument: ``[twin] camera_spp`` (0 = :data:`DEFAULT_SPP`) and ``bounces``.
    sim_scene : SimScene
        The scene.
    pixel_filter : {"tent", "box"}
        The pixel response, the laser pass's (:class:`sim.render.RenderSettings`).

    Returns
    -------
    CameraPass
        The pass.
    """
    settings = CameraSettings(spp=rig.twin.camera_spp or DEFAULT_SPP, bounces=rig.twin.bounces,
                              pixel_filter=pixel_filter)
    return CameraPass(rig, sim_scene, settings)


def sensor_window(pose: SensorPose, u0: int, v0: int, columns: int, rows: int, scale: int = 1) -> SensorPose:
    """A window of a sensor: the same plane, pixels (u0 … u0 + columns − 1, v0 … v0 + rows − 1).

    Parameters
    ----------
    pose : SensorPose
        The whole sensor.
    u0, v0 : int
        First column and row of the window [px].
    columns, rows : int
        Window size in the sensor's pixels [px].
    scale : int, default 1
        Sub-pixels per pixel along each axis (pitch / scale) [-].

    Returns
    -------
    SensorPose
        Its pixel (u', v') is the sensor's (u0 − ½ + (u' + ½)/scale, v0 − ½ + (v' + ½)/scale).
    """
    p = pose.pitch_mm
    shift = (u0 - 0.5 + 0.5 / scale) * p * pose.u_dir + (v0 - 0.5 + 0.5 / scale) * p * pose.v_dir
    return SensorPose(pose.origin_mm + shift, pose.u_dir, pose.v_dir, p / scale, columns * scale,
                      rows * scale)


@dataclass(frozen=True)
class CameraSettings:
    """Sampling settings of :class:`CameraPass`.

    Parameters
    ----------
    spp : int, default 16
        Samples per pixel (pixel area × aperture × lights) [-], ≥ 1.
    bounces : int, default 1
        Path vertices: 1 = direct light of the environment and the flood light;
        N > 1 follows N − 1 inter-reflections [-], 1 … 64.
    seed : int, default 0
        Base seed, mixed with the frame seed.
    pixel_filter : {"tent", "box"}
        A pixel's response: ``"box"`` — the light falling on its square (exact
        pixel-area integration); ``"tent"`` (default, as the laser pass's
        :class:`sim.render.RenderSettings`) — the square convolved with a further
        1-px box (the laser pass's bilinear splat: mild pixel crosstalk), so that a
        flood-lit frame and a laser frame see through the same pixels.

    Raises
    ------
    RenderError
        When ``spp`` or ``bounces`` is not an integer in range, ``seed`` < 0, or
        ``pixel_filter`` is not "box" or "tent".
    """

    spp: int = DEFAULT_SPP
    bounces: int = 1
    seed: int = 0
    pixel_filter: str = "tent"

    def __post_init__(self) -> None:
        if self.pixel_filter not in ("box", "tent"):
            raise RenderError(f"camera pass pixel_filter = {self.pixel_filter!r}: must be 'box' or 'tent'")
        for name, hi in (("spp", 1 << 20), ("bounces", 64)):
            v = getattr(self, name)
            if not (isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= hi):
                raise RenderError(f"camera pass {name} = {v!r}: must be an integer in [1, {hi}]")
        if not (isinstance(self.seed, int) and self.seed >= 0):
            raise RenderError(f"camera pass seed = {self.seed!r}: must be an integer >= 0")


class CameraPass:
    """The camera pass of a rig over a :class:`~sim.scene.SimScene` (module docstring).

    Parameters
    ----------
    rig : Rig
        The instrument: lens, sensor (pose, exposure, QE), ``[environment]`` lights.
    sim_scene : SimScene
        The parts (a JIT variant).
    settings : CameraSettings, optional
        Sampling; default ``CameraSettings(bounces=rig.twin.bounces)``.
    pose : SensorPose, optional
        Sensor pose; default the rig's (:func:`scheimpflug.model.camera.sensor_pose`).
    flood : FloodLight or None or "rig", default "rig"
        The flood light; ``"rig"`` = the rig's (:func:`sim.lights.flood_light`).

    Attributes
    ----------
    shape : tuple of int
        ``(rows, columns)`` [px].
    flood : FloodLight or None
        The rig's flood light (:func:`sim.lights.flood_light`).
    env_radiance_w_m2_sr : float
        L_env = E_amb/π [W/(m²·sr)].
    electrons_per_watt : float
        t_exp · QE · λ/(h·c) at the rig's exposure [e⁻/W].
    timings : dict
        Wall time per stage since construction [s]: ``trace`` (kernels), ``readout``.

    Raises
    ------
    RenderError
        When the scene's variant is not a JIT variant, or the flood light has no aim point.
    """

    def __init__(self, rig: Rig, sim_scene: SimScene, settings: CameraSettings | None = None,
                 pose: SensorPose | None = None, flood="rig") -> None:
        if not is_jit_variant(sim_scene.variant):
            raise RenderError(f"the camera pass needs a JIT Mitsuba variant (llvm_*/cuda_*), got "
                              f"{sim_scene.variant}")
        import drjit as dr
        import mitsuba as mi

        self._mi, self._dr = mi, dr
        self.rig, self.scene = rig, sim_scene
        self.settings = settings or CameraSettings(bounces=rig.twin.bounces)
        self.pose = pose or sensor_pose(rig)
        self.shape = (self.pose.rows, self.pose.columns)
        state = lens_state(rig)
        self.focal_length_mm, self.centre_x_mm = state.focal_length_mm, state.centre_x_mm
        self.aperture_radius_mm = 0.5 * rig.lens.focal_length_mm / rig.lens.f_number
        self.aperture_area_mm2 = math.pi * self.aperture_radius_mm**2
        photon_j = PLANCK_J_S * LIGHT_SPEED_M_S / (rig.laser.wavelength_nm * 1e-9)
        self.electrons_per_watt = rig.sensor.exposure_ms * 1e-3 * rig.sensor.quantum_efficiency / photon_j
        self.channel = channel_for_wavelength(rig.laser.wavelength_nm)
        self.flood = flood_light(rig) if isinstance(flood, str) and flood == "rig" else flood
        self.env_radiance_w_m2_sr = rig.environment.ambient_irradiance_w_m2 / math.pi
        self._alpha = [int(a) for a in kronecker_constants(2)]      # the R₂ lattice of every sample pair
        self._primes_list = [p for p in _PRIMES if self.settings.spp % p][:32]
        self._primes = mi.UInt32(self._primes_list)
        self.timings = {"trace": 0.0, "readout": 0.0}

    # ------------------------------------------------------------ public
    def render(self, rig_from_part, seed: int, flood_scale: float = 1.0, ambient_scale: float = 1.0,
               exposure_ms: float | None = None) -> np.ndarray:
        """Expected photo-electrons per pixel of one frame, lit by the environment and the flood light.

        Parameters
        ----------
        rig_from_part : (4, 4) or (n_parts, 4, 4) float
            Pose of the parts in the rig frame [mm] (:meth:`SimScene.set_pose`).
        seed : int
            Frame seed (≥ 0), mixed with ``settings.seed``.
        flood_scale : float, default 1.0
            The flood light's level in this frame over the rig's (0 = off) [-].
        ambient_scale : float, default 1.0
            The environment's level over the rig's [-].
        exposure_ms : float, optional
            This frame's exposure [ms]; default the rig's ``sensor.exposure_ms``.

        Returns
        -------
        (rows, columns) float32
            Expected electrons [e⁻], before sensor noise.

        Raises
        ------
        RenderError
            When ``seed`` < 0, a scale is negative or the exposure is not > 0.
        """
        key = self._key(seed)
        if not (flood_scale >= 0 and ambient_scale >= 0):
            raise RenderError(f"camera pass: light levels must be >= 0, got flood {flood_scale}, "
                              f"ambient {ambient_scale}")
        t_exp = self.rig.sensor.exposure_ms if exposure_ms is None else float(exposure_ms)
        if not (math.isfinite(t_exp) and t_exp > 0):
            raise RenderError(f"camera pass: exposure {exposure_ms!r} ms must be > 0")
        self.scene.set_pose(rig_from_part)
        radiance = self._accumulate(key, flood_scale, ambient_scale)
        t0 = time.perf_counter()
        scale = self.aperture_area_mm2 * self.pose.pitch_mm**2 * 1e-6 / self.settings.spp \
            * self.electrons_per_watt * (t_exp / self.rig.sensor.exposure_ms)
        img = (np.asarray(radiance, np.float32) * np.float32(scale)).reshape(self.shape)
        self.timings["readout"] += time.perf_counter() - t0
        return img

    # ------------------------------------------------------------ internals
    def _key(self, seed: int) -> int:
        if int(seed) < 0:
            raise RenderError(f"seed = {seed}: must be >= 0")
        h = int(seed) * 0x9E3779B97F4A7C15 + int(self.settings.seed) * 0xBF58476D1CE4E5B9 + 0x94D049BB133111EB
        return h & 0xFFFFFFFFFFFFFFFF

    def _accumulate(self, key: int, flood_scale: float, ambient_scale: float):
        """Σ over the spp passes of L·cos θ_q·cos θ_A/|q − A|² per pixel [W/(m²·sr·mm²)] (mi.Float)."""
        mi, dr = self._mi, self._dr
        t0 = time.perf_counter()
        frame = self.scene.transforms_dr()
        key_dr = dr.opaque(mi.UInt64, key)
        levels = (dr.opaque(mi.Float, self.env_radiance_w_m2_sr * ambient_scale),
                  dr.opaque(mi.Float, (self.flood.radiance_w_m2_sr if self.flood else 0.0) * flood_scale))
        acc = dr.zeros(mi.Float, self.shape[0] * self.shape[1])
        for k in range(self.settings.spp):
            acc = acc + self._one_sample(frame, key_dr, dr.opaque(mi.UInt32, k), levels)
            dr.eval(acc)
        dr.sync_thread()
        self.timings["trace"] += time.perf_counter() - t0
        return acc

    def _samples(self, key_dr, k):
        """The pixel's 8 sample coordinates of pass k (module docstring) and a PCG32 for the rest.

        Four pairs (pixel, aperture, flood light, BSDF), each the point σ(k) of the R₂ lattice
        {frac(i·α + s)}, i < spp, with its own random shift s and index permutation
        σ(k) = (a·k + b) mod spp (a a prime not dividing spp) per pixel: after the last pass
        every pair holds each lattice point once, and the pairs are paired at random.
        """
        mi, dr = self._mi, self._dr
        n = self.shape[0] * self.shape[1]
        spp = self.settings.spp
        per_pixel = mi.PCG32(n, key_dr, mi.UInt64(0x2545F4914F6CDD1D))
        u = []
        for _ in range(4):
            a = dr.gather(mi.UInt32, self._primes, per_pixel.next_uint32() % len(self._primes_list))
            index = (a * k + per_pixel.next_uint32() % spp) % spp
            for alpha in self._alpha:
                shift = per_pixel.next_uint32()
                u.append(mi.Float((shift + index * alpha) >> 8) * (1.0 / (1 << 24)))
        rng = mi.PCG32(n, key_dr ^ mi.UInt64(0xA0761D6478BD642F), mi.UInt64(k) * 0x9E3779B97F4A7C15 + 1)
        return u, rng

    def _camera_ray(self, u):
        """Rig-frame ray A → Q of the samples, and the étendue weight cos θ_q cos θ_A / |q − A|² [1/mm²]."""
        mi, dr, pose = self._mi, self._dr, self.pose
        idx = dr.arange(mi.UInt32, self.shape[0] * self.shape[1])
        col, row = idx % self.shape[1], idx // self.shape[1]
        uu = mi.Float(col) + self._filter(u[0])
        vv = mi.Float(row) + self._filter(u[1])
        origin, u_dir, v_dir, normal = (mi.Vector3f(*floats(v)) for v in
                                        (pose.origin_mm, pose.u_dir, pose.v_dir, pose.normal))
        c = mi.Vector3f(self.centre_x_mm, 0.0, 0.0)
        rel = origin - c + (uu * pose.pitch_mm) * u_dir + (vv * pose.pitch_mm) * v_dir   # q − c
        disc = mi.warp.square_to_uniform_disk_concentric(mi.Point2f(u[2], u[3])) * self.aperture_radius_mm
        a_rel = mi.Vector3f(0.0, disc.x, disc.y)                                          # A − c
        w = a_rel - rel
        inv_len2 = dr.rcp(dr.squared_norm(w))
        g = dr.abs(w.x) * dr.abs(dr.dot(w, normal)) * inv_len2 * inv_len2
        q_obj = self._object_conjugate(rel)
        ray = mi.Ray3f(mi.Point3f(a_rel + c), dr.normalize(q_obj - a_rel))
        return ray, g

    def _filter(self, xi):
        """Offset from the pixel centre [px] of a uniform sample: box U(−½, ½) or tent on (−1, 1)."""
        dr = self._dr
        if self.settings.pixel_filter == "box":
            return xi - 0.5
        return dr.select(xi < 0.5, dr.sqrt(2.0 * xi) - 1.0, 1.0 - dr.sqrt(2.0 - 2.0 * xi))

    def _object_conjugate(self, rel):
        """Q − c of image points q − c (x' < 0): x = f·x'/(x' + f), lateral undistorted and scaled."""
        mi, dr = self._mi, self._dr
        f = self.focal_length_mm
        xp = rel.x
        x = f * xp / (xp + f)
        lat = x / xp
        if not is_radial(self.rig.lens):
            ay, az = undistort_tangents_dr(self.rig, rel.y / xp, rel.z / xp)
            return mi.Vector3f(x, x * ay, x * az)
        k1, k2 = self.rig.lens.k1, self.rig.lens.k2
        if k1 != 0.0 or k2 != 0.0:
            td = dr.sqrt((rel.y * rel.y + rel.z * rel.z) / (xp * xp))
            t = td
            for _ in range(8):   # t·(1 + k1 t² + k2 t⁴) = t_d, Newton
                t2 = t * t
                t = t - (t * (1.0 + k1 * t2 + k2 * t2 * t2) - td) / (1.0 + 3.0 * k1 * t2 + 5.0 * k2 * t2 * t2)
            lat = lat * dr.select(td > 0, t / dr.maximum(td, 1e-30), 1.0)
        return mi.Vector3f(x, rel.y * lat, rel.z * lat)

    def _one_sample(self, frame, key_dr, k, levels):
        """L·g of one sample per pixel (mi.Float, unevaluated)."""
        mi, dr = self._mi, self._dr
        u, rng = self._samples(key_dr, k)
        ray, g = self._camera_ray(u)
        to_scene = frame[0]
        ray_s = to_scene @ ray
        si = self.scene.scene.ray_intersect(ray_s)
        env, flood = levels
        radiance = dr.select(si.is_valid(), 0.0, env)
        throughput = mi.Float(1.0)
        active = si.is_valid()
        depth = self.settings.bounces
        for d in range(depth):
            u_light = mi.Point2f(u[4], u[5]) if d == 0 else mi.Point2f(rng.next_float32(), rng.next_float32())
            u_bsdf = mi.Point2f(u[6], u[7]) if d == 0 else mi.Point2f(rng.next_float32(), rng.next_float32())
            direct, weight, si_next, escaped = self._vertex(si, active, to_scene, u_light, u_bsdf,
                                                            rng.next_float32(), flood, last=d == depth - 1)
            radiance += throughput * (direct + dr.select(escaped, weight * env, 0.0))
            throughput = throughput * weight
            if si_next is None:
                break
            si, active = si_next, active & si_next.is_valid() & ~escaped
        return radiance * g

    def _vertex(self, si, active, to_scene, u_light, u_bsdf, u_lobe, flood, last: bool):
        """Direct flood light at a hit, its BSDF sample, and where that sample goes.

        Returns (flood radiance toward the camera, BSDF weight·albedo, the next hit or None,
        whether the BSDF sample escapes to the environment).
        """
        mi, dr = self._mi, self._dr
        ctx = mi.BSDFContext(mi.TransportMode.Radiance)
        bsdf = si.bsdf()
        albedo = self.scene.albedo_dr(si) if self.scene.textures else mi.Float(1.0)
        direct = mi.Float(0.0)
        if self.flood is not None:
            direct = self._flood_nee(si, active, to_scene, u_light, flood, bsdf, ctx) * albedo
        bs, w = bsdf.sample(ctx, si, u_lobe, u_bsdf, active)
        ok = active & (bs.pdf > 0)
        weight = dr.select(ok, w[self.channel] * albedo, 0.0)
        ray = si.spawn_ray(si.to_world(bs.wo))
        if last:
            return direct, weight, None, ok & ~self.scene.scene.ray_test(ray, ok)
        nxt = self.scene.scene.ray_intersect(ray, ok)
        return direct, weight, nxt, ok & ~nxt.is_valid()

    def _flood_nee(self, si, active, to_scene, u_light, level, bsdf, ctx):
        """Next-event estimate of the flood light: L_e·A·f·cos θ_x·cos θ_L/r² (shadow ray)."""
        mi, dr, fl = self._mi, self._dr, self.flood
        centre = mi.Point3f(*floats(fl.centre_mm))
        e1, e2, n = (mi.Vector3f(*floats(v)) for v in (fl.e1, fl.e2, fl.normal))
        y = mi.Point3f(centre + ((u_light.x - 0.5) * fl.size_mm) * e1 + ((u_light.y - 0.5) * fl.size_mm) * e2)
        y_s, n_s = to_scene @ y, to_scene @ n     # a Point3f moves, a Vector3f turns
        d = y_s - si.p
        dist2 = dr.squared_norm(d)
        wi = d * dr.rsqrt(dist2)
        cos_l = -dr.dot(n_s, wi)
        ok = active & (cos_l > 0)
        f = bsdf.eval(ctx, si, si.to_local(wi), ok)[self.channel]
        ok &= f > 0
        ok &= ~self.scene.scene.ray_test(si.spawn_ray_to(y_s), ok)
        return dr.select(ok, level * fl.area_mm2 * f * cos_l / dist2, 0.0)

"""The render loop: expected photo-electrons per pixel for one frame (laser + ambient).

Why light tracing
-----------------
Only a band a few pixels wide is lit by the laser in each row (≈ 0.3 % of the
sensor).  A camera-side renderer must either shoot samples into every pixel
(wasting > 99 % of them) or first find the band and then shoot the
band's pixels × aperture samples × sheet-thickness samples.  Light tracing
(particle tracing) puts every sample where light is *by construction*: rays
are drawn from the laser's own distribution, their first hit is the lit point
(so laser-side occlusion is automatic and exact), and each hit is splatted
through a sample point of the aperture onto the tilted sensor.  The cost is
proportional to the number of lit rows, not pixels; the estimator is unbiased
and energy-conserving (each ray carries its share of the laser power).

Laser pass (per frame)
----------------------
1. *Samples.*  N = samples_per_row · rows laser rays in groups of four.  Each
   group q has its own fan angle α_q = lo + (q + ξ)·Δα/N_groups (exact 1-D
   stratification over the fan interval the sensor sees on the sheet,
   :func:`sim.lightsheet.visible_fan_interval`, ξ one shift per frame) and one
   point of a randomly shifted Kronecker (golden-ratio / R2) sequence for the
   offset across the sheet, the aperture point and the beam angle.  The four
   samples of a group are its mirror images about the sheet's mid-plane and
   the lens centre (±δ × ±A, antithetic), which cancels the stripe centre's
   first-order Monte Carlo terms — including the δ·A defocus term.
2. *Thickness.*  A pilot ray along the sheet's mid-plane per ``pilot_block``
   samples finds the reference distance r_ref; the offset δ ~ N(0, s(r_ref)²)
   and the angle a | δ come from :func:`sim.lightsheet.conditional_angle`, so
   the ray ensemble reproduces w(r) = √(w0² + θ²(r − r_w)²) at every distance.
3. *Hit.*  ray: O_l + (δ − a·r_ref)·n + λ·(d_s(α) + a·n); first hit P.
   Rays are traced in the scene frame (``SimScene.scene_from_rig``, an opaque
   per-frame transform), so a rigid motion of the parts costs no BVH rebuild.
4. *Splat.*  Aperture point A on the lens disc (diameter f/N at x = 0); the
   thin lens sends the ray P→A toward the conjugate P' of P
   (:func:`scheimpflug.model.camera.conjugate_point`, distortion included), and it
   lands on the sensor plane (:func:`scheimpflug.model.camera.sensor_pose`) at
   q = A + λ(P' − A).  Light-tracing estimator of the flux through the lens::

       Φ_pix += Φ_ray · f_r(ω_l, ω_c)·cos θ_c · A_ap · cos θ_A / |P − A|²

   (Mitsuba's ``BSDF.eval`` returns f_r·cos θ_c, with ω_l toward the laser and
   ω_c toward A), if the segment P→A is free (camera-side occlusion, a shadow
   ray).  ``pixel_filter="box"``: the pixel whose square contains q (exact
   pixel-area integration); ``"tent"`` (default): bilinear weights, i.e. the
   pixel square ⊗ a 1-px box (+1/12 px² stripe variance) — far less
   quantisation noise in the stripe centre.  Φ_ray = I(α)·Δα/N.
5. *Electrons*: Φ · t_exp · QE · λ/(h·c).

Splats are accumulated by a sequential numba loop in sample order (hence
bit-identical for a given seed; parallel float atomics would not be).

Ambient pass (approximation)
----------------------------
One chief ray per cell of a coarse grid (every ``ambient_step_px``-th pixel in
both directions, cell centres), bilinear upsampling.  The hit surface is lit
by a uniform, unoccluded diffuse irradiance E_amb, so its radiance is
L = E_amb/π · ρ_dir(ω_c) with ρ_dir the directional albedo, estimated with
``ambient_bsdf_samples`` BSDF samples (= ρ exactly for a Lambertian surface).
Pixel flux Φ = L · A_pix · A_ap · cos θ_q · cos θ_A / |q|² (chief ray through
the lens centre).  Ignored: inter-reflections, ambient occlusion, defocus blur
of the ambient image, a background (rays that miss see black).

Speckle: :func:`sim.lightsheet.speckle_pattern` on the laser part only, grain
from the magnification at the sensor centre.

Noise of the render: the stripe centre's Monte Carlo scatter is measured by
``benchmarks/bench_render.py``: at the default 32 samples per row, mean per-row
std ≈ 0.005 px mid/far range and ≈ 0.02 px at the near end (wide stripe).

Only JIT variants (llvm_*, cuda_*) are supported; per-frame values (seed,
scene transform) are opaque, so frames reuse the compiled kernels.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numba
import numpy as np

from scheimpflug.errors import RenderError
from scheimpflug.model.camera import (
    SensorPose,
    chief_ray_from_pixel,
    sensor_point_from_pixel,
    sensor_pose,
    sheet_point_from_pixel,
)
from scheimpflug.model.rig import Rig

from .lens import LensConnection, floats
from .lightsheet import light_sheet, speckle_grain_um, speckle_pattern, visible_fan_interval
from .materials import SPECKLE_CONTRAST, channel_for_wavelength, is_translucent
from .render_limits import check_laser_samples
from .scene import SimScene
from .transport import LightTransport, TransportResult
from .variant import is_jit_variant

__all__ = [
    "FrameLight",
    "PendingLight",
    "RenderSettings",
    "Renderer",
]

PLANCK_J_S = 6.62607015e-34
LIGHT_SPEED_M_S = 299792458.0


@dataclass(frozen=True)
class RenderSettings:
    """Sampling settings of :class:`Renderer`.

    Frozen; validated on construction.

    Parameters
    ----------
    samples_per_row : int, default 32
        Laser samples (rays = splats) per sensor row [-]: the laser pass shoots
        N = samples_per_row · rows rays over the visible fan, plus as many shadow rays and
        N/pilot_block pilot rays.  (This light tracer has no "band": every sample lands
        on the lit band, so this is the number of splats per lit row.)
    pilot_block : int, default 8
        Samples sharing one pilot ray, a multiple of 4 [-].
    fan_margin_deg : float, default 0.25
        Widening of the visible fan interval on each side [deg].
    ambient : bool, default True
        Render the ambient pass (skipped anyway when E_amb = 0).
    ambient_step_px : int, default 8
        Ambient chief rays every this many pixels in u and v [px].
    ambient_bsdf_samples : int, default 1
        BSDF samples per ambient chief ray (directional albedo) [-].
    speckle : bool, default True
        Apply speckle when the rig's ``speckle_contrast`` > 0.
    seed : int, default 0
        Base seed, mixed with the per-frame seed of :meth:`Renderer.render`.
    pixel_filter : {"tent", "box"}
        How a splat lands in pixels: ``"box"`` — the pixel whose square holds
        it (exact pixel-area integration); ``"tent"`` (default) — bilinear weights over the
        four nearest pixel centres, i.e. the pixel square convolved with a further 1-px box
        (adds 1/12 px² to the stripe's variance, like mild pixel crosstalk) but removes
        the quantisation noise of the box, so the stripe centre converges much faster.
    rr_depth : int, default 3
        Path depth up to which no Russian roulette is played (multi-bounce, rig key
        ``[twin] bounces``) [-].
    secondary_thinning : int, default 4
        One laser path in this many (random within each block, its power multiplied
        accordingly) continues beyond the first surface; 4 = 8 of the default 32 samples
        per row carry the inter-reflected light [-].
    subsurface_max_steps : int, default 512
        Events after which a subsurface random walk is abandoned [-].
    subsurface_thinning : int, default 2
        One path in this many that enters a translucent material without a tabulated
        response (g ≠ 0) walks in it (its power multiplied accordingly); a walk splats at
        every scattering vertex [-].

    Raises
    ------
    RenderError
        When ``pixel_filter`` is not ``"box"`` or ``"tent"``, ``pilot_block`` is not
        a multiple of 4, or a count (``samples_per_row``, ``pilot_block``,
        ``ambient_step_px``, ``ambient_bsdf_samples``, ``rr_depth``,
        ``secondary_thinning``, ``subsurface_max_steps``, ``subsurface_thinning``) is not an
        integer ≥ 1.
    """

    samples_per_row: int = 32
    pilot_block: int = 8
    fan_margin_deg: float = 0.25
    ambient: bool = True
    ambient_step_px: int = 8
    ambient_bsdf_samples: int = 1
    speckle: bool = True
    seed: int = 0
    pixel_filter: str = "tent"
    rr_depth: int = 3
    secondary_thinning: int = 4
    subsurface_max_steps: int = 512
    subsurface_thinning: int = 2

    def __post_init__(self) -> None:
        if self.pixel_filter not in ("box", "tent"):
            raise RenderError(f"pixel_filter = {self.pixel_filter!r}: must be 'box' or 'tent'")
        if self.pilot_block % 4:
            raise RenderError(f"pilot_block = {self.pilot_block}: must be a multiple of 4 "
                              "(samples come in mirrored groups of four)")
        for name in ("samples_per_row", "pilot_block", "ambient_step_px", "ambient_bsdf_samples",
                     "rr_depth", "subsurface_max_steps", "secondary_thinning",
                     "subsurface_thinning"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 1):
                raise RenderError(f"RenderSettings.{name} = {value!r}: must be an integer ≥ 1")


# Additive-recurrence (Kronecker) low-discrepancy constants as 32-bit fixed point:
# golden ratio (thickness: with the exact 1-D fan stratification it forms a Fibonacci
# lattice), plastic-number R2 pair (aperture disc), √2 − 1 (angle within the beam).
_KRONECKER_U32 = tuple(int(round(c * 2**32)) & 0xFFFFFFFF for c in (
    0.6180339887498949, 0.7548776662466927, 0.5698402909980532, 0.41421356237309503))


@dataclass
class FrameLight:
    """A rendered frame and its laser light by origin (expected electrons).

    Parameters
    ----------
    image : (rows, columns) float32
        Laser (with speckle) + ambient [e⁻].
    laser : (rows, columns) float32 or None
        All laser light before speckle; None when not split (the ideal twin) [e⁻].
    coherent : (rows, columns) float32 or None
        Laser light weighted by each splat's speckle contrast [e⁻].
    secondary : (rows, columns) float32 or None
        Light that reached the imaged surface after ≥ 1 earlier surface
        (inter-reflections; their subsurface light included) [e⁻].
    subsurface : (rows, columns) float32 or None
        Light that entered the first lit surface and left it elsewhere [e⁻].
    walks : tuple
        (number of subsurface walks, their total events).
    """

    image: np.ndarray
    laser: np.ndarray | None = None
    coherent: np.ndarray | None = None
    secondary: np.ndarray | None = None
    subsurface: np.ndarray | None = None
    walks: tuple = (0, 0)


class PendingLight:
    """A frame begun by :meth:`Renderer.begin_light`: its light split, and what is left to compute.

    Parameters
    ----------
    light : FrameLight
        The frame's light; its ``image`` is final once :meth:`finish` has run.
    rest : callable or None
        What is left (no scene query), returning ``light``; None when nothing is.
    """

    def __init__(self, light: FrameLight, rest: Callable[[], FrameLight] | None = None) -> None:
        self.light, self._rest = light, rest

    @property
    def done(self) -> bool:
        """True when nothing is left to compute (``light.image`` is final)."""
        return self._rest is None

    def finish(self) -> FrameLight:
        """Compute what is left (once; any thread) and return the frame's light.

        Returns
        -------
        FrameLight
            The finished frame.
        """
        if self._rest is not None:
            rest, self._rest = self._rest, None
            rest()
        return self.light


def _border_pixels(pose: SensorPose, n: int = 33) -> np.ndarray:
    u = np.linspace(-0.5, pose.columns - 0.5, n)
    v = np.linspace(-0.5, pose.rows - 0.5, n)
    edges = [np.stack([u, np.full(n, v[0])], 1), np.stack([u, np.full(n, v[-1])], 1),
             np.stack([np.full(n, u[0]), v], 1), np.stack([np.full(n, u[-1]), v], 1)]
    return np.concatenate(edges)


class Renderer:
    """Renders frames of a :class:`~sim.scene.SimScene` as seen by a rig.

    The algorithm (light tracing of the laser, chief-ray ambient pass) is
    described in the module docstring.  Images are expected photo-electrons per
    pixel, before sensor noise (:mod:`sim.sensor`).

    Parameters
    ----------
    rig : Rig
        The rig: lens, sensor (exposure, quantum efficiency), laser, ambient light.
    sim_scene : SimScene
        The parts; its Mitsuba variant must be a JIT variant.
    settings : RenderSettings, optional
        Sampling settings; default ``RenderSettings()``.
    pose : SensorPose, optional
        Sensor pose; default :func:`scheimpflug.model.camera.sensor_pose` (rig).  A custom pose
        (e.g. an untilted sensor) changes where light lands, not the lens.

    Attributes
    ----------
    shape : tuple of int
        ``(rows, columns)`` of the rendered images [px].
    sheet : LightSheet
        The rig's light sheet (:func:`sim.lightsheet.light_sheet`).
    aperture_radius_mm : float
        Radius of the entrance pupil, f/(2N) [mm].
    electrons_per_watt : float
        Photo-electrons per watt of flux on a pixel over the exposure,
        t_exp · QE · λ/(h·c) [e⁻/W].
    fan_interval_rad : tuple of float
        Fan-angle interval that the sensor sees on the sheet, with margins [rad].

    Raises
    ------
    RenderError
        If the scene's Mitsuba variant is not a JIT (llvm_*/cuda_*) variant, or the laser
        samples of a frame would not fit the memory budget (:mod:`sim.render_limits`).
    """

    def __init__(self, rig: Rig, sim_scene: SimScene, settings: RenderSettings | None = None,
                 pose: SensorPose | None = None) -> None:
        if not is_jit_variant(sim_scene.variant):
            raise RenderError(f"the renderer needs a JIT Mitsuba variant (llvm_*/cuda_*), got "
                              f"{sim_scene.variant}: install libLLVM ≥ 17 (apt-get install libllvm19)")
        import drjit as dr
        import mitsuba as mi

        self._mi, self._dr = mi, dr
        self.rig, self.scene = rig, sim_scene
        self.settings = settings or RenderSettings()
        self.pose = pose or sensor_pose(rig)
        check_laser_samples(self.settings.samples_per_row, self.pose.rows, rig.twin.bounces,
                            "RenderSettings.samples_per_row")      # before Dr.Jit allocates for minutes
        self.sheet = light_sheet(rig)
        self.shape = (self.pose.rows, self.pose.columns)
        lens = rig.lens
        self.aperture_radius_mm = 0.5 * lens.focal_length_mm / lens.f_number
        self.aperture_area_mm2 = math.pi * self.aperture_radius_mm**2
        photon_j = PLANCK_J_S * LIGHT_SPEED_M_S / (rig.laser.wavelength_nm * 1e-9)
        self.electrons_per_watt = rig.sensor.exposure_ms * 1e-3 * rig.sensor.quantum_efficiency \
            / photon_j  # [e⁻ per W of flux over the exposure]
        self.channel = channel_for_wavelength(rig.laser.wavelength_nm)
        self.lens = LensConnection(rig, self.pose, mi, dr)
        self._contrast = self._part_contrast()
        self.transport = LightTransport(
            mi, dr, sim_scene, self.lens, self.channel, rig.twin.bounces, self.shape,
            self.electrons_per_watt, self.settings.rr_depth, self.settings.subsurface_max_steps,
            self._contrast, self.settings.secondary_thinning, self.settings.subsurface_thinning)
        self._setup_laser()
        self._setup_ambient()
        self._frame = sim_scene.transforms_dr()  # (scene_from_rig, rig_from_scene) of the frame
        self._laser_tf = None                    # this frame's sheet pose (pointing), opaque
        self._speckle_model = None
        #: wall time [s] spent per stage since construction (``benchmarks/bench_optics.py``)
        self.timings = {"ambient": 0.0, "first_hit": 0.0, "transport": 0.0, "accumulate": 0.0,
                        "speckle": 0.0, "finish": 0.0}

    def _part_contrast(self) -> np.ndarray:
        """Speckle contrast of each part's surface light, indexed by part index + 1."""
        c = [1.0]
        for spec, medium in zip(self.scene.specs, self.scene.media):
            surface_gloss = medium is not None          # a dielectric boundary's reflection
            c.append(1.0 if surface_gloss or not is_translucent(spec.material)
                     else SPECKLE_CONTRAST[spec.material])
        return np.asarray(c, np.float32)

    # ------------------------------------------------------------ setup
    def _setup_laser(self) -> None:
        pts = sheet_point_from_pixel(self.rig, _border_pixels(self.pose), self.pose)
        lo, hi = visible_fan_interval(self.sheet, pts, math.radians(self.settings.fan_margin_deg))
        self.fan_interval_rad = (lo, hi)
        block = self.settings.pilot_block
        self.n_pilot = -(-(self.settings.samples_per_row * self.pose.rows) // block)
        self.n_groups = self.n_pilot * (block // 4)

    def _setup_ambient(self) -> None:
        mi, pose, step = self._mi, self.pose, self.settings.ambient_step_px
        nc, nr = -(-pose.columns // step), -(-pose.rows // step)
        uu = step * np.arange(nc) + 0.5 * (step - 1)
        vv = step * np.arange(nr) + 0.5 * (step - 1)
        uv = np.stack(np.meshgrid(uu, vv), axis=-1).reshape(-1, 2)
        dirs = chief_ray_from_pixel(self.rig, uv, pose)
        q = sensor_point_from_pixel(pose, uv)        # relative to the lens centre:
        q[:, 0] -= self.lens.centre_x_mm
        qn = np.linalg.norm(q, axis=1)
        cos_a, cos_q = np.abs(q[:, 0]) / qn, np.abs(q @ pose.normal) / qn
        g = pose.pitch_mm**2 * self.aperture_area_mm2 * cos_a * cos_q / qn**2  # [mm²·sr]
        self._amb_grid = (nr, nc)
        self._amb_dirs = mi.Vector3f(dirs.T.astype(np.float32))
        self._amb_e_per_radiance = g * 1e-6 * self.electrons_per_watt  # [e⁻ per W/(m²·sr)]

    # ------------------------------------------------------------ public
    def render(self, rig_from_part, seed: int, rig_from_laser=None) -> np.ndarray:
        """Expected photo-electrons per pixel of one frame (laser + ambient).

        Sets the scene's pose (:meth:`SimScene.set_pose`), then renders the
        ambient pass and the laser pass (all bounces and subsurface light of the
        rig's ``[twin]`` table, speckle on the laser part when enabled).

        Parameters
        ----------
        rig_from_part : (4, 4) or (n_parts, 4, 4) float
            Pose of the parts in the rig frame [mm].
        seed : int
            Frame seed (≥ 0), mixed with ``settings.seed``: same seeds, same
            image, bit for bit.
        rig_from_laser : (4, 4) float, optional
            This frame's pose of the laser sheet (pointing drift,
            :func:`sim.lightsheet.pointing_pose`) [mm]; None = the nominal sheet.

        Returns
        -------
        (rows, columns) float32
            Laser (all bounces, subsurface light, speckle) + ambient [e⁻].

        Raises
        ------
        RenderError
            When ``seed`` < 0.
        ValueError
            When ``rig_from_part`` has neither shape ``(4, 4)`` nor ``(n_parts, 4, 4)``.
        """
        return self.render_light(rig_from_part, seed, rig_from_laser).image

    def render_light(self, rig_from_part, seed: int, rig_from_laser=None) -> FrameLight:
        """One frame with its light split by origin (for the truth of secondary light).

        Parameters
        ----------
        rig_from_part : (4, 4) or (n_parts, 4, 4) float
            Pose of the parts in the rig frame [mm].
        seed : int
            Frame seed (≥ 0), as in :meth:`render`.
        rig_from_laser : (4, 4) float, optional
            This frame's pose of the laser sheet, as in :meth:`render` [mm].

        Returns
        -------
        FrameLight
            The image and, beyond the ideal twin, its laser light by origin.
        """
        return self.begin_light(rig_from_part, seed, rig_from_laser).finish()

    def begin_light(self, rig_from_part, seed: int, rig_from_laser=None) -> PendingLight:
        """:meth:`render_light` up to what needs the posed scene; the rest in ``finish()``.

        Everything that queries the scene — pose, ambient light, the laser's paths, the
        surface speckle's chief-ray hits — runs here; what is left (the surface
        speckle's deposit and coherent sums, or on the ideal twin the ambient grid's
        interpolation and the splats: numba and OpenCV on arrays) runs in the returned
        object's ``finish()``, which may be called on another thread after the scene is
        posed for the next frame (the pipelined frame loop).  ``begin_light(...).finish()``
        is :meth:`render_light`, value for value.

        Parameters
        ----------
        rig_from_part : (4, 4) or (n_parts, 4, 4) float
            Pose of the parts in the rig frame [mm].
        seed : int
            Frame seed (≥ 0), as in :meth:`render`.
        rig_from_laser : (4, 4) float, optional
            This frame's pose of the laser sheet, as in :meth:`render` [mm].

        Returns
        -------
        PendingLight
            The frame's light split now (``light.image`` once finished) and what is left.
        """
        self._pose_frame(rig_from_part, rig_from_laser)
        key = self._key(seed)
        t0 = time.perf_counter()
        coarse = self._ambient_coarse(key)
        self.timings["ambient"] += time.perf_counter() - t0
        first, extra = self._laser_paths(key)
        if extra is None and not self._speckle_on():     # the ideal twin, as it always was
            light = FrameLight(None)

            def finish_ideal() -> FrameLight:
                t2 = time.perf_counter()
                out = self._ambient_full(coarse)
                self._splat_into(out, first[0], first[1])
                light.image = out
                self.timings["finish"] += time.perf_counter() - t2   # only here: one thread
                return light

            return PendingLight(light, finish_ideal)
        t0 = time.perf_counter()
        out = self._ambient_full(coarse)
        self.timings["ambient"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        if extra is None and self.rig.twin.speckle_model == "sensor":
            out += self._accumulate(first[0], first[1]) * self._speckle(key).astype(np.float32)
            return PendingLight(FrameLight(out))
        light = self._combine(first, extra)
        t1 = time.perf_counter()
        self.timings["accumulate"] += t1 - t0
        if not self._speckle_on() or self.rig.twin.speckle_model == "sensor":
            out += self._speckled(light, key) if self._speckle_on() else light.laser
            self.timings["speckle"] += time.perf_counter() - t1
            light.image = out
            return PendingLight(light)
        prepared = self._surface_speckle().prepare(light.laser)
        coherent = light.coherent * self.sheet.speckle_contrast
        scene_s = time.perf_counter() - t1

        def finish() -> FrameLight:
            t2 = time.perf_counter()
            out.__iadd__(prepared.apply(light.laser, coherent))
            light.image = out
            self.timings["speckle"] += scene_s + time.perf_counter() - t2   # only here: one thread
            return light

        return PendingLight(light, finish)

    def render_components(self, rig_from_part, seed: int,
                          rig_from_laser=None) -> tuple[np.ndarray, np.ndarray]:
        """Expected electrons of one frame, laser and ambient light apart.

        Parameters
        ----------
        rig_from_part : (4, 4) or (n_parts, 4, 4) float
            Pose of the parts in the rig frame [mm].
        seed : int
            Frame seed (≥ 0), as in :meth:`render`.
        rig_from_laser : (4, 4) float, optional
            This frame's pose of the laser sheet, as in :meth:`render` [mm].

        Returns
        -------
        laser : (rows, columns) float32
            Laser light, speckle applied when enabled [e⁻].
        ambient : (rows, columns) float32
            Ambient light [e⁻].  ``laser + ambient`` is :meth:`render` (up to
            float32 rounding of the sum).

        Raises
        ------
        RenderError
            When ``seed`` < 0.
        ValueError
            When ``rig_from_part`` has neither shape ``(4, 4)`` nor ``(n_parts, 4, 4)``.
        """
        self._pose_frame(rig_from_part, rig_from_laser)
        key = self._key(seed)
        first, extra = self._laser_paths(key)
        light = self._combine(first, extra)
        laser = self._speckled(light, key) if self._speckle_on() else light.laser
        return laser, self._ambient_full(self._ambient_coarse(key))

    def speckle_grain_px(self) -> float:
        """Speckle grain on the sensor, in pixels.

        Returns
        -------
        float
            1.22·λ·N·(1 + m) divided by the pixel pitch [px], with m = f/(x − f)
            the magnification of the sheet point imaged at the sensor centre
            (x its rig-frame distance along the optical axis); m = 0 when that
            point is not finite or not beyond the focal length.
        """
        centre = np.array([0.5 * (self.pose.columns - 1), 0.5 * (self.pose.rows - 1)])
        x = sheet_point_from_pixel(self.rig, centre, self.pose)[0]
        f = self.rig.lens.focal_length_mm
        mag = f / (x - f) if np.isfinite(x) and x > f else 0.0
        return speckle_grain_um(self.rig.laser.wavelength_nm, self.rig.lens.f_number, mag) \
            / (self.pose.pitch_mm * 1e3)

    def render_point_source(self, point_mm, intensity_w_sr: float, n_samples: int = 65536,
                            seed: int = 0) -> np.ndarray:
        """Expected electrons of an isotropic point emitter.

        Parameters
        ----------
        point_mm : (3,) float
            Emitter position, rig frame [mm] (x > f).
        intensity_w_sr : float
            Radiant intensity [W/sr].
        n_samples : int, default 65536
            Aperture samples (randomly shifted R2 low-discrepancy sequence) [-].
        seed : int, default 0
            Seed of the sequence's shift (≥ 0).

        Returns
        -------
        (rows, columns) float32
            Expected electrons per pixel [e⁻].

        Raises
        ------
        RenderError
            When ``seed`` < 0.

        Notes
        -----
        The spot is the thin-lens blur of the point on the sensor (same camera-side code
        as the laser pass); parts between the point and the aperture, in their
        current pose, shadow it.
        """
        mi, dr = self._mi, self._dr
        s = dr.opaque(mi.UInt32, self._key(seed))
        i = dr.arange(mi.UInt32, n_samples)
        u = mi.Point2f(*[_kronecker(mi, i, k + 1, s) for k in range(2)])
        p = mi.Point3f(*floats(point_mm))
        geo, uv, ok, a = self.lens.connect(p, mi.Bool(True), u)
        v = a - p
        length = dr.norm(v)
        to_scene = self.scene.transforms_dr()[0]
        ray = to_scene @ mi.Ray3f(mi.Ray3f(p, v / length), length * (1 - 1e-5))
        ok &= ~self.scene.scene.ray_test(ray, ok)
        flux = dr.select(ok, geo * (intensity_w_sr / n_samples), 0.0)
        dr.eval(flux, uv)
        return self._accumulate(np.asarray(uv, np.float32), np.asarray(flux, np.float32))

    def render_point_light(self, rig_from_part, point_mm, intensity_w_sr: float,
                           cone_axis, cone_half_angle_deg: float, n_rays: int,
                           seed: int = 0) -> FrameLight:
        """Light an isotropic point source sheds on the scene, traced like the laser.

        The source's rays (uniform within a cone, which must hold every part the
        light should reach) go through the same first-hit splat, multi-bounce
        transport and subsurface walks as the laser sheet's; no ambient light,
        no speckle.  Used to compare the transport with Mitsuba's own integrators.

        Parameters
        ----------
        rig_from_part : (4, 4) or (n_parts, 4, 4) float
            Pose of the parts [mm].
        point_mm : (3,) float
            Source position, rig frame [mm].
        intensity_w_sr : float
            Radiant intensity [W/sr].
        cone_axis : (3,) float
            Axis of the emission cone (rig frame).
        cone_half_angle_deg : float
            Half-angle of the cone [deg].
        n_rays : int
            Rays (uniform in the cone's solid angle).
        seed : int
            Frame seed.

        Returns
        -------
        FrameLight
            ``laser`` and ``image`` hold the source's light (no ambient).
        """
        mi, dr = self._mi, self._dr
        self.scene.set_pose(rig_from_part)
        key = self._key(seed)
        self._frame = self.scene.transforms_dr()
        s = dr.opaque(mi.UInt32, key)
        i = dr.arange(mi.UInt32, n_rays)
        u = [mi.sample_tea_float32(i, s ^ mi.UInt32(0x1000193 * (k + 1)), 6) for k in range(4)]
        cos_max = math.cos(math.radians(cone_half_angle_deg))
        local = mi.warp.square_to_uniform_cone(mi.Point2f(u[0], u[1]), cos_max)
        d = mi.Frame3f(mi.Vector3f(*floats(np.asarray(cone_axis) / np.linalg.norm(cone_axis))))
        ray = mi.Ray3f(mi.Point3f(*floats(point_mm)), d.to_world(local))
        solid_angle = 2.0 * math.pi * (1.0 - cos_max)
        flux = mi.Float(intensity_w_sr * solid_angle / n_rays) + 0.0 * u[0]
        first, extra = self._trace_from(ray, flux, mi.Point2f(u[2], u[3]), s)
        return self._combine(first, extra)

    def _speckle_on(self) -> bool:
        return self.settings.speckle and self.sheet.speckle_contrast > 0

    def _speckled(self, light: FrameLight, key: int) -> np.ndarray:
        """Laser light with speckle: I + I_c·(S − 1), S the model's pixel speckle (mean 1)."""
        if self.rig.twin.speckle_model == "sensor":
            return light.laser * self._speckle(key).astype(np.float32)
        c = self.sheet.speckle_contrast
        return self._surface_speckle().apply(light.laser, light.coherent * c)

    def _surface_speckle(self):
        """The surface speckle model (:class:`sim.speckle.SurfaceSpeckle`), made on first use."""
        if self._speckle_model is None:
            from .speckle import SurfaceSpeckle

            self._speckle_model = SurfaceSpeckle(self.rig, self.pose, self.scene,
                                                 self.settings.seed)
        return self._speckle_model

    def _speckle(self, key: int) -> np.ndarray:
        return speckle_pattern(self.shape, self.sheet.speckle_contrast, self.speckle_grain_px(), key)

    # ------------------------------------------------------------ internals
    def _pose_frame(self, rig_from_part, rig_from_laser) -> None:
        """Pose the parts and the laser sheet for one frame (opaque transforms: no recompile)."""
        self.scene.set_pose(rig_from_part)
        self._frame = self.scene.transforms_dr()
        self._laser_tf = None
        if rig_from_laser is not None:
            mi, dr = self._mi, self._dr
            m = np.asarray(rig_from_laser, dtype=np.float64).astype(np.float32)
            self._laser_tf = mi.Transform4f(dr.opaque(mi.Matrix4f(m)))

    def _posed_ray(self, ray):
        """A laser ray built on the nominal sheet, moved by this frame's sheet pose."""
        return ray if self._laser_tf is None else self._laser_tf @ ray

    def _key(self, seed: int) -> int:
        if int(seed) < 0:
            raise RenderError(f"seed = {seed}: must be ≥ 0")
        h = (int(seed) * 0x9E3779B1 + int(self.settings.seed) * 0x85EBCA77 + 0x165667B1)
        return h & 0xFFFFFFFF

    def _splat_into(self, img: np.ndarray, uv: np.ndarray, flux: np.ndarray) -> None:
        """Img += electrons of splats at pixel coordinates uv (2, n) with flux (n,) [W]."""
        _splat_add(img, uv[0], uv[1], flux, self.electrons_per_watt,
                   self.settings.pixel_filter == "tent")

    def _accumulate(self, uv: np.ndarray, flux: np.ndarray) -> np.ndarray:
        """Splats → electrons (rows, columns) float32 (sequential sum: deterministic)."""
        img = np.zeros(self.shape, np.float32)
        self._splat_into(img, uv, flux)
        return img

    def _alpha(self, s, group_index):
        """Fan angle of sample group q: α = lo + (q + ξ)·Δα/N_groups, ξ one shift per frame [rad]."""
        mi = self._mi
        lo, hi = self.fan_interval_rad
        xi = mi.sample_tea_float32(s, 0x7FFFFFFF)
        return lo + (group_index + xi) * ((hi - lo) / self.n_groups)

    def _fan_rays(self, s):
        """Pilot rays along the sheet's mid-plane, one per block of samples: r_ref [mm], evaluated."""
        mi, dr, sh = self._mi, self._dr, self.sheet
        per_pilot = self.settings.pilot_block // 4
        b = dr.arange(mi.Float, self.n_pilot)
        alpha = self._alpha(s, b * per_pilot + 0.5 * (per_pilot - 1))
        d = _sheet_dir(mi, dr, sh, alpha)
        if sh.bow_rad != 0.0:
            d = dr.normalize(d + _bow(sh, alpha) * mi.Vector3f(*_floats(sh.normal)))
        ray = self._frame[0] @ self._posed_ray(mi.Ray3f(mi.Point3f(*_floats(sh.origin_mm)), d))
        si = self.scene.scene.ray_intersect(ray)
        r_ref = dr.select(si.is_valid(), si.t, sh.waist_distance_mm)
        dr.eval(r_ref)
        return r_ref

    def _laser_rays(self, s, r_ref_pilot):
        """Laser rays of all samples: (ray, flux [W], aperture sample ∈ [0, 1)²).

        Sample groups q = 0 … N/4 − 1 each have their own fan angle (exact 1-D
        stratification) and a point of a randomly shifted Kronecker sequence for the
        thickness offset, the aperture point and the beam angle.  The four samples of a
        group are the four mirror images (u → 1 − u) of that point about the sheet's
        mid-plane and/or the lens centre (antithetic sampling): offsets ±δ and aperture
        points ±A in all combinations, so the stripe centre's first-order terms in δ, in A
        and in δ·A (defocus of off-sheet points) cancel within every group.
        """
        mi, dr, sh = self._mi, self._dr, self.sheet
        idx = dr.arange(mi.UInt32, 4 * self.n_groups)
        q = idx >> 2
        alpha = self._alpha(s, mi.Float(q))
        r = dr.gather(mi.Float, r_ref_pilot, q // (self.settings.pilot_block // 4))
        u = [_kronecker(mi, q, k, s) for k in range(4)]
        flip_beam, flip_lens = (idx & 1) == 1, (idx & 2) == 2
        u = [dr.select(flip_beam if k in (0, 3) else flip_lens, 1.0 - x, x) for k, x in enumerate(u)]
        theta, w0 = sh.divergence_rad, sh.waist_mm
        dl = r - sh.waist_distance_mm
        w2 = w0 * w0 + theta * theta * dl * dl
        delta = 0.5 * dr.sqrt(w2) * _norm_ppf(dr, u[0])
        a = theta * theta * dl / w2 * delta + 0.5 * theta * w0 * dr.rsqrt(w2) * _norm_ppf(dr, u[3])
        n = mi.Vector3f(*_floats(sh.normal))
        origin = mi.Point3f(*_floats(sh.origin_mm)) + (delta - a * r) * n
        if sh.bow_rad != 0.0:   # the bowed sheet: transverse angle β(α) from the origin
            a_dir = a + _bow(sh, alpha)
        else:
            a_dir = a
        ray = self._posed_ray(mi.Ray3f(origin, dr.normalize(_sheet_dir(mi, dr, sh, alpha) + a_dir * n)))
        lo, hi = self.fan_interval_rad
        flux = _fan_intensity(dr, sh, alpha) * ((hi - lo) / (4 * self.n_groups))
        return ray, flux, mi.Point2f(u[1], u[2])

    def _laser_paths(self, key: int):
        """The laser's light: first-surface splats and (if any) the transport beyond.

        Returns ``((uv (2, n) float32 [px], flux (n,) float32 [W], contrast (n,) or None),
        TransportResult or None)``.
        """
        mi, dr = self._mi, self._dr
        s = dr.opaque(mi.UInt32, key)
        ray, flux, u_ap = self._laser_rays(s, self._fan_rays(s))
        return self._trace_from(ray, flux, u_ap, s)

    def _trace_from(self, ray, flux, u_ap, s):
        """First hit + camera splat of rays (rig frame), then the transport beyond it."""
        mi, dr = self._mi, self._dr
        t0 = time.perf_counter()
        to_scene, to_rig = self._frame
        ray_s = to_scene @ ray
        si = self.scene.scene.ray_intersect(ray_s)
        p = to_rig @ si.p
        geo, uv, ok, a = self.lens.connect(p, si.is_valid(), u_ap)
        wo = to_scene @ mi.Vector3f(dr.normalize(a - p))
        ctx = mi.BSDFContext(mi.TransportMode.Importance)
        if self.transport.has_media:
            si = self.transport._outside_frame(si, ray_s.d, si.is_valid())
        f_cos = si.bsdf().eval(ctx, si, si.to_local(wo), ok)[self.channel]
        if self.scene.textures:     # a printed pattern: its albedo map (sim.textures)
            f_cos = f_cos * self.scene.albedo_dr(si)
        ok &= ~self.scene.scene.ray_test(si.spawn_ray_to(to_scene @ a), ok)
        value = dr.select(ok, flux * f_cos * geo, 0.0)
        contrast = None
        if self.transport.active:
            contrast = dr.gather(mi.Float, mi.Float(self._contrast), self.scene.part_index_dr(si))
            dr.eval(value, uv, contrast, si)
        elif self._speckle_on():
            contrast = dr.gather(mi.Float, mi.Float(self._contrast), self.scene.part_index_dr(si))
            dr.eval(value, uv, contrast)
        else:
            dr.eval(value, uv)
        first = (np.asarray(uv, np.float32), np.asarray(value, np.float32),
                 None if contrast is None else np.asarray(contrast, np.float32))
        t1 = time.perf_counter()
        self.timings["first_hit"] += t1 - t0
        if not self.transport.active:
            return first, None
        beta = dr.select(si.is_valid(), flux, 0.0)
        result = self.transport.trace(si, ray_s.d, beta, s, self._frame)
        self.transport.subsurface_electrons(result)
        self.timings["transport"] += time.perf_counter() - t1
        return first, result

    def _combine(self, first, extra: TransportResult | None) -> FrameLight:
        """Accumulate the splats into images (sequential: deterministic)."""
        uv, value, contrast = first
        laser = self._accumulate(uv, value)
        coherent = self._accumulate(uv, value * contrast) if contrast is not None else laser.copy()
        light = FrameLight(laser, laser, coherent)
        if extra is None:
            return light
        secondary = np.zeros(self.shape, np.float32)
        for b in extra.batches:
            self._splat_into(laser, b.uv, b.value)
            self._splat_into(secondary, b.uv, b.value)
            self._splat_into(coherent, b.uv, b.value * b.contrast)
        volume_contrast = float(SPECKLE_CONTRAST["paper"])
        for depth, img in sorted(extra.subsurface.items()):
            laser += img
            coherent += img * np.float32(volume_contrast)
            if depth >= 2:
                secondary += img
        light.secondary = secondary
        light.subsurface = extra.subsurface.get(1)
        light.walks = extra.walks
        return light

    def _ambient_coarse(self, key: int) -> np.ndarray | None:
        """The ambient light on the coarse grid (rows, columns of ``_amb_grid``) [e⁻]; None = no ambient.

        The scene query (Dr.Jit); :meth:`_ambient_full` makes the image of it (any thread).
        """
        e_amb = self.rig.environment.ambient_irradiance_w_m2
        if not self.settings.ambient or e_amb == 0.0:
            return None
        mi, dr = self._mi, self._dr
        s = dr.opaque(mi.UInt32, key) ^ 0x27D4EB2F
        ray = self._frame[0] @ mi.Ray3f(mi.Point3f(self.lens.centre_x_mm, 0.0, 0.0), self._amb_dirs)
        si = self.scene.scene.ray_intersect(ray)
        valid = si.is_valid()
        ctx = mi.BSDFContext(mi.TransportMode.Radiance)
        bsdf = si.bsdf()
        k_n = self.settings.ambient_bsdf_samples
        i = dr.arange(mi.UInt32, dr.width(self._amb_dirs)) * (3 * k_n)
        albedo = mi.Float(0.0)
        for k in range(k_n):
            smp = [mi.sample_tea_float32(s, i + 3 * k + c) for c in range(3)]
            _, weight = bsdf.sample(ctx, si, smp[0], mi.Point2f(smp[1], smp[2]), valid)
            albedo += dr.select(valid, weight[self.channel], 0.0)
        if self.scene.textures:
            albedo = albedo * self.scene.albedo_dr(si)
        radiance = albedo * (e_amb / (math.pi * k_n))  # [W/(m²·sr)]
        return (np.asarray(radiance, np.float64) * self._amb_e_per_radiance).astype(np.float32)

    def _ambient_full(self, coarse: np.ndarray | None) -> np.ndarray:
        """The ambient image (rows, columns) float32 [e⁻]: the coarse grid interpolated, or zeros."""
        if coarse is None:
            return np.zeros(self.shape, np.float32)
        import cv2

        nr, nc = self._amb_grid
        step = self.settings.ambient_step_px
        big = cv2.resize(coarse.reshape(nr, nc), (nc * step, nr * step),
                         interpolation=cv2.INTER_LINEAR)
        return np.ascontiguousarray(big[: self.shape[0], : self.shape[1]])


@numba.njit(cache=True, nogil=True)
def _splat_add(img, u, v, flux, scale, tent):  # pragma: no cover - compiled
    """img[v, u] += flux·scale per splat, box or bilinear ("tent"), in order (deterministic)."""
    rows, cols = img.shape
    for i in range(u.shape[0]):
        w = flux[i] * scale
        if w == 0.0:
            continue
        if not tent:
            iu, iv = int(math.floor(u[i] + 0.5)), int(math.floor(v[i] + 0.5))
            if 0 <= iu < cols and 0 <= iv < rows:
                img[iv, iu] += w
            continue
        fu, fv = math.floor(u[i]), math.floor(v[i])
        au, av = u[i] - fu, v[i] - fv
        iu, iv = int(fu), int(fv)
        for dv in range(2):
            wv = av if dv else 1.0 - av
            if 0 <= iv + dv < rows:
                for du in range(2):
                    if 0 <= iu + du < cols:
                        img[iv + dv, iu + du] += w * wv * (au if du else 1.0 - au)


def _floats(v) -> list[float]:
    return [float(c) for c in np.asarray(v, dtype=np.float64).ravel()]


def _kronecker(mi, index, dim: int, s):
    """Randomly shifted additive recurrence frac(index·c_dim + shift) ∈ [0, 1), exact in 32 bit."""
    shift = mi.sample_tea_32(s, mi.UInt32(0x3C6EF372 + dim))[0]
    return mi.Float((index * _KRONECKER_U32[dim] + shift) >> 8) * (1.0 / (1 << 24))


def _norm_ppf(dr, u):
    """Standard normal quantile Φ⁻¹(u) = √2·erfinv(2u − 1), u clamped to (0, 1)."""
    return math.sqrt(2.0) * dr.erfinv(2.0 * dr.clip(u, 1e-7, 1.0 - 1e-7) - 1.0)


def _sheet_dir(mi, dr, sheet, alpha):
    """In-sheet direction d_s(α) = cos α·e_p + sin α·e_z."""
    return dr.cos(alpha) * mi.Vector3f(*_floats(sheet.prop_dir)) + dr.sin(alpha) * mi.Vector3f(*_floats(sheet.up))


def _fan_intensity(dr, sheet, alpha):
    """I(α) = P/F·g(α) [W/rad] (Dr.Jit version of sim.lightsheet.radiant_intensity_w_per_rad)."""
    half = 0.5 * sheet.fan_full_rad
    scale = sheet.power_w / sheet.fan_full_rad
    if sheet.edge_sigma_rad == 0.0:
        out = dr.select(dr.abs(alpha) <= half, scale, 0.0)
    else:
        k = 1.0 / (math.sqrt(2.0) * sheet.edge_sigma_rad)
        out = scale * 0.5 * (dr.erf((alpha + half) * k) - dr.erf((alpha - half) * k))
    if sheet.edge_ratio == 1.0:
        return out
    c = sheet.edge_ratio - 1.0   # Powell profile (sim.lightsheet.powell_factor)
    norm = 1.0 + c * (1.0 / 3.0 + 4.0 * sheet.edge_sigma_rad**2 / sheet.fan_full_rad**2)
    x = alpha * (2.0 / sheet.fan_full_rad)
    return out * ((1.0 + c * x * x) * (1.0 / norm))


def _bow(sheet, alpha):
    """β(α) = b·(2α/F)² [rad] (Dr.Jit version of sim.lightsheet.bow_angle_rad)."""
    x = alpha * (2.0 / sheet.fan_full_rad)
    return sheet.bow_rad * x * x

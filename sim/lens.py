"""The light tracer's camera side: scene points through the thin lens onto the tilted sensor.

A light-tracing path vertex P (rig frame) is connected to a point A of the
aperture disc (diameter f/N in the lens plane x = 0).  The thin lens sends the
ray P→A toward the conjugate point P' of P
(:func:`scheimpflug.model.camera.conjugate_point`, radial distortion included),
so it lands on the sensor plane (:func:`scheimpflug.model.camera.sensor_pose`)
at q = A + λ(P' − A).  The flux of a vertex that reaches the aperture through
A is its radiant intensity toward A times the solid angle of the aperture seen
from P, estimated with the one sample A::

    Ω_ap ≈ A_ap · cos θ_A / |P − A|²          (A_ap = π (f/2N)², θ_A to the axis)

:class:`LensConnection` evaluates both in Dr.Jit for whole arrays of vertices;
the renderer, the multi-bounce transport (:mod:`sim.transport`) and the
subsurface walk (:mod:`sim.subsurface`) share it.
"""

from __future__ import annotations

import math

import numpy as np

from scheimpflug.model.camera import SensorPose, lens_state
from scheimpflug.model.distortion import is_radial
from scheimpflug.model.rig import Rig

__all__ = [
    "LensConnection",
    "distort_tangents_dr",
    "floats",
    "undistort_tangents_dr",
]


def floats(v) -> list[float]:
    """Python floats of an array's elements (flattened), for Dr.Jit constructors.

    Parameters
    ----------
    v : array_like
        Numbers.

    Returns
    -------
    list of float
        The elements in order.
    """
    return [float(c) for c in np.asarray(v, dtype=np.float64).ravel()]


def _roll(rig: Rig) -> tuple[float, float]:
    r = math.radians(rig.sensor.roll_deg)
    return math.cos(r), math.sin(r)


def _opencv_dr(lens, mx, my):
    """OpenCV's distorted (x_d, y_d) of normalised (x, y), and the radial factor and its r²-slope."""
    r2 = mx * mx + my * my
    radial = 1.0 + r2 * (lens.k1 + r2 * (lens.k2 + r2 * lens.k3))
    xd = mx * radial + 2.0 * lens.p1 * mx * my + lens.p2 * (r2 + 2.0 * mx * mx)
    yd = my * radial + lens.p1 * (r2 + 2.0 * my * my) + 2.0 * lens.p2 * mx * my
    slope = lens.k1 + r2 * (2.0 * lens.k2 + 3.0 * r2 * lens.k3)
    return xd, yd, radial, slope


def distort_tangents_dr(rig: Rig, ay, az):
    """Distorted chief-ray tangents of object tangents in Dr.Jit (``model.distortion.distort_tangents``).

    Parameters
    ----------
    rig : Rig
        The instrument (its lens's k1, k2, k3, p1, p2, aspect ratio; its sensor's roll).
    ay, az : drjit Float
        Object-side tangents y/x, z/x in the rig frame [-].

    Returns
    -------
    tuple of drjit Float
        The distorted tangents (a_d,y, a_d,z) [-].
    """
    c, s = _roll(rig)
    xd, yd, _, _ = _opencv_dr(rig.lens, -(c * ay + s * az), -(-s * ay + c * az))
    yd = yd * rig.lens.aspect_ratio
    return -(c * xd - s * yd), -(s * xd + c * yd)


def undistort_tangents_dr(rig: Rig, ady, adz, iterations: int = 10):
    """Object tangents of distorted ones, in Dr.Jit: Newton on OpenCV's 2 × 2 model.

    Parameters
    ----------
    rig : Rig
        The instrument (lens distortion, sensor roll).
    ady, adz : drjit Float
        Distorted tangents in the rig frame [-].
    iterations : int, default 10
        Newton steps [-].

    Returns
    -------
    tuple of drjit Float
        The object tangents (a_y, a_z) [-].
    """
    lens = rig.lens
    c, s = _roll(rig)
    tx, ty = -(c * ady + s * adz), -(-s * ady + c * adz) / lens.aspect_ratio
    mx, my = tx, ty
    for _ in range(iterations):
        xd, yd, radial, slope = _opencv_dr(lens, mx, my)
        off = 2.0 * mx * my * slope + 2.0 * lens.p1 * mx + 2.0 * lens.p2 * my
        ja = radial + 2.0 * mx * mx * slope + 2.0 * lens.p1 * my + 6.0 * lens.p2 * mx
        jd = radial + 2.0 * my * my * slope + 6.0 * lens.p1 * my + 2.0 * lens.p2 * mx
        rx, ry = xd - tx, yd - ty
        det = ja * jd - off * off
        mx, my = mx - (jd * rx - off * ry) / det, my - (ja * ry - off * rx) / det
    return -(c * mx - s * my), -(s * mx + c * my)


class LensConnection:
    """Thin-lens connection of rig points to the aperture and the sensor (Dr.Jit).

    Parameters
    ----------
    rig : Rig
        The instrument (focal length, f-number, distortion k1, k2).
    pose : SensorPose
        Where the sensor is (tilted Scheimpflug pose or any other plane).
    mi : module
        The ``mitsuba`` module with a JIT variant set.
    dr : module
        The ``drjit`` module.
    """

    def __init__(self, rig: Rig, pose: SensorPose, mi, dr) -> None:
        self._mi, self._dr = mi, dr
        self.rig, self.pose = rig, pose
        lens = rig.lens
        self.aperture_radius_mm = 0.5 * lens.focal_length_mm / lens.f_number
        self.aperture_area_mm2 = math.pi * self.aperture_radius_mm**2
        state = lens_state(rig)          # the real lens: f' = f + Δf, centre at x = δ
        self.focal_length_mm, self.centre_x_mm = state.focal_length_mm, state.centre_x_mm
        self._plane = tuple(floats(v) for v in (pose.origin_mm, pose.normal, pose.u_dir,
                                                  pose.v_dir))

    def aperture_point(self, u_ap):
        """Rig point A on the aperture disc for samples u ∈ [0, 1)² (concentric map).

        Parameters
        ----------
        u_ap : mitsuba.Point2f
            Uniform samples.

        Returns
        -------
        mitsuba.Point3f
            A = (δ, r·x, r·y) [mm], δ the lens centre (0 for an ideal lens,
            :func:`scheimpflug.model.camera.lens_state`).
        """
        mi = self._mi
        disc = mi.warp.square_to_uniform_disk_concentric(u_ap) * self.aperture_radius_mm
        return mi.Point3f(self.centre_x_mm, disc.x, disc.y)

    def connect(self, p, active, u_ap):
        """Thin-lens splat of rig points p through aperture samples u_ap ∈ [0, 1)².

        Parameters
        ----------
        p : mitsuba.Point3f
            Vertices, rig frame [mm].
        active : mitsuba.Bool
            Lanes to connect.
        u_ap : mitsuba.Point2f
            Aperture samples.

        Returns
        -------
        geo : mitsuba.Float
            A_ap·cos θ_A / |P − A|², the aperture's solid angle seen from P [sr].
        uv : mitsuba.Point2f
            Pixel coordinates of the landing point [px] (−10 where not ok).
        ok : mitsuba.Bool
            In front of the focal plane, landing on the sensor.
        a : mitsuba.Point3f
            The aperture point A [mm].
        """
        return self.connect_at(p, active, self.aperture_point(u_ap))

    def connect_at(self, p, active, a):
        """As :meth:`connect`, with the aperture point A [mm] given (rig frame).

        Parameters
        ----------
        p : mitsuba.Point3f
            Vertices, rig frame [mm].
        active : mitsuba.Bool
            Lanes to connect.
        a : mitsuba.Point3f
            Aperture points (x = δ, :meth:`aperture_point`) [mm].

        Returns
        -------
        tuple
            ``(geo, uv, ok, a)`` as :meth:`connect`.
        """
        mi, dr, pose = self._mi, self._dr, self.pose
        f = self.focal_length_mm
        v = p - a
        dist2 = dr.squared_norm(v)
        geo = self.aperture_area_mm2 * v.x * dr.rsqrt(dist2) / dist2
        img = self._conjugate(p)
        origin, normal, u_dir, v_dir = self._plane
        o, n = mi.Point3f(*origin), mi.Vector3f(*normal)
        w = img - a
        lam = dr.dot(o - a, n) / dr.dot(w, n)
        rel = a + lam * w - o
        uv = mi.Point2f(dr.dot(rel, mi.Vector3f(*u_dir)),
                        dr.dot(rel, mi.Vector3f(*v_dir))) / pose.pitch_mm
        ok = active & (p.x - self.centre_x_mm > f * 1.0001) & (lam > 0) & (uv.x > -1.0) & (uv.x < pose.columns) \
            & (uv.y > -1.0) & (uv.y < pose.rows)
        return geo, dr.select(ok, uv, -10.0), ok, a

    def landing(self, p, a):
        """Where the ray from rig point p through aperture point a meets the sensor plane.

        Unmasked (also off the sensor), for finite differences of the projection.

        Parameters
        ----------
        p : mitsuba.Point3f
            Rig points in front of the focal plane [mm].
        a : mitsuba.Point3f
            Aperture points [mm].

        Returns
        -------
        mitsuba.Point2f
            Pixel coordinates [px].
        """
        mi, dr, pose = self._mi, self._dr, self.pose
        img = self._conjugate(p)
        origin, normal, u_dir, v_dir = self._plane
        o, n = mi.Point3f(*origin), mi.Vector3f(*normal)
        w = img - a
        rel = a + dr.dot(o - a, n) / dr.dot(w, n) * w - o
        return mi.Point2f(dr.dot(rel, mi.Vector3f(*u_dir)),
                          dr.dot(rel, mi.Vector3f(*v_dir))) / pose.pitch_mm

    def _conjugate(self, p):
        """Distorted conjugate point P' of rig points p through the real lens (centre x = δ)."""
        mi, f, cx = self._mi, self.focal_length_mm, self.centre_x_mm
        k1, k2 = self.rig.lens.k1, self.rig.lens.k2
        px = p.x - cx
        mag = -f / (px - f)
        if not is_radial(self.rig.lens):
            ady, adz = distort_tangents_dr(self.rig, p.y / px, p.z / px)
            return mi.Point3f(mag * px + cx, mag * px * ady, mag * px * adz)
        t2 = (p.y * p.y + p.z * p.z) / (px * px)
        dist = 1.0 + k1 * t2 + k2 * t2 * t2
        return mi.Point3f(mag * px + cx, mag * p.y * dist, mag * p.z * dist)

"""Procedural parts: each generator returns a :class:`~scenes.part.Part` [mm] in its own frame.

Every part stands on ``z = 0`` with the rotary axis along ``z`` and carries the
exact analytic description used for scoring (``Part.analytic``).  Curved
surfaces are polygons whose chord sagitta is ≤ ``max_sagitta_mm`` (default
0.1 µm, far below the 0.05 mm accuracy target); knurls are meshed exactly on
an aligned grid (see :mod:`scenes.knurl`) with edges ≤ ``max_edge_mm``.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

from scenes import knurl as _knurl
from scheimpflug.errors import MeshError

from .part import Part
from .revolve import box_mesh, revolved_mesh, segments_for_sagitta

__all__ = [
    "ball_bar",
    "blocker",
    "box",
    "cylinder",
    "knurled_cylinder",
    "knurled_ring",
    "plate",
    "plate_face_x_mm",
    "sphere",
    "tape_roll",
]

_SAGITTA_MM = 1e-4  # default chord sagitta of smooth curved surfaces: 0.1 µm


def _positive(**values: float) -> None:
    for name, v in values.items():
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0):
            raise MeshError(f"{name} = {v!r}: must be a finite number > 0")


def _eye() -> list:
    return np.eye(4).tolist()


def _box_part(name, lo, hi, material, analytic) -> Part:
    return Part(name=name, mesh=box_mesh(lo, hi), material=material,
                analytic=dict(analytic, mesh_from_part=_eye()))


def plate(width_mm: float = 120.0, height_mm: float = 89.0, thickness_mm: float = 5.0, *,
          flatness_um: float = 0.0, edge_break_mm: float = 0.0, material: str = "metal",
          name: str = "plate") -> Part:
    """Calibration plate: x ∈ [0, t], y ∈ [−w/2, w/2], z ∈ [0, h] [mm].

    The measured face is the −x face at x = 0 (it faces the laser, which comes
    from −x).  Defaults: the paper's 89 mm height; 120 mm wide, 5 mm thick (assumed).

    Parameters
    ----------
    width_mm : float, default 120.0
        Width w along y [mm].
    height_mm : float, default 89.0
        Height h [mm].
    thickness_mm : float, default 5.0
        Thickness t along x [mm].
    flatness_um : float, default 0.0
        Peak-to-valley flatness F of the measured face [µm]: the face is the
        paraboloid x = −F·(1 − ρ²/ρ_max²), ρ² = y² + (z − h/2)²,
        ρ_max² = (w/2)² + (h/2)² — its corners at x = 0, its centre F nearer
        the laser when F > 0 (:func:`plate_face_x_mm`); 0 = a flat face.
    edge_break_mm : float, default 0.0
        45° chamfer c of the measured face's top and bottom edges (a machined
        plate's "broken" edges, ISO 13715) [mm]: the face spans z ∈ [c, h − c],
        the chamfers run from (x, z) = (0, c) to (c, 0) and from (0, h − c) to
        (c, h); 0 = sharp edges.  The sheet lights the chamfers too, so the lit
        stripe's ends — the plate's endpoints in the calibration — depend on
        how bright a chamfer looks from the camera.
    material : str, default "metal"
        Material tag (:data:`scenes.part.MATERIALS`).
    name : str, default "plate"
        Part name.

    Returns
    -------
    Part
        The part in its own frame (standing on ``z = 0``), with its analytic
        description (``kind`` "plate", ``flatness_um``).  A bowed face is
        meshed with edges ≤ 4 mm (chord sagitta < 1e-4 of F).

    Raises
    ------
    MeshError
        When a dimension is not a finite number > 0, the flatness is not
        finite or not smaller than the thickness, or the material is unknown.
    """
    _positive(width_mm=width_mm, height_mm=height_mm, thickness_mm=thickness_mm)
    if not (math.isfinite(flatness_um) and abs(flatness_um) * 1e-3 < thickness_mm):
        raise MeshError(f"flatness_um = {flatness_um!r}: must be finite and smaller than the thickness")
    if not (math.isfinite(edge_break_mm) and 0.0 <= edge_break_mm < min(thickness_mm, height_mm / 2)):
        raise MeshError(f"edge_break_mm = {edge_break_mm!r}: must be ≥ 0 and smaller than the thickness "
                        "and half the height")
    analytic = {"kind": "plate", "width_mm": float(width_mm), "height_mm": float(height_mm),
                "thickness_mm": float(thickness_mm), "measured_face_x_mm": 0.0,
                "measured_face_normal": [-1.0, 0.0, 0.0], "flatness_um": float(flatness_um),
                "edge_break_mm": float(edge_break_mm)}
    lo, hi = [0.0, -width_mm / 2, 0.0], [thickness_mm, width_mm / 2, height_mm]
    if flatness_um == 0.0 and edge_break_mm == 0.0:
        return _box_part(name, lo, hi, material, analytic)
    base = box_mesh(lo, hi) if edge_break_mm == 0.0 else _chamfered_plate(width_mm, height_mm, thickness_mm,
                                                                           edge_break_mm)
    if flatness_um == 0.0:
        return Part(name=name, mesh=base, material=material, analytic=dict(analytic, mesh_from_part=_eye()))
    v, f = trimesh.remesh.subdivide_to_size(base.vertices, base.faces, max_edge=_PLATE_EDGE_MM, max_iter=12)
    front = v[:, 0] <= edge_break_mm * (1 + 1e-12)  # the face and its chamfers move with the bow
    v[front, 0] += plate_face_x_mm(v[front, 1], v[front, 2], width_mm, height_mm, flatness_um)
    mesh = trimesh.Trimesh(v, f, process=False)
    return Part(name=name, mesh=mesh, material=material, analytic=dict(analytic, mesh_from_part=_eye()))


def _chamfered_plate(width_mm: float, height_mm: float, thickness_mm: float, c_mm: float) -> trimesh.Trimesh:
    """The plate's prism: its (x, z) section a rectangle with the measured face's two edges cut 45° by c."""
    t, h = thickness_mm, height_mm
    section = np.array([(c_mm, 0.0), (t, 0.0), (t, h), (c_mm, h), (0.0, h - c_mm), (0.0, c_mm)])
    n = len(section)
    v = np.concatenate([np.column_stack([section[:, 0], np.full(n, y), section[:, 1]])
                        for y in (-width_mm / 2, width_mm / 2)])
    sides = [[i, (i + 1) % n, (i + 1) % n + n, i, (i + 1) % n + n, i + n] for i in range(n)]
    caps = [[0, j + 1, j] for j in range(1, n - 1)] + [[n, n + j, n + j + 1] for j in range(1, n - 1)]
    faces = np.concatenate([np.reshape(sides, (-1, 3)), np.asarray(caps)])
    mesh = trimesh.Trimesh(v, faces, process=False)
    trimesh.repair.fix_normals(mesh)
    return mesh


_PLATE_EDGE_MM = 4.0  # longest edge of a bowed plate's mesh


def plate_face_x_mm(y_mm, z_mm, width_mm: float, height_mm: float, flatness_um: float) -> np.ndarray:
    """The measured face of a bowed plate, x as a function of (y, z).

    Parameters
    ----------
    y_mm, z_mm : array_like
        Points of the face, plate frame [mm].
    width_mm, height_mm : float
        Plate width and height [mm].
    flatness_um : float
        Peak-to-valley flatness F [µm] (:func:`plate`).

    Returns
    -------
    ndarray
        x = −F·(1 − ρ²/ρ_max²) [mm], ρ² = y² + (z − h/2)², ρ_max² = (w/2)² + (h/2)².
    """
    rho2 = np.asarray(y_mm, dtype=np.float64) ** 2 + (np.asarray(z_mm, dtype=np.float64) - height_mm / 2) ** 2
    rho2_max = (width_mm / 2) ** 2 + (height_mm / 2) ** 2
    return -1e-3 * flatness_um * (1.0 - rho2 / rho2_max)


def blocker(thickness_mm: float = 2.0, width_mm: float = 60.0, height_mm: float = 80.0, *,
            material: str = "metal", name: str = "blocker") -> Part:
    """Thin vertical plate centred on the rotary axis: x ∈ [−t/2, t/2], y ∈ [−w/2, w/2], z ∈ [0, h].

    Its large faces are perpendicular to x; the face the laser hits at stage
    angle 0 is at x = −t/2 (``analytic["laser_face_x_mm"]``), so an axis locator
    adds t/2 to the measured face distance.

    Parameters
    ----------
    thickness_mm : float, default 2.0
        Thickness t along x [mm].
    width_mm : float, default 60.0
        Width w along y [mm].
    height_mm : float, default 80.0
        Height h [mm].
    material : str, default "metal"
        Material tag (:data:`scenes.part.MATERIALS`).
    name : str, default "blocker"
        Part name.

    Returns
    -------
    Part
        The part in its own frame (standing on ``z = 0``), with its analytic
        description (``kind`` "blocker").

    Raises
    ------
    MeshError
        When a dimension is not a finite number > 0, or the material is unknown.
    """
    _positive(thickness_mm=thickness_mm, width_mm=width_mm, height_mm=height_mm)
    analytic = {"kind": "blocker", "thickness_mm": float(thickness_mm), "width_mm": float(width_mm),
                "height_mm": float(height_mm), "laser_face_x_mm": -thickness_mm / 2,
                "axis_xy_mm": [0.0, 0.0]}
    return _box_part(name, [-thickness_mm / 2, -width_mm / 2, 0.0],
                     [thickness_mm / 2, width_mm / 2, height_mm], material, analytic)


def box(length_mm: float = 252.0, width_mm: float = 165.0, height_mm: float = 62.0, *,
        material: str = "cardboard", name: str = "box") -> Part:
    """Rectangular box lying flat, centred on the axis: x ∈ ±L/2, y ∈ ±W/2, z ∈ [0, H].

    Defaults: the paper's cardboard box, 252 × 165 × 62 mm.  Its faces are
    planes: ``analytic["planes"]`` lists (unit normal, offset) with n·x = offset.

    Parameters
    ----------
    length_mm : float, default 252.0
        Length L along x [mm].
    width_mm : float, default 165.0
        Width W along y [mm].
    height_mm : float, default 62.0
        Height H [mm].
    material : str, default "cardboard"
        Material tag (:data:`scenes.part.MATERIALS`).
    name : str, default "box"
        Part name.

    Returns
    -------
    Part
        The part in its own frame (standing on ``z = 0``), with its analytic
        description (``kind`` "box").

    Raises
    ------
    MeshError
        When a dimension is not a finite number > 0, or the material is unknown.
    """
    _positive(length_mm=length_mm, width_mm=width_mm, height_mm=height_mm)
    L, W, H = float(length_mm), float(width_mm), float(height_mm)
    planes = [[[1, 0, 0], L / 2], [[-1, 0, 0], L / 2], [[0, 1, 0], W / 2], [[0, -1, 0], W / 2],
              [[0, 0, 1], H], [[0, 0, -1], 0.0]]
    analytic = {"kind": "box", "length_mm": L, "width_mm": W, "height_mm": H,
                "centre_mm": [0.0, 0.0, H / 2],
                "planes": [{"normal": [float(c) for c in n], "offset_mm": o} for n, o in planes]}
    return _box_part(name, [-L / 2, -W / 2, 0.0], [L / 2, W / 2, H], material, analytic)


def _smooth_rows(radius_mm: float, height_mm: float, z0_mm: float = 0.0):
    return [(z0_mm, 0.0), (z0_mm, radius_mm), (z0_mm + height_mm, radius_mm), (z0_mm + height_mm, 0.0)]


def _rows_mesh(theta, rows, closed=False, r_mid=None) -> trimesh.Trimesh:
    z = np.array([z for z, _ in rows], dtype=float)
    r = np.stack([np.broadcast_to(np.asarray(rr, dtype=float), theta.shape) for _, rr in rows])
    return revolved_mesh(theta, z, r, closed=closed, r_mid_mm=r_mid)


def _theta(n: int) -> np.ndarray:
    return 2 * math.pi * np.arange(n) / n


def cylinder(diameter_mm: float = 100.0, height_mm: float = 108.0, *, max_sagitta_mm: float = _SAGITTA_MM,
             material: str = "metal", name: str = "cylinder") -> Part:
    """Smooth solid cylinder on the axis: r ≤ D/2, z ∈ [0, H] [mm].

    Parameters
    ----------
    diameter_mm : float, default 100.0
        Diameter D [mm].
    height_mm : float, default 108.0
        Height H [mm].
    max_sagitta_mm : float, default 1e-4
        Largest chord sagitta of the polygonal wall [mm].
    material : str, default "metal"
        Material tag (:data:`scenes.part.MATERIALS`).
    name : str, default "cylinder"
        Part name.

    Returns
    -------
    Part
        The part in its own frame (standing on ``z = 0``), with its analytic
        description (``kind`` "cylinder").

    Raises
    ------
    MeshError
        When a dimension is not a finite number > 0, or the material is unknown.
    """
    _positive(diameter_mm=diameter_mm, height_mm=height_mm, max_sagitta_mm=max_sagitta_mm)
    R = diameter_mm / 2
    n = segments_for_sagitta(R, max_sagitta_mm)
    mesh = _rows_mesh(_theta(n), _smooth_rows(R, height_mm))
    analytic = {"kind": "cylinder", "radius_mm": R, "diameter_mm": float(diameter_mm),
                "height_mm": float(height_mm), "z0_mm": 0.0, "z1_mm": float(height_mm),
                "axis_xy_mm": [0.0, 0.0], "smooth_z_range_mm": [0.0, float(height_mm)],
                "segments": n, "mesh_from_part": _eye()}
    return Part(name=name, mesh=mesh, material=material, analytic=analytic)


def _knurl_spec(R, z0, z1, pattern, pitch_mm, depth_mm, helix_deg) -> dict:
    try:
        return _knurl.knurl_spec(R, z0, z1, pattern=pattern, pitch_mm=pitch_mm,
                                 depth_mm=depth_mm, helix_deg=helix_deg)
    except ValueError as exc:
        raise MeshError(str(exc)) from None


def _knurl_rows(spec, max_edge_mm):
    """Rows (z, r(θ)) of a knurl band, the θ grid and exact mid-quad radii."""
    try:
        theta, z = _knurl.knurl_grid(spec, max_edge_mm)
    except ValueError as exc:
        raise MeshError(str(exc)) from None
    r = _knurl.knurl_radius_mm(theta[None, :], z[:, None], spec)
    dth = theta[1] - theta[0]
    r_mid = _knurl.knurl_radius_mm(theta[None, :] + dth / 2, 0.5 * (z[1:] + z[:-1])[:, None], spec)
    return theta, [(zj, rj) for zj, rj in zip(z, r)], r_mid


def knurled_cylinder(diameter_mm: float = 100.0, height_mm: float = 108.0, *,
                     band_z0_mm: float = 0.0, band_height_mm: float = 20.0,
                     pattern: str = "diamond", pitch_mm: float = 1.0, depth_mm: float = 0.4,
                     helix_deg: float = 30.0, max_edge_mm: float = 0.15,
                     material: str = "metal", name: str = "cylinder") -> Part:
    """Solid cylinder with a knurled band z ∈ [band_z0, band_z0 + band_height], smooth elsewhere.

    The knurl crests lie on the cylinder radius D/2 and the roots d below
    (see :mod:`scenes.knurl`); a horizontal shoulder joins the band to the
    smooth wall.  The defaults are the paper's Ø100 × 108 mm cylinder with a
    20 mm diamond-knurled bottom band (pitch 1 mm, depth 0.4 mm, 30° helix;
    pitch/depth/helix assumed).  ``band_height_mm = 0`` gives a smooth cylinder.

    Parameters
    ----------
    diameter_mm : float, default 100.0
        Diameter D (at the knurl crests) [mm].
    height_mm : float, default 108.0
        Height H [mm].
    band_z0_mm : float, default 0.0
        Bottom of the knurled band [mm].
    band_height_mm : float, default 20.0
        Height of the band [mm]; 0 gives :func:`cylinder` (the knurl
        parameters are then ignored).
    pattern : {"diamond", "straight"}
        Knurl pattern (:func:`scenes.knurl.knurl_spec`).
    pitch_mm : float, default 1.0
        Requested normal pitch of the grooves [mm] (snapped to close the circle).
    depth_mm : float, default 0.4
        Groove depth [mm].
    helix_deg : float, default 30.0
        Groove angle to the axis [deg].
    max_edge_mm : float, default 0.15
        Largest triangle edge across the teeth, along θ and z [mm].
    material : str, default "metal"
        Material tag (:data:`scenes.part.MATERIALS`).
    name : str, default "cylinder"
        Part name.

    Returns
    -------
    Part
        The part in its own frame (standing on ``z = 0``), with its analytic
        description (``kind`` "knurled_cylinder", the knurl in ``knurl``).

    Raises
    ------
    MeshError
        When a dimension is not a finite number > 0, the band does not lie within
        [0, H], a knurl parameter is out of range, or the material is unknown.
    """
    if band_height_mm == 0:
        return cylinder(diameter_mm, height_mm, material=material, name=name)
    _positive(diameter_mm=diameter_mm, height_mm=height_mm, band_height_mm=band_height_mm)
    R, H, b0, b1 = diameter_mm / 2, float(height_mm), float(band_z0_mm), float(band_z0_mm + band_height_mm)
    if not 0 <= b0 < b1 <= H:
        raise MeshError(f"knurl band [{b0}, {b1}] mm must lie within the cylinder height [0, {H}] mm")
    spec = _knurl_spec(R, b0, b1, pattern, pitch_mm, depth_mm, helix_deg)
    theta, band, band_mid = _knurl_rows(spec, max_edge_mm)
    below = [(0.0, 0.0)] + ([(0.0, R), (b0, R)] if b0 > 0 else [])
    above = ([(b1, R), (H, R)] if b1 < H else []) + [(H, 0.0)]
    rows = below + band + above
    r_mid = np.full((len(rows) - 1, len(theta)), np.nan)
    r_mid[len(below):len(below) + len(band) - 1] = band_mid
    mesh = _rows_mesh(theta, rows, r_mid=r_mid)
    smooth = [[0.0, b0]] if b0 > 0 else []
    smooth += [[b1, H]] if b1 < H else []
    analytic = {"kind": "knurled_cylinder", "radius_mm": R, "diameter_mm": float(diameter_mm),
                "height_mm": H, "z0_mm": 0.0, "z1_mm": H, "axis_xy_mm": [0.0, 0.0],
                "smooth_z_range_mm": smooth[-1] if smooth else None, "smooth_z_ranges_mm": smooth,
                "knurl": spec, "segments": len(theta), "mesh_from_part": _eye()}
    return Part(name=name, mesh=mesh, material=material, analytic=analytic)


def knurled_ring(od_mm: float = 69.0, id_mm: float = 45.0, height_mm: float = 15.0, *,
                 pattern: str = "diamond", pitch_mm: float = 1.2, depth_mm: float = 0.5,
                 helix_deg: float = 30.0, max_edge_mm: float = 0.15,
                 material: str = "knurled-metal", name: str = "ring") -> Part:
    """Ring knurled over its whole outer wall: crest Ø = OD, smooth bore Ø = ID, z ∈ [0, h].

    Defaults: the paper's OD 69 mm; ID 45, height 15, diamond knurl pitch 1.2 mm,
    depth 0.5 mm, 30° helix (assumed).

    Parameters
    ----------
    od_mm : float, default 69.0
        Outer diameter at the knurl crests [mm].
    id_mm : float, default 45.0
        Bore diameter [mm], < od_mm − 2·depth_mm.
    height_mm : float, default 15.0
        Height h [mm].
    pattern : {"diamond", "straight"}
        Knurl pattern (:func:`scenes.knurl.knurl_spec`).
    pitch_mm : float, default 1.2
        Requested normal pitch of the grooves [mm] (snapped to close the circle).
    depth_mm : float, default 0.5
        Groove depth [mm].
    helix_deg : float, default 30.0
        Groove angle to the axis [deg].
    max_edge_mm : float, default 0.15
        Largest triangle edge across the teeth, along θ and z [mm].
    material : str, default "knurled-metal"
        Material tag (:data:`scenes.part.MATERIALS`).
    name : str, default "ring"
        Part name.

    Returns
    -------
    Part
        The part in its own frame (standing on ``z = 0``), with its analytic
        description (``kind`` "knurled_ring").

    Raises
    ------
    MeshError
        When a dimension is not a finite number > 0, the bore is not smaller than
        the knurl roots, a knurl parameter is out of range, or the material is unknown.
    """
    _positive(od_mm=od_mm, id_mm=id_mm, height_mm=height_mm)
    if not id_mm < od_mm - 2 * depth_mm:
        raise MeshError(f"id_mm = {id_mm} must be < od_mm − 2·depth_mm = {od_mm - 2 * depth_mm} mm")
    ro, ri, h = od_mm / 2, id_mm / 2, float(height_mm)
    spec = _knurl_spec(ro, 0.0, h, pattern, pitch_mm, depth_mm, helix_deg)
    theta, band, band_mid = _knurl_rows(spec, max_edge_mm)
    rows = band + [(h, ri), (0.0, ri)]
    r_mid = np.full((len(rows), len(theta)), np.nan)
    r_mid[:len(band) - 1] = band_mid
    mesh = _rows_mesh(theta, rows, closed=True, r_mid=r_mid)
    analytic = {"kind": "knurled_ring", "od_mm": float(od_mm), "id_mm": float(id_mm),
                "outer_radius_mm": ro, "inner_radius_mm": ri, "height_mm": h, "z0_mm": 0.0,
                "z1_mm": h, "axis_xy_mm": [0.0, 0.0], "knurl": spec, "segments": len(theta),
                "mesh_from_part": _eye()}
    return Part(name=name, mesh=mesh, material=material, analytic=analytic)


def tape_roll(od_mm: float = 120.0, id_mm: float = 76.0, width_mm: float = 48.0, *,
              max_sagitta_mm: float = _SAGITTA_MM, material: str = "tape", name: str = "tape") -> Part:
    """Roll of tape lying flat: annulus ID/2 ≤ r ≤ OD/2, z ∈ [0, width] [mm].

    Defaults: the paper's OD 120 mm; 76 mm (3") core, 48 mm wide (assumed).

    Parameters
    ----------
    od_mm : float, default 120.0
        Outer diameter [mm].
    id_mm : float, default 76.0
        Core (inner) diameter [mm], < od_mm.
    width_mm : float, default 48.0
        Width of the tape = height of the roll lying flat [mm].
    max_sagitta_mm : float, default 1e-4
        Largest chord sagitta of the polygonal walls [mm].
    material : str, default "tape"
        Material tag (:data:`scenes.part.MATERIALS`).
    name : str, default "tape"
        Part name.

    Returns
    -------
    Part
        The part in its own frame (standing on ``z = 0``), with its analytic
        description (``kind`` "tape_roll").

    Raises
    ------
    MeshError
        When a dimension is not a finite number > 0, ``id_mm`` ≥ ``od_mm``, or the
        material is unknown.
    """
    _positive(od_mm=od_mm, id_mm=id_mm, width_mm=width_mm, max_sagitta_mm=max_sagitta_mm)
    if not id_mm < od_mm:
        raise MeshError(f"id_mm = {id_mm} must be < od_mm = {od_mm} mm")
    ro, ri, w = od_mm / 2, id_mm / 2, float(width_mm)
    n = segments_for_sagitta(ro, max_sagitta_mm)
    mesh = _rows_mesh(_theta(n), [(0.0, ro), (w, ro), (w, ri), (0.0, ri)], closed=True)
    analytic = {"kind": "tape_roll", "od_mm": float(od_mm), "id_mm": float(id_mm),
                "outer_radius_mm": ro, "inner_radius_mm": ri, "width_mm": w, "height_mm": w,
                "z0_mm": 0.0, "z1_mm": w, "axis_xy_mm": [0.0, 0.0], "segments": n,
                "mesh_from_part": _eye()}
    return Part(name=name, mesh=mesh, material=material, analytic=analytic)


def _icosphere(radius_mm: float, centre, max_sagitta_mm: float) -> trimesh.Trimesh:
    """Icosphere inscribed in the sphere, subdivided until its sagitta ≤ max_sagitta_mm (≤ 7 times)."""
    for s in range(1, 8):
        ico = trimesh.creation.icosphere(subdivisions=s, radius=radius_mm)
        plane_dist = np.abs(np.einsum("ij,ij->i", ico.face_normals, ico.triangles_center))
        if radius_mm - plane_dist.min() <= max_sagitta_mm:
            break
    return trimesh.Trimesh(np.asarray(ico.vertices) + np.asarray(centre, dtype=float),
                           np.asarray(ico.faces), process=False)


def _post(diameter_mm, top_mm, xy, max_sagitta_mm) -> trimesh.Trimesh:
    n = segments_for_sagitta(diameter_mm / 2, max_sagitta_mm * 10)
    post = _rows_mesh(_theta(n), _smooth_rows(diameter_mm / 2, top_mm))
    post.apply_translation([xy[0], xy[1], 0.0])
    return post


def _spheres_on_posts(centres, radius_mm, stand_height_mm, post_diameter_mm, max_sagitta_mm):
    meshes = [_icosphere(radius_mm, c, max_sagitta_mm) for c in centres]
    if stand_height_mm > 0:
        meshes += [_post(post_diameter_mm, c[2], c[:2], max_sagitta_mm) for c in centres]
    return trimesh.util.concatenate(meshes)


def sphere(diameter_mm: float = 25.4, *, stand_height_mm: float = 30.0, post_diameter_mm: float = 8.0,
           max_sagitta_mm: float = 1e-3, material: str = "metal", name: str = "sphere") -> Part:
    """Reference sphere on a vertical post, centred on the axis.

    The sphere's lowest point is ``stand_height_mm`` above the table (centre at
    stand + D/2); the post (Ø ``post_diameter_mm``) runs from the table up to the
    sphere's centre, inside the sphere, as a separate closed shell.
    ``stand_height_mm = 0``: a bare sphere touching the table.  The sphere is an
    icosphere inscribed in the true sphere with sagitta ≤ ``max_sagitta_mm``
    (at most 7 subdivisions).

    Parameters
    ----------
    diameter_mm : float, default 25.4
        Sphere diameter D [mm].
    stand_height_mm : float, default 30.0
        Height of the sphere's lowest point above the table (≥ 0) [mm].
    post_diameter_mm : float, default 8.0
        Post diameter [mm].
    max_sagitta_mm : float, default 1e-3
        Largest sagitta of the icosphere's facets [mm] (the post: 10×).
    material : str, default "metal"
        Material tag (:data:`scenes.part.MATERIALS`).
    name : str, default "sphere"
        Part name.

    Returns
    -------
    Part
        The part in its own frame (standing on ``z = 0``), with its analytic
        description (``kind`` "sphere").

    Raises
    ------
    MeshError
        When a dimension is not a finite number > 0, ``stand_height_mm`` < 0, or the
        material is unknown.
    """
    _positive(diameter_mm=diameter_mm, post_diameter_mm=post_diameter_mm, max_sagitta_mm=max_sagitta_mm)
    if stand_height_mm < 0:
        raise MeshError(f"stand_height_mm = {stand_height_mm}: must be >= 0")
    R = diameter_mm / 2
    centre = [0.0, 0.0, stand_height_mm + R]
    mesh = _spheres_on_posts([centre], R, stand_height_mm, post_diameter_mm, max_sagitta_mm)
    analytic = {"kind": "sphere", "diameter_mm": float(diameter_mm), "radius_mm": R,
                "centre_mm": centre, "stand_height_mm": float(stand_height_mm),
                "post_diameter_mm": float(post_diameter_mm), "mesh_from_part": _eye()}
    return Part(name=name, mesh=mesh, material=material, analytic=analytic)


def ball_bar(sphere_diameter_mm: float = 20.0, centre_distance_mm: float = 100.0, *,
             stand_height_mm: float = 30.0, post_diameter_mm: float = 6.0,
             max_sagitta_mm: float = 1e-3, material: str = "metal", name: str = "ball-bar") -> Part:
    """Two equal spheres on posts, centres at (±L/2, 0, stand + D/2) [mm] (VDI/VDE 2634 style).

    Each sphere and post is built as in :func:`sphere`.

    Parameters
    ----------
    sphere_diameter_mm : float, default 20.0
        Sphere diameter D [mm].
    centre_distance_mm : float, default 100.0
        Distance L between the sphere centres [mm], > D.
    stand_height_mm : float, default 30.0
        Height of the spheres' lowest points above the table (≥ 0) [mm].
    post_diameter_mm : float, default 6.0
        Post diameter [mm].
    max_sagitta_mm : float, default 1e-3
        Largest sagitta of the icosphere's facets [mm].
    material : str, default "metal"
        Material tag (:data:`scenes.part.MATERIALS`).
    name : str, default "ball-bar"
        Part name.

    Returns
    -------
    Part
        The part in its own frame (standing on ``z = 0``), with its analytic
        description (``kind`` "ball_bar").

    Raises
    ------
    MeshError
        When a dimension is not a finite number > 0, ``centre_distance_mm`` ≤
        ``sphere_diameter_mm``, ``stand_height_mm`` < 0, or the material is unknown.
    """
    _positive(sphere_diameter_mm=sphere_diameter_mm, centre_distance_mm=centre_distance_mm,
              post_diameter_mm=post_diameter_mm, max_sagitta_mm=max_sagitta_mm)
    if centre_distance_mm <= sphere_diameter_mm or stand_height_mm < 0:
        raise MeshError("ball_bar: centre_distance_mm must exceed sphere_diameter_mm and "
                        "stand_height_mm must be >= 0")
    R, zc = sphere_diameter_mm / 2, stand_height_mm + sphere_diameter_mm / 2
    centres = [[-centre_distance_mm / 2, 0.0, zc], [centre_distance_mm / 2, 0.0, zc]]
    mesh = _spheres_on_posts(centres, R, stand_height_mm, post_diameter_mm, max_sagitta_mm)
    analytic = {"kind": "ball_bar", "sphere_diameter_mm": float(sphere_diameter_mm),
                "radius_mm": R, "centre_distance_mm": float(centre_distance_mm),
                "centres_mm": centres, "stand_height_mm": float(stand_height_mm),
                "post_diameter_mm": float(post_diameter_mm), "mesh_from_part": _eye()}
    return Part(name=name, mesh=mesh, material=material, analytic=analytic)

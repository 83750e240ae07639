"""Printed calibration patterns as parts: chessboard, ChArUco and circle grids on a plate.

The pattern's geometry — the spec, the corners in millimetres, their ids, OpenCV's
ChArUco layout — is the instrument core's (:mod:`scheimpflug.calibration.pattern`:
the calibration needs it); this module adds what the twin renders: the print's
albedo texture, the plate, a bow.

Pattern specs (docs/reference/interface.md ``--pattern SPEC``)
--------------------------------------------------------------
``chessboard:COLSxROWS:SQUARE_MM``
    COLS × ROWS *inner* corners (OpenCV's ``patternSize``), squares of edge
    SQUARE_MM; (COLS + 1) × (ROWS + 1) squares, the top-left one black.
``charuco:COLSxROWS:SQUARE_MM:MARKER_MM[:DICT]``
    OpenCV's ``cv2.aruco.CharucoBoard((COLS, ROWS), SQUARE_MM, MARKER_MM, dictionary)``:
    COLS × ROWS *squares* (as OpenCV counts them), ArUco markers of edge MARKER_MM
    in the white squares, DICT one of OpenCV's predefined dictionaries
    (default ``DICT_4X4_50``); its (COLS − 1) × (ROWS − 1) inner corners carry
    OpenCV's corner ids (row-major).  The layout (which square is black, where
    each marker sits, every marker's bits) is OpenCV's own.
``circles:COLSxROWS:PITCH_MM[:DIAMETER_MM]``
    a symmetric grid of COLS × ROWS black dots, centre pitch PITCH_MM, diameter
    DIAMETER_MM (default PITCH_MM/2) — OpenCV's ``findCirclesGrid`` symmetric grid.

Pattern frame
-------------
Millimetres; origin at the first inner corner (chessboard, ChArUco) or the
first dot centre (circles); ``x`` along the print's columns (COLS), ``y``
along its rows (ROWS, downward when the print is read), ``z = x × y`` into the
print (away from its reader) — the frame of OpenCV's object points
``(i·s, j·s, 0)``, so ``cv2.solvePnP`` of the corners returns camera_from_pattern.
Corner (i, j) lies at (i·s, j·s); :meth:`PatternSpec.corner_ids` lists (i, j)
in OpenCV's order (row-major, i fastest).

Target part (:func:`target_assembly`)
-------------------------------------
Two parts: the **print** (object id 1) — an open surface carrying the
pattern as an albedo texture, in its own (u, v) = pattern (x, y) coordinates,
optionally bowed — and the **plate** it is glued on (object id 2), a box of
the plate material whose front face lies ``PAPER_THICKNESS_MM`` behind the print.
Bow b [mm]: the print is a cylinder section about an axis parallel to y, its
centre line b nearer the reader than its left and right edges (b < 0: farther);
(u, v) are arc lengths on it, so a printed distance stays a distance on the
bent print.  The mesh is a grid of columns whose chords deviate from the
cylinder by < 0.1 µm; the corners' 3-D truth (:func:`print_points_mm`) lies
on that mesh exactly.

Reflectances (matte office paper and laser-printer toner, at the flood light's
and the laser's wavelengths): white ``WHITE_ALBEDO`` = 0.85 — office paper's
diffuse blue reflectance factor (ISO 2470-1, "ISO brightness", 457 nm) is
0.85–0.92 for ordinary copy paper, its luminous reflectance (ISO 2469 d/0°
geometry) ≈ 0.85–0.90; black ``BLACK_ALBEDO`` = 0.05 — black toner prints at
a reflection optical density of ≈ 1.3 (ISO 5-4 densitometry; printer makers'
specifications give 1.3–1.5), R = 10^−1.3 = 0.050.  Both are Lambertian (matte
print); typical values, not one measured sheet.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh

from scheimpflug.calibration.pattern import PATTERN_KINDS, charuco_layout
from scheimpflug.calibration.pattern import PatternSpec as _CorePatternSpec
from scheimpflug.calibration.pattern import parse_pattern as _parse_core
from scheimpflug.errors import MeshError

from .part import Assembly, Part
from .revolve import box_mesh

__all__ = [
    "BLACK_ALBEDO",
    "PAPER_THICKNESS_MM",
    "PATTERN_KINDS",
    "WHITE_ALBEDO",
    "PatternSpec",
    "charuco_layout",
    "parse_pattern",
    "print_points_mm",
    "target_assembly",
    "texture_albedo",
]

#: diffuse reflectance of white office paper (module docstring for the source) [-]
WHITE_ALBEDO = 0.85
#: diffuse reflectance of black laser toner, R = 10^(−OD), OD ≈ 1.3 [-]
BLACK_ALBEDO = 0.05
#: gap between the print and the plate's front face (a sheet of 80 g/m² paper) [mm]
PAPER_THICKNESS_MM = 0.1
_SAGITTA_MM = 1e-4          # chord sagitta of a bowed print's mesh columns [mm]


@dataclass(frozen=True)
class PatternSpec(_CorePatternSpec):
    """A parsed pattern spec with its print's texture (:class:`scheimpflug.calibration.pattern.PatternSpec`).

    Parameters
    ----------
    kind : str
        ``"chessboard"``, ``"charuco"`` or ``"circles"``.
    cols, rows : int
        Chessboard: inner corners; ChArUco: squares; circles: dots [-].
    pitch_mm : float
        Square edge or dot pitch [mm].
    marker_mm : float or None
        ChArUco marker edge [mm].
    dictionary : str or None
        ChArUco: OpenCV dictionary name, e.g. ``"DICT_4X4_50"``.
    diameter_mm : float or None
        Circles: dot diameter [mm].
    """

    def texture(self, black: float = BLACK_ALBEDO, white: float = WHITE_ALBEDO) -> dict:
        """The print's albedo texture (:func:`texture_albedo`; ``sim.textures`` evaluates it).

        Parameters
        ----------
        black, white : float
            Albedos of the ink and of the paper [-].

        Returns
        -------
        dict
            ``kind`` (the pattern kind), ``spec`` (:attr:`text`), ``black``, ``white``,
            and for ChArUco the layout arrays of :func:`charuco_layout`.
        """
        return {**self.layout(), "black": float(black), "white": float(white)}


def parse_pattern(spec: str) -> PatternSpec:
    """Parse a pattern spec (:func:`scheimpflug.calibration.pattern.parse_pattern`), with its texture.

    Parameters
    ----------
    spec : str
        ``chessboard:COLSxROWS:SQUARE_MM``, ``charuco:COLSxROWS:SQUARE_MM:MARKER_MM[:DICT]``
        or ``circles:COLSxROWS:PITCH_MM[:DIAMETER_MM]``.

    Returns
    -------
    PatternSpec
        The pattern.

    Raises
    ------
    MeshError
        One line naming what is wrong (the core's parser).
    """
    core = _parse_core(spec)
    return PatternSpec(core.kind, core.cols, core.rows, core.pitch_mm, core.marker_mm, core.dictionary,
                       core.diameter_mm)


# ------------------------------------------------------------------ albedo (numpy reference)


def texture_albedo(texture: dict, uv_mm) -> np.ndarray:
    """Albedo of a texture at texture coordinates (the reference implementation, numpy).

    Parameters
    ----------
    texture : dict
        A pattern texture (:meth:`PatternSpec.texture`), ``{"kind": "uniform",
        "albedo": a}`` or ``{"kind": "image", "albedo": (H, W) array, "extent_mm":
        [u0, v0, u1, v1]}`` (bilinear between texel centres, row index along v,
        clamped at the edges).
    uv_mm : (..., 2) array_like float
        Texture coordinates (u, v) [mm] (pattern textures: the pattern frame's x, y).

    Returns
    -------
    (...) float64
        The albedo [-]: for a pattern ``black`` on ink, ``white`` on paper (also
        outside the pattern).

    Raises
    ------
    ValueError
        For an unknown texture kind.
    """
    uv = np.asarray(uv_mm, dtype=np.float64)
    x, y = uv[..., 0], uv[..., 1]
    kind = texture.get("kind")
    if kind == "uniform":
        return np.full(x.shape, float(texture["albedo"]))
    if kind == "image":
        return _image_albedo(texture, x, y)
    ink = _ink(texture, x, y)
    return np.where(ink, texture["black"], texture["white"])


def _image_albedo(t: dict, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    img = np.asarray(t["albedo"], dtype=np.float64)
    h, w = img.shape
    u0, v0, u1, v1 = (float(c) for c in t["extent_mm"])
    fx = np.clip((x - u0) / (u1 - u0) * w - 0.5, 0.0, w - 1.0)
    fy = np.clip((y - v0) / (v1 - v0) * h - 0.5, 0.0, h - 1.0)
    c0, r0 = np.minimum(np.floor(fx).astype(np.int64), w - 2 if w > 1 else 0), \
        np.minimum(np.floor(fy).astype(np.int64), h - 2 if h > 1 else 0)
    c1, r1 = np.minimum(c0 + 1, w - 1), np.minimum(r0 + 1, h - 1)
    ax, ay = fx - c0, fy - r0
    top = img[r0, c0] * (1 - ax) + img[r0, c1] * ax
    bottom = img[r1, c0] * (1 - ax) + img[r1, c1] * ax
    return top * (1 - ay) + bottom * ay


def _ink(t: dict, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    s, kind = t["pitch_mm"], t["kind"]
    if kind == "circles":
        i = np.clip(np.round(x / s), 0, t["cols"] - 1)
        j = np.clip(np.round(y / s), 0, t["rows"] - 1)
        return (x - i * s) ** 2 + (y - j * s) ** 2 <= (0.5 * t["diameter_mm"]) ** 2
    if kind == "chessboard":
        n_c, n_r = t["cols"] + 1, t["rows"] + 1
        first_black = True
    elif kind == "charuco":
        n_c, n_r = t["cols"], t["rows"]
        first_black = t["first_black"]
    else:
        raise ValueError(f"texture kind {kind!r} unknown (known: chessboard, charuco, circles, image, uniform)")
    i, j = np.floor(x / s).astype(np.int64) + 1, np.floor(y / s).astype(np.int64) + 1
    inside = (i >= 0) & (i < n_c) & (j >= 0) & (j < n_r)
    black = ((i + j) % 2 == 0) == first_black
    if kind == "charuco":
        return inside & (black | _marker_ink(t, x, y, i, j, inside))
    return inside & black


def _marker_ink(t, x, y, i, j, inside) -> np.ndarray:
    slot = np.where(inside, t["square_marker"][np.clip(j, 0, t["rows"] - 1), np.clip(i, 0, t["cols"] - 1)], -1)
    has = slot >= 0
    k = np.where(has, slot, 0)
    origin = t["marker_origin_mm"][k]
    cells = t["marker_bits"].shape[1]
    cell = t["marker_mm"] / cells
    a = np.floor((x - origin[..., 0]) / cell).astype(np.int64)
    b = np.floor((y - origin[..., 1]) / cell).astype(np.int64)
    in_marker = has & (a >= 0) & (a < cells) & (b >= 0) & (b < cells)
    white = t["marker_bits"][k, np.clip(b, 0, cells - 1), np.clip(a, 0, cells - 1)] == 1
    return in_marker & ~white


# ------------------------------------------------------------------ the target part


def _bow_radius_mm(half_width_mm: float, bow_mm: float) -> float:
    """R of the circular arc of half arc length a whose sagitta is |b|: |b| = R·(1 − cos(a/R))."""
    b, a = abs(bow_mm), half_width_mm
    lo, hi = a / math.pi * 1.000001, a * a / b + a   # sagitta(lo) > b > sagitta(hi)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mid * (1.0 - math.cos(a / mid)) > b:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def _print_columns(x0: float, x1: float, bow_mm: float) -> np.ndarray:
    """Arc-length positions of the print mesh's columns [mm] (2 when flat)."""
    if bow_mm == 0.0:
        return np.array([x0, x1])
    r = _bow_radius_mm(0.5 * (x1 - x0), bow_mm)
    n = max(2, int(math.ceil((x1 - x0) / math.sqrt(8.0 * r * _SAGITTA_MM))))
    return np.linspace(x0, x1, n + 1)


def _bent(s_mm: np.ndarray, x0: float, x1: float, bow_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """(x, z) of arc lengths s on the bowed print (z toward −reader for b > 0 is −b at the centre)."""
    if bow_mm == 0.0:
        return np.asarray(s_mm, dtype=np.float64), np.zeros_like(np.asarray(s_mm, dtype=np.float64))
    xc, a = 0.5 * (x0 + x1), 0.5 * (x1 - x0)
    r = _bow_radius_mm(a, bow_mm)
    phi = (np.asarray(s_mm, dtype=np.float64) - xc) / r
    sign = 1.0 if bow_mm > 0 else -1.0
    z = -sign * (r * np.cos(phi) - r * math.cos(a / r))   # edges at 0, centre at −b
    return xc + r * np.sin(phi), z


def _print_mesh(x0, y0, x1, y1, bow_mm) -> tuple[trimesh.Trimesh, np.ndarray]:
    s = _print_columns(x0, x1, bow_mm)
    x, z = _bent(s, x0, x1, bow_mm)
    n = len(s)
    top = np.stack([x, np.full(n, y0), z], axis=1)
    bottom = np.stack([x, np.full(n, y1), z], axis=1)
    vertices = np.concatenate([top, bottom])
    uv = np.concatenate([np.stack([s, np.full(n, y0)], 1), np.stack([s, np.full(n, y1)], 1)])
    k = np.arange(n - 1)
    faces = np.concatenate([np.stack([k, k + n, k + 1], 1), np.stack([k + 1, k + n, k + n + 1], 1)])
    return trimesh.Trimesh(vertices, faces, process=False), uv


def print_points_mm(analytic: dict, xy_mm) -> np.ndarray:
    """3-D points of the print's surface at pattern coordinates, in the part (pattern) frame.

    Parameters
    ----------
    analytic : dict
        The print part's ``analytic`` description (:func:`target_assembly`).
    xy_mm : (n, 2) array_like float
        Pattern coordinates (u, v) = arc lengths on the print [mm].

    Returns
    -------
    (n, 3) float64
        The point of the print's mesh with those texture coordinates [mm]: on the
        flat print (x, y, 0); on a bowed one, linear between the mesh's columns
        (the renderer's own interpolation), NaN outside the print.
    """
    xy = np.atleast_2d(np.asarray(xy_mm, dtype=np.float64))
    x0, y0, x1, y1 = analytic["print_mm"]
    s = _print_columns(x0, x1, analytic["bow_mm"])
    x, z = _bent(s, x0, x1, analytic["bow_mm"])
    out = np.stack([np.interp(xy[:, 0], s, x), xy[:, 1], np.interp(xy[:, 0], s, z)], axis=1)
    inside = (xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1)
    out[~inside] = np.nan
    return out


def _plate_size(spec: PatternSpec, plate_mm, border_mm: float) -> tuple[float, float, float, float]:
    """(x0, y0, x1, y1) of the plate in the pattern frame, centred on the pattern [mm]."""
    e = spec.extent_mm()
    need_w, need_h = e[2] - e[0] + 2 * border_mm, e[3] - e[1] + 2 * border_mm
    if plate_mm is None:
        w, h = need_w, need_h
    else:
        w, h = (float(v) for v in plate_mm)
        if not (w > 0 and h > 0 and math.isfinite(w) and math.isfinite(h)):
            raise MeshError(f"plate size {w:g} × {h:g} mm: must be > 0")
        if w < need_w - 1e-9 or h < need_h - 1e-9:
            raise MeshError(f"pattern {spec.text} with a {border_mm:g} mm border needs a plate of at least "
                            f"{need_w:g} × {need_h:g} mm; the plate is {w:g} × {h:g} mm")
    xc, yc = 0.5 * (e[0] + e[2]), 0.5 * (e[1] + e[3])
    return xc - 0.5 * w, yc - 0.5 * h, xc + 0.5 * w, yc + 0.5 * h


def target_assembly(spec: PatternSpec | str, *, plate_mm=None, border_mm: float | None = None,
                    thickness_mm: float = 3.0, bow_mm: float = 0.0, plate_material: str = "white-plastic",
                    print_material: str = "paper", black: float = BLACK_ALBEDO,
                    white: float = WHITE_ALBEDO) -> Assembly:
    """A printed pattern on a plate, in the pattern frame (module docstring).

    Parameters
    ----------
    spec : PatternSpec or str
        The pattern (:func:`parse_pattern`).
    plate_mm : (2,) float, optional
        Plate width (along x) and height (along y) [mm]; default the pattern plus
        the border on each side.
    border_mm : float, optional
        Paper margin around the pattern (≥ 0) [mm]; default one square / pitch.
    thickness_mm : float, default 3.0
        Plate thickness [mm].
    bow_mm : float, default 0.0
        Sagitta of the print's bow at its centre line, + toward the reader [mm];
        |bow| < a quarter of the plate width.
    plate_material, print_material : str
        Material tags (:data:`scenes.MATERIALS`); the print is rendered as its
        texture's matte albedo.
    black, white : float
        Albedos of ink and paper, in [0, 1] [-].

    Returns
    -------
    Assembly
        ``print`` (object id 1; ``analytic`` kind ``"pattern-print"`` with ``spec``,
        ``print_mm`` [x0, y0, x1, y1], ``bow_mm``; its ``texture`` and ``uv_mm``)
        and ``plate`` (object id 2, a box behind the print).

    Raises
    ------
    MeshError
        For a bad spec, a pattern that does not fit on the plate (the message gives
        the size it needs), a negative border, a thickness that is not > 0, a bow
        too large, an albedo outside [0, 1] or an unknown material.
    """
    spec = parse_pattern(spec if isinstance(spec, str) else spec.text)
    border = spec.pitch_mm if border_mm is None else float(border_mm)
    if not (math.isfinite(border) and border >= 0):
        raise MeshError(f"pattern border {border_mm!r} mm: must be >= 0")
    if not (math.isfinite(thickness_mm) and thickness_mm > 0):
        raise MeshError(f"plate thickness {thickness_mm!r} mm: must be > 0")
    for name, v in (("black", black), ("white", white)):
        if not (0.0 <= v <= 1.0):
            raise MeshError(f"pattern {name} albedo {v!r}: must be in [0, 1]")
    x0, y0, x1, y1 = _plate_size(spec, plate_mm, border)
    if not (math.isfinite(bow_mm) and abs(bow_mm) < 0.25 * (x1 - x0)):
        raise MeshError(f"print bow {bow_mm!r} mm: must be finite and below a quarter of the plate "
                        f"width ({0.25 * (x1 - x0):g} mm)")
    mesh, uv = _print_mesh(x0, y0, x1, y1, float(bow_mm))
    analytic = {"kind": "pattern-print", "spec": spec.text, "print_mm": [x0, y0, x1, y1],
                "bow_mm": float(bow_mm), "black": float(black), "white": float(white),
                "mesh_from_part": np.eye(4).tolist()}
    printed = Part("print", mesh, print_material, analytic, 1, texture=spec.texture(black, white), uv_mm=uv)
    z0 = PAPER_THICKNESS_MM + max(0.0, -float(bow_mm))
    plate = Part("plate", box_mesh([x0, y0, z0], [x1, y1, z0 + thickness_mm]), plate_material,
                 {"kind": "box", "lo_mm": [x0, y0, z0], "hi_mm": [x1, y1, z0 + thickness_mm],
                  "mesh_from_part": np.eye(4).tolist()}, 2)
    return Assembly(f"target {spec.text}", (printed, plate))

"""Printed calibration patterns: the spec, the grid of corners in millimetres, their ids.

What a calibration needs to know of its pattern (the print itself — its albedo
texture, the plate it is glued on, a bow — is the parts' :mod:`scenes.patterns`).

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
"""

from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass

import cv2
import numpy as np

from scheimpflug.errors import MeshError

__all__ = [
    "PATTERN_KINDS",
    "PatternSpec",
    "aruco_dictionary",
    "charuco_board",
    "charuco_layout",
    "parse_pattern",
]

PATTERN_KINDS = ("chessboard", "charuco", "circles")
_MAX_CORNERS = 100_000


@dataclass(frozen=True)
class PatternSpec:
    """A parsed pattern spec (module docstring); build it with :func:`parse_pattern`.

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

    kind: str
    cols: int
    rows: int
    pitch_mm: float
    marker_mm: float | None = None
    dictionary: str | None = None
    diameter_mm: float | None = None

    @property
    def text(self) -> str:
        """The canonical spec string, e.g. ``"chessboard:10x8:7"``."""
        head = f"{self.kind}:{self.cols}x{self.rows}:{self.pitch_mm:g}"
        if self.kind == "charuco":
            return f"{head}:{self.marker_mm:g}:{self.dictionary}"
        if self.kind == "circles":
            return f"{head}:{self.diameter_mm:g}"
        return head

    @property
    def grid_shape(self) -> tuple[int, int]:
        """(columns, rows) of the corner / dot grid [-] (ChArUco: squares − 1 each)."""
        if self.kind == "charuco":
            return self.cols - 1, self.rows - 1
        return self.cols, self.rows

    def corner_ids(self) -> np.ndarray:
        """Grid position of every corner / dot.

        Returns
        -------
        (n, 2) int64
            (column i, row j), in OpenCV's order (row-major, i fastest) [-].
        """
        nc, nr = self.grid_shape
        j, i = np.mgrid[0:nr, 0:nc]
        return np.stack([i.ravel(), j.ravel()], axis=1).astype(np.int64)

    def corners_mm(self) -> np.ndarray:
        """Position of every corner / dot on the print.

        Returns
        -------
        (n, 2) float64
            (x, y) = (i·s, j·s) in the pattern frame [mm], the order of :meth:`corner_ids`.
        """
        return self.corner_ids().astype(np.float64) * self.pitch_mm

    def extent_mm(self) -> tuple[float, float, float, float]:
        """The printed area: the squares, or the dots' outer edges.

        Returns
        -------
        tuple of float
            (x0, y0, x1, y1) in the pattern frame [mm].
        """
        nc, nr = self.grid_shape
        s = self.pitch_mm
        if self.kind == "circles":
            r = 0.5 * self.diameter_mm
            return -r, -r, (nc - 1) * s + r, (nr - 1) * s + r
        return -s, -s, nc * s, nr * s

    def object_points(self) -> np.ndarray:
        """The corners' object points for OpenCV: ``(x, y, 0)`` in the pattern frame.

        Returns
        -------
        (n, 3) float32
            :meth:`corners_mm` with z = 0 [mm], the order of :meth:`corner_ids`.
        """
        return np.c_[self.corners_mm(), np.zeros(len(self.corner_ids()))].astype(np.float32)

    def layout(self) -> dict:
        """The print's geometry for a texture: kind, spec, grid, pitch, dots, ChArUco markers.

        Returns
        -------
        dict
            ``kind``, ``spec`` (:attr:`text`), ``cols``, ``rows``, ``pitch_mm``; ``diameter_mm``
            for circles; for ChArUco the arrays of :func:`charuco_layout` and ``marker_mm``.
        """
        out = {"kind": self.kind, "spec": self.text, "cols": self.cols, "rows": self.rows,
               "pitch_mm": self.pitch_mm}
        if self.kind == "circles":
            out["diameter_mm"] = self.diameter_mm
        if self.kind == "charuco":
            out.update(charuco_layout(self), marker_mm=self.marker_mm)
        return out


def _fail(spec: str, why: str) -> MeshError:
    return MeshError(f"pattern spec {spec!r}: {why} (e.g. chessboard:10x8:7, "
                     "charuco:11x8:15:11:DICT_4X4_50, circles:7x6:10)")


def _number(spec: str, name: str, text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise _fail(spec, f"{name} {text!r} is not a number") from None
    if not (math.isfinite(v) and v > 0):
        raise _fail(spec, f"{name} = {text} must be a number > 0 [mm]")
    return v


def _grid(spec: str, text: str, least: int) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX×]\s*(\d+)\s*", text)
    if not m:
        raise _fail(spec, f"{text!r} is not COLSxROWS")
    cols, rows = int(m.group(1)), int(m.group(2))
    if cols < least or rows < least:
        raise _fail(spec, f"{cols}x{rows}: needs at least {least}x{least}")
    if cols * rows > _MAX_CORNERS:
        raise _fail(spec, f"{cols}x{rows}: more than {_MAX_CORNERS} corners")
    return cols, rows


def parse_pattern(spec: str) -> PatternSpec:
    """Parse a pattern spec (module docstring).

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
        One line naming what is wrong: an unknown kind, a missing or extra field,
        a grid that is not COLSxROWS (at least 2 × 2 corners, 3 × 3 ChArUco squares),
        a size that is not > 0, a marker not smaller than its square, dots that touch,
        or an unknown ArUco dictionary, or one too small for the board's markers.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise _fail(str(spec), "empty")
    fields = [f.strip() for f in spec.strip().split(":")]
    kind = fields[0].lower()
    if kind not in PATTERN_KINDS:
        raise _fail(spec, f"unknown pattern {fields[0]!r} (known: {', '.join(PATTERN_KINDS)})")
    if kind == "chessboard":
        return _chessboard(spec, fields)
    if kind == "circles":
        return _circles(spec, fields)
    return _charuco(spec, fields)


def _chessboard(spec: str, fields: list[str]) -> PatternSpec:
    if len(fields) != 3:
        raise _fail(spec, "a chessboard is chessboard:COLSxROWS:SQUARE_MM")
    cols, rows = _grid(spec, fields[1], 2)
    return PatternSpec("chessboard", cols, rows, _number(spec, "square", fields[2]))


def _circles(spec: str, fields: list[str]) -> PatternSpec:
    if len(fields) not in (3, 4):
        raise _fail(spec, "a circle grid is circles:COLSxROWS:PITCH_MM[:DIAMETER_MM]")
    cols, rows = _grid(spec, fields[1], 2)
    pitch = _number(spec, "pitch", fields[2])
    diameter = _number(spec, "diameter", fields[3]) if len(fields) == 4 else 0.5 * pitch
    if diameter >= pitch:
        raise _fail(spec, f"dots of diameter {diameter:g} mm touch at pitch {pitch:g} mm")
    return PatternSpec("circles", cols, rows, pitch, diameter_mm=diameter)


def _charuco(spec: str, fields: list[str]) -> PatternSpec:
    if len(fields) not in (4, 5):
        raise _fail(spec, "a ChArUco board is charuco:COLSxROWS:SQUARE_MM:MARKER_MM[:DICT]")
    cols, rows = _grid(spec, fields[1], 3)
    square, marker = _number(spec, "square", fields[2]), _number(spec, "marker", fields[3])
    if marker >= square:
        raise _fail(spec, f"the marker ({marker:g} mm) must be smaller than the square ({square:g} mm)")
    name = fields[4].upper() if len(fields) == 5 else "DICT_4X4_50"
    dictionary = _dictionary(spec, name)
    n_markers = (cols * rows) // 2
    if n_markers > len(dictionary.bytesList):
        raise _fail(spec, f"{name} holds {len(dictionary.bytesList)} markers, the board needs {n_markers}")
    return PatternSpec("charuco", cols, rows, square, marker_mm=marker, dictionary=name)


def _dictionary(spec: str, name: str):
    code = getattr(cv2.aruco, name, None) if name.startswith("DICT_") else None
    if not isinstance(code, int):
        known = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
        raise _fail(spec, f"unknown ArUco dictionary {name!r} (OpenCV's: {', '.join(known[:6])}, …)")
    return cv2.aruco.getPredefinedDictionary(code)


def aruco_dictionary(spec: PatternSpec):
    """OpenCV's ArUco dictionary of a ChArUco pattern.

    Parameters
    ----------
    spec : PatternSpec
        A ``charuco`` pattern.

    Returns
    -------
    cv2.aruco.Dictionary
        ``cv2.aruco.getPredefinedDictionary`` of its dictionary.

    Raises
    ------
    MeshError
        An unknown dictionary name.
    """
    return _dictionary(spec.text, spec.dictionary)


def charuco_board(spec: PatternSpec):
    """OpenCV's ``CharucoBoard`` of a ChArUco pattern (the detector's and the layout's board).

    Parameters
    ----------
    spec : PatternSpec
        A ``charuco`` pattern.

    Returns
    -------
    cv2.aruco.CharucoBoard
        ``CharucoBoard((cols, rows), square, marker, dictionary)`` [mm].

    Raises
    ------
    ValueError
        When ``spec`` is not a ChArUco pattern.
    """
    if spec.kind != "charuco":
        raise ValueError(f"charuco_board needs a charuco pattern, got {spec.kind!r}")
    return cv2.aruco.CharucoBoard((spec.cols, spec.rows), spec.pitch_mm, spec.marker_mm, aruco_dictionary(spec))


@functools.lru_cache(maxsize=16)
def _charuco_layout_cached(text: str) -> tuple:
    spec = parse_pattern(text)
    d = _dictionary(text, spec.dictionary)
    board = charuco_board(spec)
    s = spec.pitch_mm
    obj = np.asarray(board.getObjPoints(), dtype=np.float64)      # (k, 4, 3), board frame
    ids = np.asarray(board.getIds(), dtype=np.int64).ravel()
    cells = d.markerSize + 2
    square_marker = -np.ones((spec.rows, spec.cols), np.int64)      # [row, col] → marker slot
    bits = np.zeros((len(ids), cells, cells), np.uint8)               # 1 = white cell
    for k, (corners, marker_id) in enumerate(zip(obj, ids)):
        col, row = (int(c) for c in np.floor(corners[:, :2].mean(axis=0) / s))
        square_marker[row, col] = k
        bits[k] = cv2.aruco.generateImageMarker(d, int(marker_id), cells) > 127
    first_black = not board.getLegacyPattern() or spec.rows % 2 == 1
    return square_marker, bits, obj[:, 0, :2] - s, first_black, ids


def charuco_layout(spec: PatternSpec) -> dict:
    """OpenCV's layout of a ChArUco board, in the pattern frame.

    Parameters
    ----------
    spec : PatternSpec
        A ``charuco`` pattern.

    Returns
    -------
    dict
        ``square_marker`` (rows, cols) int: the marker slot in each square (−1 = none);
        ``marker_bits`` (k, n + 2, n + 2) uint8: each marker's cells (1 = white), its
        black border included, rows downward; ``marker_origin_mm`` (k, 2): the marker's
        top-left corner [mm]; ``marker_ids`` (k,): OpenCV's marker ids;
        ``first_black`` (bool): whether square (0, 0) is black.

    Raises
    ------
    ValueError
        When ``spec`` is not a ChArUco pattern.
    """
    if spec.kind != "charuco":
        raise ValueError(f"charuco_layout needs a charuco pattern, got {spec.kind!r}")
    square_marker, bits, origin, first_black, ids = _charuco_layout_cached(spec.text)
    return {"square_marker": square_marker, "marker_bits": bits, "marker_origin_mm": origin,
            "marker_ids": ids, "first_black": bool(first_black)}

"""A scanner's housing: flat boards that stand still while the table turns (issue 35 item 5).

A turntable scanner's back walls, floor or lid are fixed surfaces beside the
part.  Each is a :class:`Board`: a rectangle of a plane with a thickness behind
its face, given in the *instrument frame* — the calibration's camera frame
(OpenCV's: X along the columns, Y along the rows, Z forward) [mm], the frame of
:mod:`scheimpflug.model.instrument`, so that a housing found from real frames
through their calibration (:func:`scheimpflug.fixed_lines.wall_board`) stands in
the twin where the real one stands (``render --housing``, :mod:`sim.backgrounds`).

A rig file holds its housing too (``render --rig`` renders it without ``--housing``): the same
tables as ``[[housing.board]]``, or ``housing = "path"`` (a housing file, relative to the rig
file); :mod:`scheimpflug.model.assembly` carries the boards in ``Rig.housing``.

Housing file (TOML), one ``[[board]]`` table per board::

    [[board]]
    name = "left"
    centre_mm = [x, y, z]     # the centre of its face [mm], instrument frame
    normal = [nx, ny, nz]     # unit normal of the face (the side that is seen and lit) [-]
    length_dir = [lx, ly, lz] # unit direction of its length, in the face (⟂ normal) [-]
    length_mm = 120.0         # extent along length_dir [mm]
    width_mm = 80.0           # extent along normal × length_dir [mm]
    thickness_mm = 10.0       # behind the face [mm]
    material = "cardboard"    # a material tag of scenes.MATERIALS
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scheimpflug.errors import RigError

__all__ = ["Board", "board_corners_mm", "check_sheet_seen", "housing_from_dict", "housing_to_toml", "load_housing",
           "segments_blocked"]

#: Tolerance on unit lengths and on the perpendicularity of a board's directions [-].
_UNIT_TOL = 1e-6


@dataclass(frozen=True, eq=False)
class Board:
    """One flat board of a housing, instrument frame (module docstring).

    Parameters
    ----------
    name : str
        Its name.
    centre_mm : (3,) ndarray
        Centre of its face [mm].
    normal : (3,) ndarray
        Unit normal of the face, toward the side that is seen and lit [-].
    length_dir : (3,) ndarray
        Unit direction of its length, perpendicular to ``normal`` [-].
    length_mm, width_mm : float
        Extents along ``length_dir`` and along ``normal × length_dir`` [mm], > 0.
    thickness_mm : float, default 10.0
        Thickness behind the face [mm], > 0.
    material : str, default "cardboard"
        Material tag (``scenes.MATERIALS``; checked where the twin builds it).
    """

    name: str
    centre_mm: np.ndarray
    normal: np.ndarray
    length_dir: np.ndarray
    length_mm: float
    width_mm: float
    thickness_mm: float = 10.0
    material: str = "cardboard"

    def __eq__(self, other: object) -> bool:
        """Equal when every field is (vectors by value)."""
        return isinstance(other, Board) and self.to_dict() == other.to_dict()

    def __hash__(self) -> int:
        """Hash of its values (a :class:`~scheimpflug.model.rig.Rig` holding it is hashed)."""
        return hash(json.dumps(self.to_dict(), sort_keys=True))

    def to_dict(self) -> dict:
        """The board as plain numbers (a housing file's ``[[board]]`` table, a manifest's entry).

        Returns
        -------
        dict
            Every field under its own name, vectors as lists.
        """
        return {"name": self.name, "centre_mm": [float(x) for x in self.centre_mm],
                "normal": [float(x) for x in self.normal], "length_dir": [float(x) for x in self.length_dir],
                "length_mm": float(self.length_mm), "width_mm": float(self.width_mm),
                "thickness_mm": float(self.thickness_mm), "material": self.material}


def _vector(d: dict, key: str, where: str, unit: bool) -> np.ndarray:
    try:
        a = np.asarray(d[key], np.float64).ravel()
    except KeyError:
        raise RigError(f"{where}: {key} is missing") from None
    except (TypeError, ValueError):
        raise RigError(f"{where}: {key} must be 3 numbers, got {d[key]!r:.60}") from None
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise RigError(f"{where}: {key} must be 3 finite numbers, got {a.tolist()!r:.80}")
    if unit and abs(float(np.linalg.norm(a)) - 1.0) > _UNIT_TOL:
        raise RigError(f"{where}: {key} {a.tolist()} has length {float(np.linalg.norm(a)):.9g}, not 1 (a unit vector)")
    return a


def _size(d: dict, key: str, where: str, default: float | None = None) -> float:
    value = d.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
        raise RigError(f"{where}: {key} = {value!r:.40} must be a number > 0 [mm]")
    return float(value)


def _board(d, i: int) -> Board:
    where = f"housing board {i}"
    if not isinstance(d, dict):
        raise RigError(f"{where} must be a table of keys, got {type(d).__name__}")
    unknown = set(d) - {"name", "centre_mm", "normal", "length_dir", "length_mm", "width_mm", "thickness_mm",
                        "material"}
    if unknown:
        raise RigError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}")
    normal, length = _vector(d, "normal", where, True), _vector(d, "length_dir", where, True)
    if abs(float(normal @ length)) > _UNIT_TOL:
        raise RigError(f"{where}: length_dir is not perpendicular to normal (cos = {float(normal @ length):.3g})")
    name, material = d.get("name", f"board{i + 1}"), d.get("material", "cardboard")
    if not isinstance(name, str) or not isinstance(material, str):
        raise RigError(f"{where}: name and material must be strings")
    return Board(name, _vector(d, "centre_mm", where, False), normal, length, _size(d, "length_mm", where),
                 _size(d, "width_mm", where), _size(d, "thickness_mm", where, 10.0), material)


def housing_from_dict(data: dict) -> tuple[Board, ...]:
    """The boards of a parsed housing file.

    Parameters
    ----------
    data : dict
        ``{"board": [table, …]}`` (module docstring).

    Returns
    -------
    tuple of Board
        The boards, checked.

    Raises
    ------
    RigError
        No boards, an unknown key, a missing or non-finite vector, a normal or direction
        that is not a unit vector, a length direction not perpendicular to the normal, a
        size that is not > 0.
    """
    boards = data.get("board") if isinstance(data, dict) else None
    if not isinstance(boards, list) or not boards:
        raise RigError("a housing needs at least one [[board]] table")
    return tuple(_board(d, i) for i, d in enumerate(boards))


def load_housing(path: str | Path) -> tuple[Board, ...]:
    """Read a housing file (module docstring).

    Parameters
    ----------
    path : str or Path
        The TOML file.

    Returns
    -------
    tuple of Board
        The boards.

    Raises
    ------
    RigError
        Naming the file: missing, unreadable, not TOML, or a bad board (:func:`housing_from_dict`).
    """
    from scheimpflug.model.rig import read_toml

    data = read_toml(path, "housing file")
    try:
        return housing_from_dict(data)
    except RigError as exc:
        raise RigError(f"housing file {str(path)!r}: {exc}") from None


def housing_to_toml(boards, comment: str = "") -> str:
    """The housing file of boards.

    Parameters
    ----------
    boards : sequence of Board
        The boards.
    comment : str, default ""
        Lines written first as ``#`` comments (where the boards came from).

    Returns
    -------
    str
        TOML text :func:`load_housing` reads back.
    """
    from scheimpflug.model.assembly import toml_value  # assembly imports this module

    lines = [f"# {line}" for line in comment.splitlines()]
    for b in boards:
        lines += ["", "[[board]]"]
        lines += [f"{key} = {toml_value(value)}" for key, value in b.to_dict().items()]
    return "\n".join(lines).lstrip("\n") + "\n"


def board_corners_mm(board: Board) -> np.ndarray:
    """The four corners of a board's face, instrument frame.

    Parameters
    ----------
    board : Board
        The board.

    Returns
    -------
    (4, 3) ndarray float64
        Corners [mm], in order around the face.
    """
    a = 0.5 * board.length_mm * np.asarray(board.length_dir, np.float64)
    b = 0.5 * board.width_mm * np.cross(board.normal, board.length_dir)
    c = np.asarray(board.centre_mm, np.float64)
    return np.stack([c - a - b, c + a - b, c + a + b, c - a + b])


def segments_blocked(board: Board, origin_mm, points_mm) -> np.ndarray:
    """Which segments from one origin to points pass through a board (its face and thickness).

    Parameters
    ----------
    board : Board
        The board: a box, its face the rectangle of :func:`board_corners_mm`, ``thickness_mm``
        behind it.
    origin_mm : (3,) array_like float
        The segments' common start (a camera's centre) [mm], the board's frame.
    points_mm : (n, 3) array_like float
        Their ends [mm].

    Returns
    -------
    (n,) ndarray bool
        True where the segment meets the box strictly between its ends (the end itself, on
        the face, is not blocked).
    """
    c = np.asarray(board.centre_mm, np.float64)
    axes = np.stack([board.length_dir, board.normal, np.cross(board.normal, board.length_dir)])
    lo = np.array([-0.5 * board.length_mm, -board.thickness_mm, -0.5 * board.width_mm])
    hi = np.array([0.5 * board.length_mm, 0.0, 0.5 * board.width_mm])
    o = axes @ (np.asarray(origin_mm, np.float64) - c)
    d = (np.asarray(points_mm, np.float64) - c) @ axes.T - o
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - o) / d, (hi - o) / d
    inside = (o >= lo) & (o <= hi)                       # a zero component: the slab holds it or not
    t_lo = np.where(d == 0, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
    t_hi = np.where(d == 0, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
    enter, leave = t_lo.max(axis=1), t_hi.min(axis=1)
    eps = 1e-9
    return (enter <= leave) & (leave > eps) & (enter < 1.0 - eps)


def check_sheet_seen(boards, origin_mm, points_mm) -> None:
    """Refuse a housing that hides the whole sheet from the camera.

    Parameters
    ----------
    boards : sequence of Board
        The housing.
    origin_mm : (3,) array_like float
        The camera's centre [mm], the boards' frame.
    points_mm : (n, 3) array_like float
        Points of the sheet's part the camera sees (where its pixels' rays meet it) [mm].

    Raises
    ------
    RigError
        When every segment from the camera to those points passes through a board, naming
        the board that blocks them all (or the boards that do between them).
    """
    pts = np.asarray(points_mm, np.float64).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if not len(pts) or not boards:
        return
    blocked = np.stack([segments_blocked(b, origin_mm, pts) for b in boards])
    if not blocked.any(axis=0).all():
        return
    whole = [b.name for b, row in zip(boards, blocked) if row.all()]
    names = whole[:1] or [b.name for b, row in zip(boards, blocked) if row.any()]
    which = f"board {names[0]!r}" if len(names) == 1 else "boards " + ", ".join(repr(n) for n in names)
    raise RigError(f"the housing hides the whole sheet from the camera: {which} stands between the camera and "
                   f"every point of the sheet it sees ({len(pts)} sampled) — move it behind the sheet")

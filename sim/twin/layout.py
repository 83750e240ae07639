"""The twin folder: what ``twin build`` writes and ``render rotary --twin`` reads.

``TWIN_DIR/``

* ``rig.toml`` — the instrument from its calibration (``rig from-calibration``);
* ``part.ply`` — the part's watertight mesh from the scan, in the part frame (z = 0 on the
  table's top, the rotary axis the z axis: :mod:`sim.twin.part`);
* ``housing.toml`` — the still walls as boards, the calibration's camera frame (absent when
  the scan shows no still wall);
* ``identify/`` — the identification's job folder (:func:`sim.identify.scan.identify_scan`),
  its ``identified.toml`` the rig with the identified values;
* ``twin.json`` — ``format``, ``complete``, ``source`` (the scan and calibration, their hashes,
  the frame size), ``options``, ``angles_deg`` (the scan's), ``regions``, ``housing``,
  ``part``, ``part_material`` (the part's ``tag`` and, for a translucent tag, its ``medium``:
  :class:`sim.materials.Translucent`'s fields; absent in a twin built before it: ``metal``),
  ``steps`` (per step its status, input key, files' hashes, seconds, result),
  ``identified`` and ``figures`` (the identification's, or null), ``files`` (relative paths).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from scheimpflug.errors import ScheimpflugError

__all__ = ["HOUSING_FILE", "IDENTIFY_DIR", "PART_FILE", "RIG_FILE", "TWIN_FILE", "TWIN_FORMAT", "TwinFiles",
           "load_twin"]

TWIN_FORMAT = "scheimpflug-twin/1"
TWIN_FILE = "twin.json"
RIG_FILE = "rig.toml"
PART_FILE = "part.ply"
HOUSING_FILE = "housing.toml"
IDENTIFY_DIR = "identify"


@dataclass(frozen=True)
class TwinFiles:
    """The files a twin renders from.

    Parameters
    ----------
    rig : Path
        The identified rig when the identification ran, else ``rig.toml``.
    part : Path
        ``part.ply``.
    housing : Path or None
        ``housing.toml``, None without one.
    angles_deg : list of float
        The real scan's angles [deg].
    identified : bool
        Whether ``rig`` is the identified one.
    materials : dict
        The identified material settings that are not rig keys (:class:`sim.materials.MaterialSettings`
        fields: ``cardboard_albedo``, ``metal_alpha`` …; ``translucent`` with the part's medium for a
        translucent part), empty without an identification and a translucent part.
    part_material : str or None
        The part's material tag (``twin.json``'s ``part_material``); None: the mesh's, ``metal``.
    """

    rig: Path
    part: Path
    housing: Path | None
    angles_deg: list
    identified: bool
    materials: dict = field(default_factory=dict)
    part_material: str | None = None


def load_twin(twin_dir) -> TwinFiles:
    """The files of a built twin folder.

    Parameters
    ----------
    twin_dir : path
        A folder written by ``twin build``.

    Returns
    -------
    TwinFiles
        Its files.

    Raises
    ------
    ScheimpflugError
        No ``twin.json``, one of another format, a build not finished, a file missing.
    """
    d = Path(twin_dir)
    try:
        meta = json.loads((d / TWIN_FILE).read_text("utf-8"))
    except (OSError, ValueError) as exc:
        raise ScheimpflugError(f"{str(d)!r} is not a twin folder ({TWIN_FILE}: {exc}); build one with "
                               "'scheimpflug twin build'") from None
    if not isinstance(meta, dict) or meta.get("format") != TWIN_FORMAT:
        got = meta.get("format") if isinstance(meta, dict) else None
        raise ScheimpflugError(f"{str(d / TWIN_FILE)!r}: format {got!r}, this program reads {TWIN_FORMAT!r}: "
                               "build the twin again")
    if not meta.get("complete"):
        raise ScheimpflugError(f"{str(d)!r}: the twin build did not finish: run 'scheimpflug twin build' again "
                               "to resume it")
    files = meta.get("files") or {}
    identified = files.get("identified_rig")
    out = TwinFiles(rig=d / (identified or files.get("rig") or RIG_FILE), part=d / (files.get("part") or PART_FILE),
                    housing=d / files["housing"] if files.get("housing") else None,
                    angles_deg=[float(a) for a in meta.get("angles_deg") or []], identified=bool(identified),
                    materials=_materials(meta, bool(identified)),
                    part_material=(meta.get("part_material") or {}).get("tag"))
    for p in (out.rig, out.part, out.housing):
        if p is not None and not p.is_file():
            raise ScheimpflugError(f"{str(d)!r}: {p.name} is missing: run 'scheimpflug twin build' again")
    return out


def _materials(meta: dict, identified: bool) -> dict:
    """The identified ``material.*`` values of ``twin.json`` as MaterialSettings fields, the part's medium."""
    from sim.identify.scan import PART_MEDIUM_KEYS
    from sim.materials import TRANSLUCENT, Translucent

    found = (meta.get("identified") or {}) if identified else {}
    out = {k.split(".", 1)[1]: float(v["value"]) for k, v in found.items()
           if k.startswith("material.") and isinstance(v, dict) and v.get("value") is not None}
    out = {k: v for k, v in out.items() if k not in PART_MEDIUM_KEYS}      # in part_material's medium
    part = meta.get("part_material") or {}
    if part.get("tag") in TRANSLUCENT and isinstance(part.get("medium"), dict):
        try:
            out["translucent"] = {**TRANSLUCENT, part["tag"]: Translucent(**part["medium"])}
        except (TypeError, ValueError) as exc:
            raise ScheimpflugError(f"{TWIN_FILE}: part_material's medium {part['medium']!r}: {exc}") from None
    return out

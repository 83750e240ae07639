"""The studio's API without HTTP: a query names a rig; the answers are what ``design`` gives for it.

A query is ``preset=NAME`` (optional) and rig keys ``<table>.<key>=<value>`` (the names of the rig
file, e.g. ``lens.focal_length_mm=35``).  The rig it names is the rig file made of the preset's tables
(or the studio's own rig file, or the paper preset) with those keys set; each value is read as a TOML
value (``35``, ``0.2``, ``true``, ``nan``) or else as a string, exactly as ``key = VALUE`` (a string
quoted) in a rig file would be; an empty value leaves the key out (its default, or derived).  So
:func:`design_json` of a query is what ``scheimpflug design --rig FILE --json`` prints for that file,
and a bad key or value raises the :class:`RigError` the command line prints
(``[lens] focal_length_mm = -1: out of range: must be in [0.5, 5000]``).
"""

from __future__ import annotations

import copy
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any
from urllib.parse import parse_qsl, urlencode

from scheimpflug.calibration.detectability import square_advice
from scheimpflug.errors import RigError
from scheimpflug.io.atomic import finite_json
from scheimpflug.model.assembly import toml_value
from scheimpflug.model.design import design_report, inverse_design
from scheimpflug.model.rig import PRESETS, Rig, preset_tables, rig_from_dict, rig_to_toml

__all__ = ["MAX_QUERY_CHARS", "STUDY_TOLERANCES", "StudioQuery", "design_json", "key_of_message", "parse_query",
           "query_number", "rig_file_text", "rig_of_query", "rig_tables", "solve_range", "split_query",
           "split_solve_query", "tolerance_spec_text"]

MAX_QUERY_CHARS = 8192
"""Longest query the studio reads [characters]: every rig key with a long value fits in a quarter of it."""

_KEY = re.compile(r"^([a-z_]+)\.([a-z0-9_]+)$")
_MESSAGE_KEY = re.compile(r"^\[([a-z_]+)\] ([a-z0-9_]+)\b")

STUDY_TOLERANCES = {"sensor.roll_deg": 0.1, "sensor.tilt_error_deg": 0.05, "lens.focus_error_um": 20.0,
                    "stage.axis_tilt_deg": 0.05}
"""The tolerances an exported study spec starts with (half-widths of uniform deviations; edit them):
sensor roll and tilt [deg], the lens left off focus [µm], the rotary axis's tilt [deg]."""


@dataclass(frozen=True)
class StudioQuery:
    """A parsed query: the preset (or None for the studio's own rig), the rig keys set, the sub-pixel factor.

    Parameters
    ----------
    preset : str or None
        ``preset=NAME``; None: the rig the studio was started with.
    keys : dict
        ``{table: {key: value}}``, each value as a TOML value or a string; None: left out.
    subpixel : float
        The sub-pixel factor the datasheet divides the per-pixel resolutions by [-] (default 1).
    """

    preset: str | None
    keys: dict
    subpixel: float = 1.0


def _value(text: str) -> Any:
    """A query value as a rig file's TOML value; a string when it is none (``abc`` as ``"abc"``); None if empty."""
    if not text.strip():
        return None
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def parse_query(query: str) -> StudioQuery:
    """Read a query string (without the ``?``).

    Parameters
    ----------
    query : str
        ``preset=NAME&subpixel=K&table.key=value&…`` (URL-encoded).

    Returns
    -------
    StudioQuery
        The preset, the keys and the sub-pixel factor.

    Raises
    ------
    RigError
        For a query longer than :data:`MAX_QUERY_CHARS`, a parameter that is not ``table.key``, a key
        given twice, an unknown preset or a sub-pixel factor that is not a number ≥ 1.
    """
    if len(query) > MAX_QUERY_CHARS:
        raise RigError(f"query of {len(query)} characters: at most {MAX_QUERY_CHARS}")
    preset, subpixel, keys, seen = None, 1.0, {}, set()
    for name, text in parse_qsl(query, keep_blank_values=True):
        if name in seen:
            raise RigError(f"{name} given twice in the query")
        seen.add(name)
        if name == "preset":
            if text not in PRESETS:
                raise RigError(f"unknown preset {text!r} (known: {', '.join(PRESETS)})")
            preset = text
        elif name == "subpixel":
            subpixel = _subpixel(text)
        elif (m := _KEY.match(name)) is not None:
            keys.setdefault(m.group(1), {})[m.group(2)] = _value(text)
        else:
            raise RigError(f"query parameter {name[:40]!r}: expected preset=NAME, subpixel=K or a rig key "
                           "table.key=VALUE (e.g. lens.focal_length_mm=35)")
    return StudioQuery(preset, keys, subpixel)


def _subpixel(text: str) -> float:
    value = _value(text)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 1 <= value <= 1000:
        raise RigError(f"subpixel = {text[:40]!r}: the sub-pixel factor must be a number in [1, 1000]")
    return float(value)


def rig_tables(q: StudioQuery, base: Mapping[str, Any] | None = None) -> dict:
    """The rig file's tables a query names: the preset's (or ``base``) with the query's keys set.

    Parameters
    ----------
    q : StudioQuery
        The parsed query.
    base : Mapping, optional
        The studio's own rig tables (``--rig FILE``), used when the query names no preset; default the
        paper preset's.

    Returns
    -------
    dict
        ``{table: {key: value}}`` as a rig file would hold them.
    """
    if q.preset is not None or base is None:
        tables = preset_tables(q.preset or "paper")
    else:
        tables = copy.deepcopy(dict(base))
    for table, values in q.keys.items():
        current = tables.setdefault(table, {})
        if isinstance(current, dict):
            current.update({k: v for k, v in values.items() if v is not None})
            for k in (k for k, v in values.items() if v is None):
                current.pop(k, None)     # left out: its default, or derived
    return tables


def rig_of_query(q: StudioQuery, base: Mapping[str, Any] | None = None) -> Rig:
    """The rig a query names (:func:`rig_tables`, then :func:`~scheimpflug.model.rig.rig_from_dict`).

    Raises
    ------
    RigError
        As ``design --rig FILE`` for a rig file of these tables: an unknown table or key, a value of the
        wrong type, out of its range, or a relation between keys broken.
    """
    return rig_from_dict(rig_tables(q, base))


def design_json(rig: Rig, advice: bool = True) -> dict:
    """What ``scheimpflug design --json`` prints for a rig, as a dict (undefined numbers as None).

    Parameters
    ----------
    rig : Rig
        The instrument.
    advice : bool, default True
        With ``pattern_advice``; False leaves out that field, the slow part (≈ 8 ms of ≈ 14: the page,
        which does not show it, asks for the rest on every slider move).

    Returns
    -------
    dict
        :func:`~scheimpflug.model.design.design_report` with ``pattern_advice``
        (:func:`~scheimpflug.calibration.detectability.square_advice`; None for an ordinary camera),
        made strict JSON.
    """
    report = design_report(rig)
    if not advice:
        return finite_json(report)
    ordinary = rig.sensor.image_distance_mm > 0      # the advice rectifies by the hinge rule: none (as design --json)
    return finite_json({**report, "pattern_advice": None if ordinary else square_advice(rig)})


def rig_file_text(rig: Rig) -> str:
    """The rig file of a rig: every key given, each derived key left as a comment.

    A derived key (:attr:`Rig.derived`) is written as a comment with the value the rule gave it, so
    that ``design --rig`` of the file derives it again and prints the same JSON as the studio
    (including ``derived``).

    Parameters
    ----------
    rig : Rig
        The instrument.

    Returns
    -------
    str
        TOML text (:func:`~scheimpflug.model.rig.rig_to_toml` with the derived keys commented out).
    """
    lines = []
    for line in rig_to_toml(rig).splitlines():
        lines.append(f"# {line} — left out: derived again when read" if line.endswith("# derived "
                     "(scheimpflug.model.plan)") else line)
    head = "# rig file written by scheimpflug studio (docs/reference/rig-keys.md)\n"
    return head + "\n".join(lines) + "\n"


def key_of_message(message: str) -> str | None:
    """The rig key an error or warning names (``"[stage] axis_mm = …"`` → ``"stage.axis_mm"``), or None."""
    m = _MESSAGE_KEY.match(message)
    return f"{m.group(1)}.{m.group(2)}" if m else None


def tolerance_spec_text(q: StudioQuery, base_file: str | None = None) -> str:
    """A tolerance-study spec of the query's design, ready for ``scheimpflug study tolerance``.

    The design is ``[rig]`` (the query's preset, or the studio's rig file ``base_file``) with the
    query's keys under ``[rig.set]``; keys the query leaves out (an empty value) make the study derive
    the design's stage layout, waist and exposure (``derive = true``).  The tolerances are
    :data:`STUDY_TOLERANCES`; the artefact is the ball bar at binning 2, the metric SD (``docs/tutorials/
    tolerance-study.md``).

    Parameters
    ----------
    q : StudioQuery
        The parsed query (its rig already checked).
    base_file : str, optional
        The studio's ``--rig`` file (an absolute path), used when the query names no preset.

    Returns
    -------
    str
        The spec's TOML text.
    """
    tolerances = len(STUDY_TOLERANCES)
    rig_line = f'file = {toml_value(base_file)}' if q.preset is None and base_file else \
        f'preset = "{q.preset or "paper"}"'
    left_out = any(v is None for values in q.keys.values() for v in values.values())
    lines = ["# tolerance study of a design from scheimpflug studio:",
             "#   scheimpflug study tolerance THIS.toml --out tolerance --workers 2",
             "", "[study]", "seed = 1", f"draws = {16 * (tolerances + 2)}    # Sobol: 16 × (tolerances + 2)",
             'method = "sobol"', 'metric = "SD_mm"', "max_error_mm = 0.1", "",
             "[rig]", rig_line, f"derive = {'true' if left_out else 'false'}", "", "[rig.set]"]
    lines += [f'"{t}.{k}" = {toml_value(v)}' for t, values in q.keys.items() for k, v in values.items()
              if v is not None]
    lines += ["", "[tolerance]    # rig key = half-width of a uniform deviation, or { normal = SIGMA }"]
    lines += [f'"{k}" = {v!r}' for k, v in STUDY_TOLERANCES.items()]
    lines += ["", "[artefacts]", 'kinds = ["ball-bar"]', "binning = 2", 'material = "metal"', ""]
    return "\n".join(lines)


def split_query(query: str, names: tuple[str, ...]) -> tuple[str, dict[str, str]]:
    """Take some parameters out of a query; the rest names the rig (:func:`parse_query`).

    Parameters
    ----------
    query : str
        The query string (URL-encoded).
    names : tuple of str
        The parameters to take out.

    Returns
    -------
    rest : str
        The query without them.
    taken : dict
        ``{name: text}`` of those given.

    Raises
    ------
    RigError
        For a query longer than :data:`MAX_QUERY_CHARS`.
    """
    if len(query) > MAX_QUERY_CHARS:
        raise RigError(f"query of {len(query)} characters: at most {MAX_QUERY_CHARS}")
    rest, taken = [], {}
    for name, text in parse_qsl(query, keep_blank_values=True):
        if name in names:
            taken[name] = text
        else:
            rest.append(urlencode([(name, text)]))
    return "&".join(rest), taken


def query_number(taken: dict[str, str], name: str, lo: float, hi: float, unit: str) -> float:
    """A number of :func:`split_query`'s parameters, finite and in [lo, hi].

    Raises
    ------
    RigError
        Naming the parameter when it is missing, not a number or out of range.
    """
    value = _value(taken.get(name, ""))
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not lo <= value <= hi:
        raise RigError(f"{name} = {taken.get(name, '')[:40]!r}: needs a number in [{lo:g}, {hi:g}] {unit}")
    return float(value)


def split_solve_query(query: str) -> tuple[str, float, float]:
    """Take ``near_mm`` and ``far_mm`` out of a solve query; the rest names the rig.

    Raises
    ------
    RigError
        If either is missing or not a positive number.
    """
    rest, taken = split_query(query, ("near_mm", "far_mm"))
    return (rest, query_number(taken, "near_mm", 0, 1e6, "mm (the wanted range, from the laser)"),
            query_number(taken, "far_mm", 0, 1e6, "mm (the wanted range, from the laser)"))


def solve_range(q: StudioQuery, near_mm: float, far_mm: float, base: Mapping[str, Any] | None = None) -> list[dict]:
    """Rigs that image a wanted range onto the sensor: the inverse design of ``design --near-mm --far-mm``.

    With the query rig's lens and sensor: one proposal keeps its sheet angle and solves the baseline
    d, one keeps its baseline and solves the sheet angle (``design --baseline-mm``); each places the
    sensor (the hinge column).

    Parameters
    ----------
    q : StudioQuery
        The current design.
    near_mm, far_mm : float
        The wanted range, along the sheet from the laser (the Scheimpflug line) [mm].
    base : Mapping, optional
        The studio's own rig tables (:func:`rig_tables`).

    Returns
    -------
    list of dict
        Per proposal: ``label``, ``keys`` (``{"table.key": value}`` to set), and ``design`` (its
        ``design --json``) or ``error`` (why the inverse design or the rig was refused).

    Raises
    ------
    RigError
        If the current design is not a rig.
    """
    rig = rig_of_query(q, base)
    f, p, n = rig.lens.focal_length_mm, rig.sensor.pixel_pitch_um, rig.sensor.columns
    out = []
    for label, kwargs in ((f"keep tan φ = {rig.laser.tan_phi:g}, solve the baseline d", {"tan_phi": rig.laser.tan_phi}),
                          (f"keep d = {rig.laser.scheimpflug_distance_mm:g} mm, solve the sheet angle",
                           {"scheimpflug_distance_mm": rig.laser.scheimpflug_distance_mm})):
        try:
            c = inverse_design(f, p, n, near_mm, far_mm, **kwargs)
            keys = {"laser.tan_phi": c.tan_phi, "laser.scheimpflug_distance_mm": c.scheimpflug_distance_mm,
                    "sensor.hinge_column": c.hinge_column}
            tables = copy.deepcopy(q.keys)
            for name, value in keys.items():
                table, key = name.split(".")
                tables.setdefault(table, {})[key] = value
            out.append({"label": label, "keys": keys,
                        "design": design_json(rig_of_query(StudioQuery(q.preset, tables, q.subpixel), base))})
        except RigError as exc:
            out.append({"label": label, "keys": {}, "error": " ".join(str(exc).split())})
    return out

"""Rig files: reading a TOML rig file, building a rig from its tables, the built-in presets.

:func:`rig_from_dict` (and :func:`load_rig`, which reads the file first) takes the
tables of a rig file; :func:`load_preset` a built-in rig by name
(``scheimpflug/model/presets/*.toml``).  Importable from :mod:`scheimpflug.model.rig` too.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any

from scheimpflug.errors import RigError
from scheimpflug.model.assembly import Rig, rig_from_tables
from scheimpflug.model.housing import load_housing
from scheimpflug.model.instrument_file import is_by_parts, rig_from_parts

__all__ = [
    "PRESETS",
    "load_preset",
    "load_rig",
    "preset_tables",
    "read_toml",
    "rig_from_dict",
    "with_stage_keys",
]

PRESETS = ("paper", "paper-as-built")
"""Names of the built-in rigs (:func:`load_preset`): ``paper``, the ideal paper rig, and
``paper-as-built``, the same rig with every modelled error source at the values of the
kind of parts the paper used (each value's source in ``presets/paper-as-built.toml``)."""


def rig_from_dict(data: Mapping[str, Any]) -> Rig:
    """Build a rig from nested tables, in either form of the rig file.

    The Scheimpflug form (``[lens]``, ``[laser]``, ``[sensor]``, ``[stage]`` …:
    :func:`scheimpflug.model.assembly.rig_from_tables`): missing keys take their
    defaults, the paper's values, except the keys of :data:`DERIVED_KEYS` (the
    stage positions, the laser's waist distance, the exposure), which are derived
    from the rig's working volume (:mod:`scheimpflug.model.plan`); None also means
    "derive".  The form by parts (``[camera]``, ``[laser] plane``, ``[turntable]``:
    :mod:`scheimpflug.model.instrument_file`): the rig of that instrument, exactly.

    Parameters
    ----------
    data : Mapping[str, Any]
        ``{table: {key: value}}`` as in the rig file (or ``manifest.json``);
        integral floats are accepted for integer keys.

    Returns
    -------
    Rig
        The validated rig, its stage keys resolved.

    Raises
    ------
    RigError
        For a non-table, an unknown table or key, a boolean or non-numeric
        value, or an invalid rig; in the form by parts also a Scheimpflug key the
        parts replace (both named), a singular camera matrix, a zero or non-unit
        normal, a sheet behind the camera or never in view, an unknown camera preset.
    """
    if not isinstance(data, Mapping):
        raise RigError(f"a rig must be a table of tables, got {type(data).__name__}")
    if is_by_parts(data):
        return rig_from_parts(data)
    return rig_from_tables(data)


def load_rig(path: str | Path) -> Rig:
    """Read a TOML rig file.

    Parameters
    ----------
    path : str or Path
        The rig file (docs/reference/interface.md).

    Returns
    -------
    Rig
        The validated rig; keys not in the file take their defaults
        (:func:`rig_from_dict`).

    Raises
    ------
    RigError
        If the file is missing, unreadable, not UTF-8, not valid TOML, or
        describes an invalid rig; a ``housing = "path"`` file that cannot be read
        (:func:`scheimpflug.model.housing.load_housing`, the path relative to the rig file).
    """
    data = read_toml(path, "rig file", RigError)
    if isinstance(data.get("housing"), str):
        where = Path(path).parent / data["housing"]
        data = {**data, "housing": {"board": [b.to_dict() for b in load_housing(where)]}}
    return rig_from_dict(data)


def read_toml(path: str | Path, what: str, error: type[Exception] = RigError) -> dict:
    """Read a UTF-8 TOML file (rig file, dataset or study spec) with one clear error.

    Parameters
    ----------
    path : str or Path
        The file.
    what : str
        What the file is, for the message (``"rig file"``, ``"spec file"``).
    error : type of Exception, default RigError
        The error class raised (the caller's typed error).

    Returns
    -------
    dict
        The parsed tables.

    Raises
    ------
    Exception
        ``error``, naming the file: it is missing, unreadable, not UTF-8 or not valid TOML.
    """
    p = Path(path)
    try:
        text = p.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise error(f"{what} {str(p)!r} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{what} {str(p)!r} cannot be read: {exc}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{what} {str(p)!r} is not valid TOML: {exc}") from None


def load_preset(name: str) -> Rig:
    """A built-in rig by name.

    Parameters
    ----------
    name : str
        One of :data:`PRESETS` (``paper``: docs/explanation/design-notes.md §2 with f/5.6;
        ``paper-as-built``: the same with its error models on).

    Returns
    -------
    Rig
        The preset, read from ``scheimpflug/model/presets/<name>.toml``.

    Raises
    ------
    RigError
        If ``name`` is not a known preset.
    """
    return rig_from_dict(preset_tables(name))


def preset_tables(name: str) -> dict:
    """The tables of a built-in rig as its file gives them (before defaults are filled in).

    Parameters
    ----------
    name : str
        One of :data:`PRESETS`.

    Returns
    -------
    dict
        ``{table: {key: value}}`` of ``scheimpflug/model/presets/<name>.toml``.

    Raises
    ------
    RigError
        If ``name`` is not a known preset.
    """
    if name not in PRESETS:
        raise RigError(f"unknown preset {name!r} (known: {', '.join(PRESETS)})")
    text = resources.files("scheimpflug.model").joinpath("presets", f"{name}.toml").read_text("utf-8")
    return tomllib.loads(text)


def with_stage_keys(text: str, keys: Mapping[str, float], note: str) -> str:
    """A rig file's text with ``keys`` set in its ``[stage]`` table, under a comment line ``note``.

    Keys already there are replaced, the others added after the table's header; a ``[stage]``
    table is appended when the file has none.  An earlier call's note (a comment line
    beginning ``# table keys fitted by``) is dropped with the keys it named.

    Parameters
    ----------
    text : str
        The rig file's text (TOML).
    keys : mapping of str to float
        ``[stage]`` keys and their values (written as TOML floats).
    note : str
        The comment line written above them (without ``#``).

    Returns
    -------
    str
        The new text, ending in a newline.
    """
    from scheimpflug.model.assembly import toml_value

    lines = text.splitlines()
    new = [f"{k} = {toml_value(float(v))}" for k, v in keys.items()]
    try:
        start = next(i for i, line in enumerate(lines) if line.strip() == "[stage]")
    except StopIteration:
        return text.rstrip("\n") + f"\n\n[stage]\n# {note}\n" + "\n".join(new) + "\n"
    end = next((i for i in range(start + 1, len(lines)) if lines[i].lstrip().startswith("[")), len(lines))
    body = [line for line in lines[start + 1:end]
            if line.split("=", 1)[0].strip() not in keys and line.strip() != f"# {note}"
            and not line.startswith("# table keys fitted by")]                 # an earlier fit's note
    return "\n".join(lines[:start + 1] + [f"# {note}"] + new + body + lines[end:]) + "\n"

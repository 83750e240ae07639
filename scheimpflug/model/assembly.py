"""The whole instrument: :class:`Rig`, its tables filled in and checked, as plain tables and as TOML.

A :class:`Rig` holds one dataclass per table of the rig file
(:mod:`scheimpflug.model.tables`), is validated on construction
(:func:`scheimpflug.model.keys.validate_rig`) and fills in the keys a file leaves
out by the working-volume rule of :mod:`scheimpflug.model.plan`.
:func:`rig_from_tables` builds one from the Scheimpflug tables; a rig file by the
instrument's parts goes through :mod:`scheimpflug.model.instrument` first
(:func:`scheimpflug.model.rigfile.rig_from_dict`).  Importable from
:mod:`scheimpflug.model.rig` too.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from scheimpflug.errors import RigError
from scheimpflug.model.chain import Chain, expand_chain_table
from scheimpflug.model.housing import Board, housing_from_dict
from scheimpflug.model.keys import table_from_values, validate_rig
from scheimpflug.model.plan import resolve_defaults
from scheimpflug.model.tables import DERIVED_KEYS, TABLES, Environment, Laser, Lens, Sensor, Stage, Twin

__all__ = [
    "Rig",
    "rig_from_tables",
    "rig_to_dict",
    "housing_lines",
    "rig_to_toml",
    "toml_value",
]


@dataclass(frozen=True)
class Rig:
    """A whole instrument: one table of the rig file per field.

    The rig is validated on construction (:func:`validate_rig`); keys left as
    None (:data:`DERIVED_KEYS`: the stage positions, the laser's waist, the
    exposure) are then derived from the rig's working volume
    (:func:`scheimpflug.model.plan.resolve_defaults`), so ``rig.stage.d0_mm``
    and the others are always numbers, and :attr:`derived` names them.

    Parameters
    ----------
    lens : Lens, optional
        The ``[lens]`` table; default the paper lens.
    laser : Laser, optional
        The ``[laser]`` table; default the paper laser.
    sensor : Sensor, optional
        The ``[sensor]`` table; default the paper sensor.
    stage : Stage, optional
        The ``[stage]`` table; default: every position key derived.
    environment : Environment, optional
        The ``[environment]`` table; default the paper's ambient light.
    twin : Twin, optional
        The ``[twin]`` table (how the digital twin renders); default the ideal twin.
    chain : Chain, optional
        The ``[chain]`` table (:mod:`scheimpflug.model.chain`: the camera's colour mosaic,
        tone curve, 8 bits, JPEG, glare, blooming); default off (16-bit grey raw frames).
    housing : tuple of Board, default ()
        The scanner's housing, ``[[housing.board]]`` (:mod:`scheimpflug.model.housing`): boards
        in the instrument frame that the twin renders beside the table; default none.

    Attributes
    ----------
    derived : tuple of str
        The keys that were derived rather than given, as ``"table.key"`` (not
        part of the rig's value: two rigs with the same numbers are equal).

    Raises
    ------
    RigError
        If a table has the wrong type, a key the wrong type or a non-finite
        value, or the values are impossible (the message names the key).
    """

    lens: Lens = field(default_factory=Lens)
    laser: Laser = field(default_factory=Laser)
    sensor: Sensor = field(default_factory=Sensor)
    stage: Stage = field(default_factory=Stage)
    environment: Environment = field(default_factory=Environment)
    twin: Twin = field(default_factory=Twin)
    chain: Chain = field(default_factory=Chain)
    housing: tuple[Board, ...] = ()
    derived: tuple[str, ...] = field(default=(), init=False, compare=False, repr=False)

    def __post_init__(self) -> None:
        validate_rig(self)
        laser, sensor, stage, derived = resolve_defaults(self)
        for name, table in (("laser", laser), ("sensor", sensor), ("stage", stage)):
            object.__setattr__(self, name, table)
        object.__setattr__(self, "derived", tuple(k for k in DERIVED_KEYS if k in derived))
        if derived:
            try:                     # derived values must lie in their ranges too
                validate_rig(self)
            except RigError as exc:
                raise RigError(f"{exc} (derived from the other keys: set it in the rig file)") from None

    def replace(self, *, rederive: bool = True, **tables: Mapping[str, Any]) -> Rig:
        """A copy with some keys changed, e.g. ``rig.replace(lens={"f_number": 8})``.

        Parameters
        ----------
        rederive : bool, default True
            Derive again, for the new rig, the keys that were derived for this
            one (unless given); False keeps their values.  A key given as None
            is derived.
        **tables : Mapping[str, Any]
            Per table name (``lens``, ``laser``, ``sensor``, ``stage``,
            ``environment``), the keys to change and their new values.

        Returns
        -------
        Rig
            The new, validated rig; ``self`` is unchanged.

        Raises
        ------
        RigError
            For an unknown table or key, or if the changed rig is invalid.
        """
        data: dict[str, dict[str, Any]] = rig_to_dict(self)
        for table, values in tables.items():
            if table not in data:
                raise RigError(f"unknown rig table [{table}]")
            data[table].update(values)
        given = {f"{t}.{k}" for t, values in tables.items() for k in values}
        again = tuple(k for k in self.derived if k not in given)
        if rederive:
            for key in again:
                table, name = key.split(".")
                data[table][name] = None
        new = rig_from_tables(data)
        if not rederive:
            object.__setattr__(new, "derived", tuple(k for k in DERIVED_KEYS if k in again or k in new.derived))
        return new


def rig_from_tables(data: Mapping[str, Any]) -> Rig:
    """Build a rig from nested tables (the Scheimpflug form: ``[lens]``, ``[laser]``, ``[sensor]`` …).

    Missing keys take their defaults: the paper's values, except the keys of
    :data:`DERIVED_KEYS` (the stage positions, the laser's waist distance, the
    exposure), which are derived from the rig's working volume
    (:mod:`scheimpflug.model.plan`); None also means "derive".

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
        value, or an invalid rig.
    """
    if not isinstance(data, Mapping):
        raise RigError(f"a rig must be a table of tables, got {type(data).__name__}")
    unknown = sorted(set(data) - set(TABLES) - {"housing"})
    if unknown:
        raise RigError(f"unknown rig table [{unknown[0]}] (known: {', '.join(TABLES)}, housing)")
    data = {**data, "chain": expand_chain_table(data.get("chain", {}))}   # a named camera's values
    parts = {name: table_from_values(name, cls, data.get(name, {})) for name, cls in TABLES.items()}
    return Rig(**parts, housing=_housing(data.get("housing")))


def _housing(table: Any) -> tuple[Board, ...]:
    """The boards of a rig's ``[housing]`` table (``{"board": [...]}``); none without one."""
    if table is None:
        return ()
    if isinstance(table, str):
        raise RigError(f"housing = {table!r}: a housing file is read by load_rig, relative to the rig file "
                       "(here no file: give the boards as [[housing.board]])")
    if not isinstance(table, Mapping) or set(table) - {"board"}:
        raise RigError("[housing] holds [[housing.board]] tables only (docs/reference/interface.md)")
    try:
        return housing_from_dict(dict(table))
    except RigError as exc:
        raise RigError(f"[housing]: {exc}") from None


def rig_to_dict(rig: Rig) -> dict[str, dict[str, Any]]:
    """Nested plain tables, as in the rig file (and in ``manifest.json``).

    Parameters
    ----------
    rig : Rig
        The instrument.

    Returns
    -------
    dict of str to dict
        ``{table: {key: value}}``, every key of every table; derived stage
        keys hold the values the rule gave them; with a housing also
        ``"housing": {"board": [board, …]}`` (:meth:`Board.to_dict`).
    """
    out = {name: dataclasses.asdict(getattr(rig, name)) for name in TABLES}
    if rig.housing:
        out["housing"] = {"board": [b.to_dict() for b in rig.housing]}
    return out


def rig_to_toml(rig: Rig) -> str:
    """The rig file text of a rig (every key, with its value).

    Parameters
    ----------
    rig : Rig
        The instrument.

    Returns
    -------
    str
        TOML text, one ``[table]`` per rig table; :func:`load_rig` reads it
        back.  Keys that the rule derived carry the comment ``# derived``.
    """
    lines: list[str] = []
    for name, table in rig_to_dict(rig).items():
        if name == "housing":
            lines += housing_lines(table["board"])
            continue
        lines.append(f"[{name}]")
        for k, v in table.items():
            note = "  # derived (scheimpflug.model.plan)" if f"{name}.{k}" in rig.derived else ""
            lines.append(f"{k} = {toml_value(v)}{note}")
        lines.append("")
    return "\n".join(lines)


def housing_lines(boards) -> list[str]:
    """A rig file's ``[[housing.board]]`` tables.

    Parameters
    ----------
    boards : sequence of dict
        :meth:`Board.to_dict` of each board.

    Returns
    -------
    list of str
        TOML lines, one table per board, each followed by a blank line.
    """
    lines: list[str] = []
    for b in boards:
        lines.append("[[housing.board]]")
        for k, v in b.items():
            lines.append(f"{k} = {toml_value(v)}")
        lines.append("")
    return lines


def toml_value(value: Any) -> str:
    """A value as a TOML literal, the one writer of rig, housing and studio files.

    Parameters
    ----------
    value : bool, int, float, str or (nested) sequence of numbers
        The value (numpy scalars and arrays included).

    Returns
    -------
    str
        ``true``/``false``, a basic string with backslash and ``"`` escaped, ``repr`` of the
        number (floats as Python floats), or an array of them.
    """
    if isinstance(value, (bool, np.bool_)):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (np.ndarray, list, tuple)):
        arr = np.asarray(value, np.float64)
        items = [repr(float(x)) for x in arr] if arr.ndim == 1 else [toml_value(row) for row in arr]
        return "[" + ", ".join(items) + "]"
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    return repr(int(value)) if isinstance(value, np.integer) else repr(value)

"""The rig: the one description of an instrument, real or simulated — every name in one place.

The rig is read from the TOML rig file of docs/reference/interface.md (one table per
dataclass) or taken from a built-in preset (``paper``).  Every key has a unit in its
name where doubt is possible; derived quantities (tilt, hinge points, F², C) are
computed in :mod:`scheimpflug.model.hinge`, never stored.  This module gathers the
names of the modules that hold it, so that ``from scheimpflug.model.rig import …``
finds each of them:

* :mod:`scheimpflug.model.tables` — the tables as frozen dataclasses (:class:`Lens`,
  :class:`Laser`, :class:`Sensor`, :class:`Stage`, :class:`Environment`, :class:`Twin`;
  the ``[chain]`` table is :mod:`scheimpflug.model.chain`'s);
* :mod:`scheimpflug.model.keys` — every key's range (:data:`KEY_RANGES`) and the checks
  of a whole rig (:func:`validate_rig`);
* :mod:`scheimpflug.model.error_models` — which keys switch the error models on;
* :mod:`scheimpflug.model.assembly` — :class:`Rig` itself, its plain tables and TOML text;
* :mod:`scheimpflug.model.rigfile` — rig files and presets (:func:`load_rig`,
  :func:`rig_from_dict`, :func:`load_preset`); a file may give the instrument by its
  parts instead (``[camera]``, ``[laser] plane``, ``[turntable]``:
  :mod:`scheimpflug.model.instrument_file`, the same rig).

Rig frame (docs/explanation/design-notes.md §2): origin at the lens centre, +x along the optical axis
toward the object, +z up, +y = z × x; lengths in mm, angles in degrees at
interfaces.
"""

from __future__ import annotations

from scheimpflug.model.assembly import Rig, rig_from_tables, rig_to_dict, rig_to_toml
from scheimpflug.model.error_models import (
    ERROR_MODEL_SHAPES,
    ERROR_MODELS,
    TWIN_EFFECTS,
    active_error_models,
    is_realistic,
    with_error_models,
)
from scheimpflug.model.keys import KEY_RANGES, MAX_TILT_DEG, key_in_range, validate_rig
from scheimpflug.model.rigfile import PRESETS, load_preset, load_rig, preset_tables, read_toml, rig_from_dict
from scheimpflug.model.tables import (
    DERIVED_KEYS,
    DERIVED_STAGE_KEYS,
    SPECKLE_MODELS,
    TABLES,
    Environment,
    Laser,
    Lens,
    Sensor,
    Stage,
    Twin,
)

#: The rig file's tables, ``{name: dataclass}`` (:data:`scheimpflug.model.tables.TABLES`; the old private name).
_TABLES = TABLES

__all__ = [
    "DERIVED_KEYS",
    "DERIVED_STAGE_KEYS",
    "ERROR_MODELS",
    "ERROR_MODEL_SHAPES",
    "Environment",
    "KEY_RANGES",
    "Laser",
    "Lens",
    "MAX_TILT_DEG",
    "PRESETS",
    "Rig",
    "SPECKLE_MODELS",
    "Sensor",
    "Stage",
    "TABLES",
    "TWIN_EFFECTS",
    "Twin",
    "active_error_models",
    "is_realistic",
    "key_in_range",
    "load_preset",
    "load_rig",
    "preset_tables",
    "read_toml",
    "rig_from_dict",
    "rig_from_tables",
    "rig_to_dict",
    "rig_to_toml",
    "validate_rig",
    "with_error_models",
]

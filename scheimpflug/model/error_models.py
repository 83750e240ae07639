"""The error models of a rig and the twin's physical light: which keys switch them, which are on.

The groups (:data:`ERROR_MODELS`, :data:`ERROR_MODEL_SHAPES`, :data:`TWIN_EFFECTS`) name
rig keys as ``"table.key"``; :func:`active_error_models` lists those of a rig that are
on, :func:`with_error_models` copies groups from one rig to another.  Importable from
:mod:`scheimpflug.model.rig` too.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

from scheimpflug.errors import RigError

if TYPE_CHECKING:
    from scheimpflug.model.assembly import Rig

__all__ = [
    "ERROR_MODELS",
    "ERROR_MODEL_SHAPES",
    "TWIN_EFFECTS",
    "active_error_models",
    "is_realistic",
    "with_error_models",
]


#: The error models' switches, by source: each model is off when all its keys hold
#: their defaults (``fan_edge_ratio`` 1, every other 0).  Keys that only shape a model
#: (``translation_lead_mm``, ``translation_travel_mm``, ``hot_pixel_e``,
#: ``pattern_seed``) are not switches.
ERROR_MODELS: dict[str, tuple[str, ...]] = {
    "translation stage": ("stage.translation_scale_ppm", "stage.translation_periodic_um",
                          "stage.translation_repeatability_um", "stage.straightness_lateral_um",
                          "stage.straightness_vertical_um", "stage.pitch_urad", "stage.yaw_urad"),
    "rotary stage": ("stage.rotary_eccentricity_deg", "stage.rotary_repeatability_deg",
                     "stage.wobble_urad", "stage.radial_error_um"),
    "calibration plate": ("stage.plate_height_error_mm", "stage.plate_flatness_um",
                          "stage.plate_edge_break_mm", "stage.plate_tilt_deg", "stage.plate_yaw_deg"),
    "laser": ("laser.line_bow_mrad", "laser.fan_edge_ratio", "laser.pointing_jitter_urad"),
    "speckle": ("laser.speckle_contrast",),
    "lens": ("lens.focal_length_error_mm", "lens.focus_error_um", "lens.k1", "lens.k2"),
    "sensor": ("sensor.prnu_percent", "sensor.dsnu_e", "sensor.hot_pixel_fraction",
               "sensor.exposure_jitter_percent"),
}


#: Keys that shape an error model without switching it on, copied with it by
#: :func:`with_error_models`.
ERROR_MODEL_SHAPES: dict[str, tuple[str, ...]] = {
    "translation stage": ("stage.translation_lead_mm", "stage.translation_travel_mm"),
    "sensor": ("sensor.hot_pixel_e", "sensor.pattern_seed"),
    "speckle": ("twin.speckle_model",),
}


#: The twin's physical light (``[twin]``, issue 10), by effect: each is off at its
#: default (``bounces`` 1, ``subsurface`` false).  Not error models of the instrument
#: (:func:`active_error_models` ignores them: the geometry and the truth stay the
#: ideal rig's), but sources of the as-built rig's error all the same, which
#: :func:`with_error_models` takes one at a time like the error models.
TWIN_EFFECTS: dict[str, tuple[str, ...]] = {
    "inter-reflections": ("twin.bounces",),
    "subsurface": ("twin.subsurface",),
}


def active_error_models(rig: Rig) -> tuple[str, ...]:
    """The error-model keys of a rig that are on.

    Parameters
    ----------
    rig : Rig
        The instrument.

    Returns
    -------
    tuple of str
        ``"table.key"`` of every key of :data:`ERROR_MODELS` whose value
        differs from its default, in the order of :data:`ERROR_MODELS`; empty
        for an ideal rig.
    """
    on = []
    for keys in ERROR_MODELS.values():
        for key in keys:
            table, name = key.split(".")
            obj = getattr(rig, table)
            default = next(f.default for f in dataclasses.fields(obj) if f.name == name)
            if getattr(obj, name) != default:
                on.append(key)
    return tuple(on)


def is_realistic(rig: Rig) -> bool:
    """Whether the rig's twin is more than the ideal first-surface one.

    The twin's physical light (:data:`TWIN_EFFECTS`, surface-attached speckle) costs
    ≈ 3 × an ideal frame's time and ≈ 2.5 × its memory (benchmarks/RESULTS.md); the
    render's job sizing and its ``--workers auto`` depend on it.

    Parameters
    ----------
    rig : Rig
        The rig.

    Returns
    -------
    bool
        True with ``[twin] bounces`` > 1, ``subsurface`` on, or surface-attached speckle
        (``speckle_model = "surface"`` with ``[laser] speckle_contrast`` > 0).
    """
    t = rig.twin
    return t.bounces > 1 or bool(t.subsurface) or (t.speckle_model == "surface"
                                                      and rig.laser.speckle_contrast > 0)


def with_error_models(rig: Rig, source: Rig, groups) -> Rig:
    """A rig with some error models taken from another rig.

    Parameters
    ----------
    rig : Rig
        The base instrument (e.g. the ideal ``paper`` preset).
    source : Rig
        The rig whose error-model values are taken (e.g. ``paper-as-built``).
    groups : iterable of str
        Names of :data:`ERROR_MODELS` groups (``"translation stage"``, ``"sensor"`` …)
        or of :data:`TWIN_EFFECTS` (``"inter-reflections"``, ``"subsurface"``).

    Returns
    -------
    Rig
        ``rig`` with every key of those groups (switches of :data:`ERROR_MODELS` and
        :data:`TWIN_EFFECTS`, shapes of :data:`ERROR_MODEL_SHAPES`) set to its value in
        ``source``.

    Raises
    ------
    RigError
        For an unknown group name.
    """
    tables: dict[str, dict[str, Any]] = {}
    known = {**ERROR_MODELS, **TWIN_EFFECTS}
    for group in groups:
        if group not in known:
            raise RigError(f"unknown error model {group!r} (known: {', '.join(known)})")
        for key in known[group] + ERROR_MODEL_SHAPES.get(group, ()):
            table, name = key.split(".")
            tables.setdefault(table, {})[name] = getattr(getattr(source, table), name)
    return rig.replace(**tables) if tables else rig


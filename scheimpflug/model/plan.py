"""Working volume and stage plan of a rig: where the plate, the axis and the tables go.

A rig file need not say where its stages are, where its laser is focused or
how long it exposes.  The keys of :data:`scheimpflug.model.rig.DERIVED_KEYS`
that it leaves out are derived here from the rig's *working volume* — the part
of the sheet that the sensor sees and the laser lights — so that the defaults
work for any rig, not only the paper's.  The paper preset sets every key to
the paper's values, so nothing is derived for it.

Working volume (ideal rig: no misalignment, no distortion)
----------------------------------------------------------
In sheet coordinates (D along the sheet from the object hinge, h above the
meridian plane), paper Eqs. 11–12 make the view a wedge from the hinge: the
sensor's columns ``m … N_u − 1 − m`` see ``D_near … D_far``, and at distance D
the rows ``m − ½ … N_v − ½ − m`` see

    h_top(D) = C·(v_h − m + ½)·D/|F²|,   h_bottom(D) = C·(v_h − N_v + ½ + m)·D/|F²|

(``m`` a margin in pixels).  The laser lights ``|h| ≤ tan(F/2 − e)·(D − D_l)``
(fan F, soft edge e, laser origin at D_l); the working volume is the
intersection.  Its top is concave and its bottom convex in D, so a part that
spans ``D_a − R … D_a + R`` is in view at every angle iff it is at both ends.

The rule for the keys a rig leaves out
--------------------------------------
``d0_mm``
    Stage zero at the near end of the view: ``d0 = −⌊D(column 0)⌋`` (whole mm).
``calibration_plate_height_mm`` and ``calibration_table_z_mm``
    The tallest plate whose two edges stay in view, with a margin of
    :data:`EDGE_MARGIN_ROWS` rows to the sensor border (the edge finder needs
    18 rows of background beyond an edge), at *every* stage position of the
    depth range (:func:`calibration_volume`: :data:`STRIPE_MARGIN_COLUMNS`
    columns from each end, or ⌈3σ⌉ + 2 where the stripe is wider, so that the
    detector's ±(⌈3σ⌉ + 1) window stays on the sensor): height
    ``min_D h_top − max_D h_bottom`` rounded down (1 mm above 10 mm, else
    0.1 mm), table at ``max_D h_bottom`` (plus half the rounding).  With one of
    the two keys set, the other is chosen so that both edges are in view over
    the longest possible stretch of the depth range.  When no plate fits over
    the whole range (a hinge row outside the sensor), the plate takes half the
    view's height where the view is tallest, and the plan says so.
``axis_mm`` and ``rotary_table_z_mm``
    The axis sits where the largest upright cylinder *as tall as it is wide*
    (the reference part, height 2R) stays in view at every angle, with a margin
    of :data:`PART_MARGIN_PX` pixels, and the table at the bottom of the view
    at the part's binding end (rounded up to 0.1 mm); the axis is rounded to
    0.1 mm.  With one key set, the other is chosen for the largest reference
    part.
``[laser] waist_distance_mm``
    The sheet's waist at the rotary axis (in-sheet distance from the laser
    origin, 0.1 mm).
``[sensor] exposure_ms``
    The exposure at which a white Lambertian surface on the rotary axis,
    facing the laser, peaks at :data:`EXPOSURE_FULL_WELL_FRACTION` of the full
    well (:func:`lambertian_peak_electrons_per_ms`, three significant
    digits): 0.49 ms for the paper rig, whose preset says 0.5 ms.  A metal
    plate seen at a steep angle is dimmer, near its specular direction up to
    ≈ 3.5 × brighter.

Order: d0; the rotary axis and its table; the waist; the plate and its table
(their column margins depend on the stripe's width, hence on the waist); the
exposure.

Calibration plan (:func:`calibration_plan`): :data:`CALIBRATION_STEPS` frames
spanning the stretch where both plate edges are in view (if it is at least
half the depth range; else the whole depth range, where frames with one edge
still give the distance relation, and ``note`` says why), step rounded down to
three significant digits, start rounded up to the step's last digit.

Rotary plan (:func:`rotary_plan`): for the rig's axis and table, the largest
reference cylinder (radius and height 2R), the largest radius of a flat part on
the table and the largest height of a thin part on the axis that stay in view
at every angle.  :func:`stage_warnings` names a key whose value puts the axis,
the rotary table or the calibration plate out of view, and the range that
would work.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.volume import (
    EDGE_MARGIN_ROWS,
    STRIPE_MARGIN_COLUMNS,
    WorkingVolume,
    bisect_boundary,
    calibration_volume,
    lambertian_peak_electrons_per_ms,
    laser_distance_mm,
    plate_interval_mm,
    sheet_half_width_mm,
    stripe_sigma_px,
    working_volume,
)

if TYPE_CHECKING:
    from scheimpflug.model.assembly import Rig
    from scheimpflug.model.tables import Laser, Sensor, Stage

__all__ = [
    "CALIBRATION_STEPS",
    "EDGE_MARGIN_ROWS",
    "EXPOSURE_FULL_WELL_FRACTION",
    "PART_MARGIN_PX",
    "STRIPE_MARGIN_COLUMNS",
    "CalibrationPlan",
    "RotaryPlan",
    "WorkingVolume",
    "axis_warnings",
    "calibration_plan",
    "calibration_volume",
    "lambertian_peak_electrons_per_ms",
    "laser_distance_mm",
    "plate_interval_mm",
    "plate_warnings",
    "resolve_defaults",
    "sheet_half_width_mm",
    "rotary_plan",
    "stage_warnings",
    "stripe_sigma_px",
    "working_volume",
]

PART_MARGIN_PX = 4           # pixels between a rotary part and the view's border [px]
CALIBRATION_STEPS = 27       # frames of the default calibration plan (the paper's count) [-]
EXPOSURE_FULL_WELL_FRACTION = 1 / 6  # white Lambertian stripe peak on the axis / full well [-]
_REFERENCE_ASPECT = 2.0      # reference part: height = 2 × radius (as tall as wide) [-]



# ---------------------------------------------------------------- rounding


def _floor_to(x: float, q: float) -> float:
    return math.floor(x / q + 1e-9) * q


def _ceil_to(x: float, q: float) -> float:
    return math.ceil(x / q - 1e-9) * q


def _nice_height(h: float) -> float:
    """A plate height rounded down: 1 mm above 10 mm, 0.1 mm above 1 mm, else 0.01 mm."""
    q = 1.0 if h >= 10 else (0.1 if h >= 1 else 0.01)
    return round(_floor_to(h, q), 6)


def _step_quantum(step: float) -> float:
    """The last digit of ``step`` kept at three significant digits [mm]."""
    return 10.0 ** (math.floor(math.log10(step)) - 2) if step > 0 else 0.01


# ---------------------------------------------------------------- the plate and its table


def _plate_layout(vol: WorkingVolume, height: float | None, table: float | None) -> tuple[float, float]:
    """Plate height and table height by the rule (module docstring), keeping a given one."""
    D = vol.grid()
    top, bot = vol.top_mm(D), vol.bottom_mm(D)
    if height is None and table is None:
        raw = float(top.min() - bot.max())
        if raw <= 0:  # no plate fits over the whole range: half the view where it is tallest
            i = int(np.argmax(top - bot))
            h = _nice_height(0.5 * float(top[i] - bot[i]))
            return h, round(float(0.5 * (top[i] + bot[i]) - 0.5 * h), 1)
        h = _nice_height(raw)
        return h, round(_ceil_to(float(bot.max()) + 0.5 * (raw - h), 0.1), 1)
    if height is None:
        return _plate_for_table(vol, float(table), top, bot), float(table)
    return float(height), _table_for_plate(vol, float(height), top, bot)


def _plate_for_table(vol: WorkingVolume, table: float, top: np.ndarray, bot: np.ndarray) -> float:
    seen = (bot <= table) & (table < top)
    if not seen.any():  # the table is out of view everywhere: half the tallest view
        return _nice_height(0.5 * float(np.max(top - bot)))
    return _nice_height(float(top[seen].min()) - table)


def _table_for_plate(vol: WorkingVolume, height: float, top: np.ndarray, bot: np.ndarray) -> float:
    """The table height that shows both edges of the plate over the longest stretch."""
    lo, hi = float(bot.min()), float(top.max()) - height
    if hi <= lo:  # taller than the view anywhere: centre it where the view is tallest
        i = int(np.argmax(top - bot))
        return round(float(0.5 * (top[i] + bot[i] - height)), 1)
    for _ in range(2):  # coarse, then fine
        z = np.linspace(lo, hi, 401)
        ok = (bot[None, :] <= z[:, None]) & (z[:, None] + height <= top[None, :])
        n = ok.sum(axis=1)
        best = z[n == n.max()]
        width = (hi - lo) / 400
        lo, hi = float(best.min()) - width, float(best.max()) + width
    return round(float(0.5 * (best.min() + best.max())), 1)


# ---------------------------------------------------------------- the rotary axis and its table


def _span_ok(vol: WorkingVolume, Da, R: float, H: float, table=None):
    """Whether a part of radius R and height H on the axis at Da fits (table given or free)."""
    Da = np.asarray(Da, dtype=np.float64)
    a, b = Da - R, Da + R
    inside = (a >= vol.near_mm) & (b <= vol.far_mm)
    floor_ = np.maximum(vol.bottom_mm(a), vol.bottom_mm(b))
    ceil_ = np.minimum(vol.top_mm(a), vol.top_mm(b))
    if table is None:
        return inside & (ceil_ - floor_ >= H), floor_
    return inside & (floor_ <= table) & (table + H <= ceil_), floor_


def _largest(fits, r_max: float) -> float:
    """Largest R in [0, r_max] with ``fits(R)`` (monotone), 0 if none."""
    if r_max <= 0 or not fits(1e-9):
        return 0.0
    if fits(r_max):
        return r_max
    return bisect_boundary(fits, 1e-9, r_max)


def _rotary_layout(vol: WorkingVolume, axis_D: float | None, table: float | None) -> tuple[float, float]:
    """Axis distance D_a and table height by the rule (module docstring), keeping a given one."""
    r_max = 0.5 * (vol.far_mm - vol.near_mm)
    Da = np.array([axis_D]) if axis_D is not None else vol.grid()

    def fits(R: float) -> bool:
        return bool(_span_ok(vol, Da, R, _REFERENCE_ASPECT * R, table)[0].any())

    R = _largest(fits, r_max)
    ok, floor_ = _span_ok(vol, Da, R, _REFERENCE_ASPECT * R, table)
    if not ok.any():  # nothing fits (axis or table out of view): fall back to the middle
        mid = float(Da[0]) if axis_D is not None else 0.5 * (vol.near_mm + vol.far_mm)
        return mid, table if table is not None else round(_ceil_to(float(vol.bottom_mm(mid)), 0.1), 1)
    pick = Da[ok]
    D_a = float(axis_D) if axis_D is not None else 0.5 * float(pick.min() + pick.max())
    if table is not None:
        return D_a, float(table)
    z = float(_span_ok(vol, np.array([D_a]), R, _REFERENCE_ASPECT * R)[1][0])
    return D_a, round(_ceil_to(z, 0.1), 1)


# ---------------------------------------------------------------- stage resolution


def _missing(table) -> list[str]:
    return [f.name for f in dataclasses.fields(table) if getattr(table, f.name) is None]


def _stage_positions(rig: Rig) -> dict:
    """d0, the rotary axis and its table by the rule (the keys that are None)."""
    st = rig.stage
    vals = {f.name: getattr(st, f.name) for f in dataclasses.fields(st)}
    if vals["d0_mm"] is None:
        vals["d0_mm"] = -float(math.floor(float(hinge_geometry(rig).distance_from_column(0.0))))
    if vals["axis_mm"] is None or vals["rotary_table_z_mm"] is None:
        part = working_volume(rig, PART_MARGIN_PX, PART_MARGIN_PX)
        axis_D = None if vals["axis_mm"] is None else vals["axis_mm"] - vals["d0_mm"]
        D_a, vals["rotary_table_z_mm"] = _rotary_layout(part, axis_D, vals["rotary_table_z_mm"])
        if vals["axis_mm"] is None:
            vals["axis_mm"] = round(D_a + vals["d0_mm"], 1)
    return vals




def resolve_defaults(rig: Rig) -> tuple[Laser, Sensor, Stage, tuple[str, ...]]:
    """The rig's tables with every key that is None derived by the rule (module docstring).

    Order: d0; the rotary axis and its table; the laser's waist (at the axis);
    the calibration plate and its table (their margins depend on the stripe's
    width); the exposure (a white Lambertian surface on the axis).

    Parameters
    ----------
    rig : Rig
        A rig whose lens, laser and sensor geometry are valid; keys of
        :data:`scheimpflug.model.rig.DERIVED_KEYS` may be None.

    Returns
    -------
    laser, sensor, stage : Laser, Sensor, Stage
        The tables with numbers everywhere.
    derived : tuple of str
        The keys that were derived, as ``"table.key"``.
    """
    derived = tuple(f"{name}.{k}" for name in ("laser", "sensor", "stage")
                    for k in _missing(getattr(rig, name)))
    if not derived:
        return rig.laser, rig.sensor, rig.stage, ()
    vals = _stage_positions(rig)
    D_axis = vals["axis_mm"] - vals["d0_mm"]
    laser = rig.laser
    if laser.waist_distance_mm is None:
        laser = dataclasses.replace(laser, waist_distance_mm=round(float(laser_distance_mm(rig, D_axis)), 1))
    probe = _Probe(rig.lens, laser, rig.sensor, rig.stage)
    if vals["calibration_plate_height_mm"] is None or vals["calibration_table_z_mm"] is None:
        vals["calibration_plate_height_mm"], vals["calibration_table_z_mm"] = _plate_layout(
            calibration_volume(probe), vals["calibration_plate_height_mm"], vals["calibration_table_z_mm"])
    sensor = rig.sensor
    if sensor.exposure_ms is None:
        per_ms = lambertian_peak_electrons_per_ms(probe, D_axis)
        exposure = EXPOSURE_FULL_WELL_FRACTION * sensor.full_well_e / per_ms if per_ms > 0 else 1.0
        sensor = dataclasses.replace(sensor, exposure_ms=float(f"{exposure:.3g}"))
    return laser, sensor, dataclasses.replace(rig.stage, **vals), derived


@dataclass(frozen=True)
class _Probe:
    """The tables the closed forms read, before a Rig exists (its keys resolved)."""

    lens: object
    laser: object
    sensor: object
    stage: object


# ---------------------------------------------------------------- plans


@dataclass(frozen=True)
class CalibrationPlan:
    """Where the calibration plate goes, frame by frame.

    Parameters
    ----------
    plate_height_mm, table_z_mm : float
        The plate and its table [mm].
    start_mm, step_mm : float
        Stage coordinate of the first frame and the step [mm].
    steps : int
        Number of frames.
    both_edges_frames : int
        Frames that show both plate edges (with the margins of the rule).
    both_edges_stage_mm : tuple of float or None
        Stage interval where both edges are in view [mm], None if nowhere.
    view_stage_mm : tuple of float
        Stage interval the usable columns see [mm].
    note : str
        Why some frames show only one edge, or "".
    """

    plate_height_mm: float
    table_z_mm: float
    start_mm: float
    step_mm: float
    steps: int
    both_edges_frames: int
    both_edges_stage_mm: tuple[float, float] | None
    view_stage_mm: tuple[float, float]
    note: str = ""

    def positions_mm(self) -> np.ndarray:
        """Stage coordinates of the frames.

        Returns
        -------
        ndarray float64, shape (steps,)
            ``start + i·step`` [mm].
        """
        return self.start_mm + self.step_mm * np.arange(self.steps)

    def to_json_dict(self) -> dict:
        """The plan as a JSON-ready dict (the dataclass fields, intervals as lists).

        Returns
        -------
        dict
            One entry per attribute.
        """
        d = dataclasses.asdict(self)
        d["both_edges_stage_mm"] = list(self.both_edges_stage_mm) if self.both_edges_stage_mm else None
        d["view_stage_mm"] = list(self.view_stage_mm)
        return d


def calibration_plan(rig: Rig, plate_height_mm: float | None = None,
                     steps: int = CALIBRATION_STEPS) -> CalibrationPlan:
    """The default calibration frames of a rig (module docstring).

    Parameters
    ----------
    rig : Rig
        The rig (its stage keys resolved).
    plate_height_mm : float, optional
        Plate height [mm]; default the rig's ``calibration_plate_height_mm``.
    steps : int
        Number of frames (≥ 1).

    Returns
    -------
    CalibrationPlan
        The plan; ``note`` says why frames show one edge only, if any do.

    Raises
    ------
    ValueError
        If ``steps`` < 1 or the plate height is not > 0.
    """
    H = float(rig.stage.calibration_plate_height_mm if plate_height_mm is None else plate_height_mm)
    if steps < 1 or not H > 0:
        raise ValueError(f"a calibration plan needs steps >= 1 and a plate height > 0 (got {steps}, {H})")
    d0, z = rig.stage.d0_mm, rig.stage.calibration_table_z_mm
    vol = calibration_volume(rig)
    both = plate_interval_mm(vol, H, z)
    depth = vol.far_mm - vol.near_mm
    use = both if both and both[1] - both[0] >= 0.5 * depth else (vol.near_mm, vol.far_mm)
    step = (use[1] - use[0]) / (steps - 1) if steps > 1 else 0.0
    q = _step_quantum(step)
    step = round(_floor_to(step, q), 10) if steps > 1 else 0.0
    start = round(_ceil_to(use[0] + d0, q), 10) if steps > 1 else round(0.5 * (use[0] + use[1]) + d0, 3)
    while steps > 1 and start + (steps - 1) * step > use[1] + d0 and step > q:
        step = round(step - q, 10)  # rounding the start up must not push the last frame out
    D = start - d0 + step * np.arange(steps)
    n_both = int(np.sum((D >= both[0] - 1e-9) & (D <= both[1] + 1e-9))) if both else 0
    plan = CalibrationPlan(H, z, start, step, steps, n_both,
                           None if both is None else (both[0] + d0, both[1] + d0),
                           (vol.near_mm + d0, vol.far_mm + d0))
    return dataclasses.replace(plan, note=_plate_note(vol, plan, d0))


def _plate_note(vol: WorkingVolume, plan: CalibrationPlan, d0: float) -> str:
    if plan.both_edges_frames == plan.steps:
        return ""
    far = vol.far_mm
    where = (f"both edges are in view only for s in [{plan.both_edges_stage_mm[0]:.2f}, "
             f"{plan.both_edges_stage_mm[1]:.2f}] mm" if plan.both_edges_stage_mm else
             f"no stage position shows both edges (the view spans h = {float(vol.bottom_mm(far)):.2f} … "
             f"{float(vol.top_mm(far)):.2f} mm at its far end, the plate "
             f"{plan.table_z_mm:.2f} … {plan.table_z_mm + plan.plate_height_mm:.2f} mm)")
    return (f"{plan.both_edges_frames} of {plan.steps} frames show both edges of the "
            f"{plan.plate_height_mm:g} mm plate on a table at {plan.table_z_mm:g} mm: {where}; "
            "the others give the distance relation only")


@dataclass(frozen=True)
class RotaryPlan:
    """What fits on the rotary stage of a rig.

    Parameters
    ----------
    axis_mm : float
        Axis position in stage coordinates [mm].
    axis_distance_mm : float
        Its distance D from the object hinge [mm].
    table_z_mm : float
        Rotary table height [mm].
    in_view : bool
        Whether the axis lies in the depth range and the table at the axis is in view.
    part_radius_mm, part_height_mm : float
        The largest reference cylinder (height = 2 × radius) that stays in view
        at every angle [mm] (0 if none).
    max_radius_mm : float
        Largest radius of a flat part on the table that stays in view [mm].
    max_height_mm : float
        Largest height of a thin part on the axis that stays in view [mm].
    """

    axis_mm: float
    axis_distance_mm: float
    table_z_mm: float
    in_view: bool
    part_radius_mm: float
    part_height_mm: float
    max_radius_mm: float
    max_height_mm: float

    def to_json_dict(self) -> dict:
        """The plan as a JSON-ready dict.

        Returns
        -------
        dict
            One entry per attribute.
        """
        return dataclasses.asdict(self)


def rotary_plan(rig: Rig) -> RotaryPlan:
    """The largest parts that stay in view at every angle on a rig's rotary stage.

    Parameters
    ----------
    rig : Rig
        The rig (its stage keys resolved).

    Returns
    -------
    RotaryPlan
        Reference part, largest flat radius and thin height (module docstring),
        with a margin of :data:`PART_MARGIN_PX` pixels.
    """
    st = rig.stage
    vol = working_volume(rig, PART_MARGIN_PX, PART_MARGIN_PX)
    Da, z = st.axis_mm - st.d0_mm, st.rotary_table_z_mm
    r_max = max(0.0, min(Da - vol.near_mm, vol.far_mm - Da))
    in_view = bool(r_max > 0 and float(vol.bottom_mm(Da)) <= z < float(vol.top_mm(Da)))
    if not in_view:
        return RotaryPlan(st.axis_mm, Da, z, False, 0.0, 0.0, 0.0, 0.0)

    def ref(R):
        return bool(_span_ok(vol, Da, R, _REFERENCE_ASPECT * R, z)[0])

    def flat(R):
        return bool(_span_ok(vol, Da, R, 0.0, z)[0])

    R = _largest(ref, r_max)
    return RotaryPlan(st.axis_mm, Da, z, True, R, _REFERENCE_ASPECT * R, _largest(flat, r_max),
                      max(0.0, float(vol.top_mm(Da)) - z))


# ---------------------------------------------------------------- warnings


def stage_warnings(rig: Rig, plate_height_mm: float | None = None) -> list[str]:
    """Warnings for stage settings that put the axis, the rotary table or the plate out of view.

    Parameters
    ----------
    rig : Rig
        The rig (its stage keys resolved).
    plate_height_mm : float, optional
        Plate height [mm]; default the rig's ``calibration_plate_height_mm``.

    Returns
    -------
    list of str
        One line per problem, naming the ``[stage]`` key, its value and the
        range that would work; empty when everything is in view.
    """
    return [*axis_warnings(rig), *plate_warnings(rig, plate_height_mm)]


def axis_warnings(rig: Rig) -> list[str]:
    """Warnings for a rotary axis or rotary table out of view.

    Parameters
    ----------
    rig : Rig
        The rig (its stage keys resolved).

    Returns
    -------
    list of str
        At most one line naming ``[stage] axis_mm`` or ``rotary_table_z_mm``
        and the range that would work; none for an ordinary camera (``[sensor]
        image_distance_mm`` > 0), whose working volume the hinge rule does not give.
    """
    if rig.sensor.image_distance_mm > 0:
        return []
    st = rig.stage
    vol = working_volume(rig, PART_MARGIN_PX, PART_MARGIN_PX)
    Da = st.axis_mm - st.d0_mm
    u = float(hinge_geometry(rig).column_from_distance(Da)) if Da != 0 else math.nan
    lo, hi = vol.near_mm + st.d0_mm, vol.far_mm + st.d0_mm
    if not vol.near_mm < Da < vol.far_mm:
        return [f"[stage] axis_mm = {st.axis_mm:g} puts the rotary axis at D = {Da:.2f} mm from the "
                f"object hinge (column {u:.1f} of 0 … {rig.sensor.columns - 1}), outside the view: "
                f"axis_mm must lie in ({lo:.2f}, {hi:.2f}) mm with d0_mm = {st.d0_mm:g} "
                f"(leave axis_mm out to let the rule place it)"]
    bot, top = float(vol.bottom_mm(Da)), float(vol.top_mm(Da))
    if not bot <= st.rotary_table_z_mm < top:
        return [f"[stage] rotary_table_z_mm = {st.rotary_table_z_mm:g} is outside the view at the "
                f"rotary axis, which sees h = {bot:.2f} … {top:.2f} mm there: use a value in "
                f"[{bot:.2f}, {top:.2f}) (leave it out to let the rule place it)"]
    return []


def plate_warnings(rig: Rig, plate_height_mm: float | None = None) -> list[str]:
    """Warnings for a calibration plate whose edges are in view over less than half the depth.

    Parameters
    ----------
    rig : Rig
        The rig (its stage keys resolved).
    plate_height_mm : float, optional
        Plate height [mm]; default the rig's ``calibration_plate_height_mm``.

    Returns
    -------
    list of str
        At most one line naming ``[stage] calibration_table_z_mm`` and the
        plate height, and the table heights (or plate height) that would work;
        none for an ordinary camera (as :func:`axis_warnings`).
    """
    if rig.sensor.image_distance_mm > 0:
        return []
    st = rig.stage
    H = float(st.calibration_plate_height_mm if plate_height_mm is None else plate_height_mm)
    vol = calibration_volume(rig)
    both = plate_interval_mm(vol, H, st.calibration_table_z_mm)
    depth = vol.far_mm - vol.near_mm
    if both is not None and both[1] - both[0] >= 0.5 * depth:
        return []
    D = vol.grid()
    top, bot = vol.top_mm(D), vol.bottom_mm(D)
    seen = (f"both edges are in view only over {both[1] - both[0]:.1f} of the {depth:.1f} mm depth range"
            if both else "no stage position shows both edges")
    key = (f"[stage] calibration_table_z_mm = {st.calibration_table_z_mm:g} with a "
           f"{H:g} mm plate (calibration_plate_height_mm)")
    if float(np.max(top - bot)) < H:
        return [f"{key}: {seen}; the plate is taller than the view anywhere (at most "
                f"{float(np.max(top - bot)):.2f} mm with the edge margins): use a plate of at most "
                f"{float(np.min(top - bot)):.2f} mm to see both edges at every position"]
    best = _table_for_plate(vol, H, top, bot)
    span = plate_interval_mm(vol, H, best)
    return [f"{key}: {seen}; calibration_table_z_mm in [{float(bot.min()):.2f}, "
            f"{float(top.max()) - H:.2f}] shows both edges somewhere, {best:g} over "
            f"s = {span[0] + st.d0_mm:.2f} … {span[1] + st.d0_mm:.2f} mm"]

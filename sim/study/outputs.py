"""What a study measures per draw: closed-form design numbers, quality parameters, calibration errors.

One record layout for the rendered draws (:mod:`sim.study.draw`) and the
noise-free geometric evaluations (:mod:`sim.study.propagation`), so that the
Monte Carlo and the analytic propagation compare like with like.

Distances of a design's range (``near_mm``, ``far_mm``) are along the sheet
from the laser / Scheimpflug line (as ``scheimpflug design --near-mm``):
``L = D + f/cos φ`` with D from the object hinge.  Calibration constants are
converted to the full-size sensor (a binned pixel j is at ``k·j + (k − 1)/2``;
F² scales with k, C and d0 do not) and compared with the design's closed forms
(``err.*`` = calibrated − design).
"""

from __future__ import annotations

import math

from scheimpflug.model.design import design_report
from scheimpflug.model.hinge import hinge_geometry
from scheimpflug.model.rig import Rig

__all__ = ["CALIBRATION_KEYS", "OUTPUTS", "design_numbers", "measured_outputs", "output_label", "unit_of"]

#: Paper-form calibration constants compared with the design's closed forms.
CALIBRATION_KEYS = ("hinge_u_px", "hinge_v_px", "F2_px_mm", "d0_mm", "C_mm")
#: Every numeric output of a draw that the analysis treats, with its plain name.
OUTPUTS = {
    "SD_mm": "sphere-spacing error SD", "PF_mm": "probing error (form) PF", "PS_mm": "probing error (size) PS",
    "F_mm": "flatness error F", "field_rms_mm": "calibration field error (RMS)",
    "field_max_mm": "calibration field error (max)", "axis_error_mm": "rotary-axis error",
    "err.hinge_u_px": "error of the hinge column u_h", "err.hinge_v_px": "error of the hinge row v_h",
    "err.F2_px_mm": "error of F²", "err.d0_mm": "error of d0", "err.C_mm": "error of C",
    "part_rms_mm": "user part: RMS distance from its mesh",
}
_UNITS = (("_deg", "°"), ("_um", "µm"), ("_mm", "mm"), ("_px_mm", "px·mm"), ("_px", "px"), ("_urad", "µrad"),
          ("_mrad", "mrad"), ("_ppm", "ppm"), ("_percent", "%"), ("_nm", "nm"), ("_mw", "mW"), ("_ms", "ms"),
          ("_e", "e⁻"), ("_dn", "DN"), ("_w_m2", "W/m²"))


def unit_of(key: str) -> str:
    """The unit a key's name ends with (``roll_deg`` → ``°``), "" when it has none.

    Parameters
    ----------
    key : str
        A rig key or output name.

    Returns
    -------
    str
        The unit symbol.
    """
    for suffix, unit in sorted(_UNITS, key=lambda su: -len(su[0])):
        if key.endswith(suffix):
            return unit
    return ""


def output_label(name: str) -> str:
    """Plain name of an output (``SD_mm`` → ``sphere-spacing error SD``).

    Parameters
    ----------
    name : str
        Output name.

    Returns
    -------
    str
        The label, or the name itself.
    """
    return OUTPUTS.get(name, name)


def design_numbers(rig: Rig) -> dict:
    """Closed-form design numbers of a full-size rig (paper Eqs. 5, 11, 12; :func:`design_report`).

    Parameters
    ----------
    rig : Rig
        The design.

    Returns
    -------
    dict
        ``tilt_deg``, ``tan_beta``, ``hinge_u_px``, ``F2_px_mm``, ``C_mm``, ``near_mm`` and ``far_mm``
        (range along the sheet from the laser) [mm], ``depth_range_mm``,
        ``distance_resolution_center_mm``, ``height_resolution_center_mm``, ``height_range_near_mm``,
        ``height_range_far_mm`` [mm].
    """
    rep = design_report(rig)
    offset = rig.lens.focal_length_mm * math.hypot(1.0, rig.laser.tan_phi)    # f / cos φ
    near, far = rep["distance_range_mm"]
    keys = ("tilt_deg", "tan_beta", "F2_px_mm", "C_mm", "depth_range_mm", "distance_resolution_center_mm",
            "height_resolution_center_mm", "height_range_near_mm", "height_range_far_mm")
    return {**{k: float(rep[k]) for k in keys}, "hinge_u_px": float(rig.sensor.hinge_column),
            "near_mm": float(near + offset), "far_mm": float(far + offset)}


def _full_size(constants: dict, k: int) -> dict:
    c = (k - 1) / 2
    return {"hinge_u_px": k * constants["hinge_u_px"] + c, "hinge_v_px": k * constants["hinge_v_px"] + c,
            "F2_px_mm": k * constants["F2_px_mm"], "d0_mm": constants["d0_mm"], "C_mm": constants["C_mm"]}


def _number(x):
    return None if x is None or not math.isfinite(float(x)) else float(x)


def measured_outputs(result: dict, rig_b: Rig, nominal_b: Rig, binning: int) -> dict:
    """The flat outputs of one acceptance run (rendered or geometric) of an as-built rig.

    Parameters
    ----------
    result : dict
        :func:`sim.acceptance.run_acceptance` or :meth:`sim.study.geometric.GeometricTwin.evaluate`
        (``calibration.constants`` of the binned sensor; the field error when present).
    rig_b : Rig
        The rig as built, binned as the run used it (its stage positions: the axis).
    nominal_b : Rig
        The design, binned the same way: the closed forms the constants are compared with.
    binning : int
        The binning the run used [-].

    Returns
    -------
    dict
        The keys of :data:`OUTPUTS` (None where not measured) and ``cal.*``, the calibrated
        constants converted to the full-size sensor.
    """
    g = hinge_geometry(nominal_b)
    design = _full_size({"hinge_u_px": g.hinge_column, "hinge_v_px": g.axis_row, "F2_px_mm": g.F2_px_mm,
                         "d0_mm": nominal_b.stage.d0_mm, "C_mm": g.C_mm}, binning)
    cal = _full_size(result["calibration"]["constants"], binning)
    out = {k: _number(result.get(k)) for k in ("SD_mm", "PF_mm", "PS_mm", "F_mm", "field_rms_mm", "field_max_mm")}
    out["axis_error_mm"] = _number(result["axis_mm"] - rig_b.stage.axis_mm)
    out.update({f"cal.{k}": float(v) for k, v in cal.items()})
    out.update({f"err.{k}": float(cal[k] - design[k]) for k in CALIBRATION_KEYS})
    return out

"""The options of ``scheimpflug render target`` and the camera pass's rig keys (see :mod:`sim.target`).

``render target --pattern SPEC [--poses N | --on-table --step-deg D]`` photographs a
printed pattern; ``--flood-w-m2`` and ``--camera-spp`` set the rig's flood light and the
camera pass for every scenario (:mod:`sim.camera_pass`).
"""

from __future__ import annotations

import argparse

from scheimpflug.app.commands._common import integer, number
from scheimpflug.errors import ScheimpflugError

__all__ = ["TARGET_OPTIONS", "add_target_options", "camera_rig", "target_options"]

#: option → keyword of sim.target.target_scenario
TARGET_OPTIONS = {
    "pattern": "pattern", "poses": "poses", "on_table": "on_table", "tilt_deg": "tilt_deg",
    "roll_deg": "roll_deg", "off_sheet_mm": "off_sheet_mm", "depth_range_mm": "depth_range_mm",
    "height_range_mm": "height_range_mm", "lights": "lights", "laser_flood": "laser_flood",
    "flood_exposure_ms": "flood_exposure", "plate_mm": "plate_mm", "border_mm": "border_mm",
    "plate_thickness_mm": "thickness_mm", "bow_mm": "bow_mm", "plate_material": "plate_material",
}


def _pair(sep: str, unit: str):
    """An argparse ``type=``: two finite numbers 'A<sep>B'."""

    def parse(text: str) -> tuple[float, float]:
        parts = text.replace("×", "x").split(sep)
        try:
            a, b = (float(x) for x in parts)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r}: expected two numbers A{sep}B [{unit}]") from None
        return a, b

    parse.__name__ = "pair"
    return parse


def add_target_options(p: argparse.ArgumentParser) -> None:
    """Add the ``target`` scenario's options and the camera pass's to ``render``.

    Parameters
    ----------
    p : argparse.ArgumentParser
        The ``render`` parser.
    """
    g = p.add_argument_group("target (a printed pattern; sim/target.py)")
    g.add_argument("--pattern", metavar="SPEC",
                   help="chessboard:COLSxROWS:SQUARE_MM (inner corners), charuco:COLSxROWS:SQUARE_MM:MARKER_MM[:DICT] "
                        "(squares, OpenCV's board), circles:COLSxROWS:PITCH_MM[:DIAMETER_MM]")
    g.add_argument("--poses", type=int, help="hand-held poses (default 20)")
    g.add_argument("--on-table", action="store_true", default=None,
                   help="the pattern standing on the rotary table at k·--step-deg (angles where it is seen)")
    g.add_argument("--tilt-deg", type=number(0, 80, unit="deg"), help="tilt limit about both print axes (default 35)")
    g.add_argument("--roll-deg", type=number(0, 180, unit="deg"), help="in-plane turn limit (default 30)")
    g.add_argument("--off-sheet-mm", type=number(0, 1e4, unit="mm"),
                   help="largest offset of a pose from the sheet (default 5)")
    g.add_argument("--depth-range-mm", type=_pair(":", "mm"), metavar="LO:HI",
                   help="D range (from the object hinge, along the sheet) of the poses' centres (default: the view)")
    g.add_argument("--height-range-mm", type=_pair(":", "mm"), metavar="LO:HI",
                   help="height range of the poses' centres (default: the view)")
    g.add_argument("--lights", help="frames per pose: flood,laser (default both)")
    g.add_argument("--laser-flood", type=number(0, 1e3), help="flood level in laser frames, 0 = off (default 0)")
    g.add_argument("--room-light", type=number(0, 1e5, lo_open=True, unit="W/m²"), metavar="W_M2",
                   help="the set as users take it in a lit room: the flood light (the room's) at W_M2 in every "
                        "frame, the laser frames at the flood frames' exposure, so that each pose's flood frame is "
                        "its laser frame's laser-off frame (calibrate --laser-background)")
    g.add_argument("--flood-exposure-ms", type=number(0, 1e6, lo_open=True, unit="ms"),
                   help="exposure of the flood frames (default: white paper at half the full well)")
    g.add_argument("--plate-mm", type=_pair("x", "mm"), metavar="WxH", help="plate size (default: pattern + border)")
    g.add_argument("--border-mm", type=number(0, 1e4, unit="mm"), help="paper margin (default one square)")
    g.add_argument("--plate-thickness-mm", type=number(0, 1e3, lo_open=True, unit="mm"), help="default 3")
    g.add_argument("--bow-mm", type=number(-1e3, 1e3, unit="mm"),
                   help="bow of the print, + toward the camera (default 0)")
    g.add_argument("--plate-material", help="material of the plate (default white-plastic)")
    g.add_argument("--pose-from", metavar="FRAME[,FRAME...]",
                   help="the poses of real frames instead of drawn ones: the pattern found whole in each frame "
                        "(a dim laser-off frame is brightened ×2, ×4, ×8) and placed by --pose-calibration's camera "
                        "(solvePnP); the rig must be built from that calibration (rig from-calibration)")
    g.add_argument("--pose-calibration", metavar="CAL.json",
                   help="with --pose-from: the calibration (camera_matrix, dist_coeffs) whose camera frame is the "
                        "rig's instrument frame")
    g.add_argument("--pose-channel", default=None, metavar="r|g|b|gray",
                   help="with --pose-from: the channel of colour frames the pattern is found in (default gray)")
    g = p.add_argument_group("flood light and camera pass (every scenario)")
    g.add_argument("--flood-w-m2", type=number(0, 1e5, unit="W/m²"),
                   help="the flood light's irradiance at its aim point (rig key [environment] "
                        "flood_irradiance_w_m2; target default 20 when the rig has none)")
    g.add_argument("--background", choices=("none", "walls", "box"),
                   help="blocker, rotary: walls behind the table or a housing around it, fixed while it turns "
                        "(scenes/backgrounds.py; default none)")
    g.add_argument("--background-material", help="material of the background boards (default cardboard)")
    g.add_argument("--background-height-mm", type=number(0, 1e4, lo_open=True, unit="mm"),
                   help="height of the background above the table (default 250)")
    g.add_argument("--background-distance-mm", type=number(0, 1e5, lo_open=True, unit="mm"),
                   help="where the background stands beyond the axis (default: the view's far end, at most 150/0.9)")
    g.add_argument("--camera-spp", type=integer(0, 4096),
                   help="camera pass samples per pixel (rig key [twin] camera_spp; 0 = coarse ambient pass; "
                        "target default 16)")


def target_options(args) -> dict:
    """The target scenario's keyword options from the parsed arguments.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed ``render`` arguments.

    Returns
    -------
    dict
        Keywords of :func:`sim.target.target_scenario` (only those given).

    Raises
    ------
    ScheimpflugError
        Without ``--pattern``, with ``--on-table`` and ``--poses`` together, ``--on-table``
        without ``--step-deg``, or ``--room-light`` and another ``--flood-w-m2``.
    """
    if not args.pattern:
        raise ScheimpflugError("render target needs --pattern SPEC (e.g. chessboard:10x8:7)")
    if args.on_table and args.poses is not None:
        raise ScheimpflugError("--on-table and --poses exclude each other (the table's angles are the poses)")
    opts = {kw: getattr(args, opt) for opt, kw in TARGET_OPTIONS.items() if getattr(args, opt, None) is not None}
    if getattr(args, "room_light", None) is not None:
        if args.flood_w_m2 is not None and args.flood_w_m2 != args.room_light:
            raise ScheimpflugError(f"--room-light {args.room_light:g} and --flood-w-m2 {args.flood_w_m2:g}: the room's "
                                   "light is the flood light in room light; give one")
        opts["room_light"] = True
    if args.on_table:
        if args.step_deg is None:
            raise ScheimpflugError("--on-table needs --step-deg D (the table's step) [deg]")
        opts["step_deg"] = args.step_deg
    return opts


def camera_rig(args, rig, scenario: str):
    """The rig with ``--flood-w-m2`` / ``--camera-spp`` applied (and the target's defaults).

    Parameters
    ----------
    args : argparse.Namespace
        Parsed ``render`` arguments.
    rig : Rig
        The rig of ``--rig`` / ``--preset``.
    scenario : str
        The scenario name.

    Returns
    -------
    Rig
        The rig to render.
    """
    from sim.camera_pass import DEFAULT_SPP
    from sim.target import DEFAULT_FLOOD_W_M2

    flood = args.flood_w_m2 if getattr(args, "room_light", None) is None else args.room_light
    spp = args.camera_spp
    if scenario == "target":
        if flood is None and rig.environment.flood_irradiance_w_m2 == 0:
            flood = DEFAULT_FLOOD_W_M2
        if spp is None and rig.twin.camera_spp == 0:
            spp = DEFAULT_SPP
    if flood is not None:
        rig = rig.replace(environment={"flood_irradiance_w_m2": flood})
    if spp is not None:
        rig = rig.replace(twin={"camera_spp": spp})
    return rig

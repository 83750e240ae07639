"""The surface-model options of ``reconstruct`` (``--model``, sections, gap rule) and their output."""

from __future__ import annotations

import argparse

import numpy as np

from scheimpflug.app.commands._common import number

__all__ = ["add_model_options", "check_model_args", "make_model", "model_summary", "table_z_from_folder",
           "write_model"]

_METHODS = ("grid", "poisson")


def add_model_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("surface model (docs/howto/surface-model.md)")
    g.add_argument("--model", metavar="OUT.stl|OUT.ply",
                   help="also write a watertight triangle mesh of the scan (PLY: with per-face 'fill' "
                        "(0 measured, 1 gap, 2 table, 3 cap, 4 side) and 'body')")
    g.add_argument("--model-method", choices=_METHODS, default="grid",
                   help="grid: meshed on the scan's frame × row grid (default); poisson: Open3D's "
                        "screened Poisson reconstruction (optional: pip install '.[poisson]')")
    g.add_argument("--table-z-mm", type=number(-1e5, 1e5, unit="mm"), metavar="Z",
                   help="rotary-table plane in the part frame [mm] (default: the manifest rig's "
                        "stage.rotary_table_z_mm; none: every open bottom is capped)")
    g.add_argument("--max-step-mm", type=number(0, 1e5, lo_open=True, unit="mm"), metavar="D",
                   help="largest step between consecutive points of one profile [mm] "
                        "(default: 20 × the scan's median row-to-row step)")
    g.add_argument("--max-gap-deg", type=number(0, 360, lo_open=True, unit="deg"), metavar="A",
                   help="largest angle bridged between two profiles of a body [deg] (default 3 × the step)")
    g.add_argument("--section-z", type=number(-1e5, 1e5, unit="mm"), action="append", default=[], metavar="Z",
                   help="report the cross-section at this height [mm, part frame] (repeatable; "
                        "default: 5 heights evenly inside the model)")
    g.add_argument("--sections-plot", metavar="FILE.png", help="plot the sections and the area over height")


def check_model_args(args) -> None:
    """Fail before any work: a model file that cannot be written, or model options without --model."""
    from scheimpflug.errors import MeshError
    from scheimpflug.io.meshfile import check_mesh_destination

    if args.model:
        check_mesh_destination(args.model)
    elif args.section_z or args.sections_plot:
        raise MeshError("--section-z and --sections-plot need --model (the sections are cut from the model)")


def table_z_from_folder(args, folder) -> float | None:
    if args.table_z_mm is not None:
        return float(args.table_z_mm)
    stage = (folder.rig or {}).get("stage") if folder is not None else None
    z = stage.get("rotary_table_z_mm") if isinstance(stage, dict) else None
    ok = isinstance(z, (int, float)) and not isinstance(z, bool) and abs(z) <= 1e5   # NaN fails too
    return float(z) if ok else None


def make_model(cloud, args, table_z_mm):
    from scheimpflug.meshing import ModelSettings, model_from_cloud

    if args.model_method == "poisson":
        from scheimpflug.poisson import poisson_model

        return poisson_model(cloud)
    settings = ModelSettings(max_step_mm=args.max_step_mm, max_gap_deg=args.max_gap_deg, table_z_mm=table_z_mm)
    return model_from_cloud(cloud, settings)


def _default_sections(model) -> list[float]:
    z = model.vertices_mm[:, 2]
    lo, hi = float(z.min()), float(z.max())
    return [float(v) for v in np.round(lo + (hi - lo) * np.array([0.1, 0.3, 0.5, 0.7, 0.9]), 3)]


def model_summary(model, section_z) -> dict:
    """The ``reconstruct --json`` model fields (docs/reference/json.md)."""
    from scheimpflug.meshing import FILL_NAMES
    from scheimpflug.scoring import is_closed_mesh
    from scheimpflug.volumetry import solid_summary

    zs = list(section_z) or _default_sections(model)
    out = solid_summary(model.vertices_mm, model.faces, model.face_body, zs, measured=model.measured)
    counts = np.bincount(model.face_fill, minlength=len(FILL_NAMES))
    out.update(n_faces=int(len(model.faces)), n_vertices=int(len(model.vertices_mm)),
               n_bodies=model.n_bodies, watertight=bool(is_closed_mesh(model.faces)),  # bodies share no vertex
               faces_by_fill={name: int(c) for name, c in zip(FILL_NAMES, counts)},
               n_points_used=model.n_points_used, n_points_unused=model.n_points_unused)
    return out


def write_model(path, model, comment: str):
    from scheimpflug.io.meshfile import write_mesh

    return write_mesh(path, model.vertices_mm, model.faces,
                      {"fill": model.face_fill.astype(np.uint8), "body": model.face_body.astype(np.int32)},
                      comment=comment)


def print_model_line(summary: dict, path, file) -> None:
    print(f"model: {summary['n_faces']} faces, {summary['n_bodies']} bod{'y' if summary['n_bodies'] == 1 else 'ies'}"
          f"{', watertight' if summary['watertight'] else ', NOT watertight'}, volume "
          f"{summary['volume_mm3']:.6g} mm³ (from sections {summary['volume_from_sections_mm3']:.6g}), area "
          f"{summary['area_mm2']:.6g} mm², height {summary['height_mm']:.4g} mm, "
          f"{100 * summary['measured_area_share']:.1f} % of the area measured → {path}", file=file)

"""Sensitivity of the paper's figures to assumed values of the as-built rig (issue 11).

Not a preset change: the `paper-as-built` preset with one or more rig keys set, rendered
and measured as the paper measured its frames (whole pixels, `calibrate --detector paper
--method paper`), beside the paper's σ(F²) = 581 px·mm, σ(C) = 0.2014 mm and box-side
plane RMSE 0.1775 mm.  Two plans:

* ``--plan demo``: the demo's as-built column (27 full calibration frames, the blocker,
  the pile at 6°; ``scheimpflug.app.demo``'s own steps): σ(F²), σ(C), box RMSE, ring
  error and the endpoint lines' residuals;
* ``--plan calibration``: the 27 calibration frames alone (10 mm steps from −10 mm):
  σ(F²), σ(C) measured as the paper measured and by this pipeline.

Usage::

    python benchmarks/bench_aperture.py --set lens.f_number=22 --seeds 0 1
    python benchmarks/bench_aperture.py --set lens.f_number=22 --exposure-scaled --seeds 0 1
    python benchmarks/bench_aperture.py --plan calibration --set lens.f_number=22 laser.speckle_contrast=0
    python benchmarks/bench_aperture.py --plan calibration --set lens.focus_error_um=66

``--exposure-scaled`` multiplies the exposure by (N / 5.6)² so that a stopped-down lens
keeps the frame's brightness.  ``--set laser.waist_um=W`` keeps the laser's M² (the
divergence follows).  Frames go to a temporary folder (``--keep DIR`` keeps them).
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import tempfile
import time
from pathlib import Path

PAPER = {"F2_sigma_px_mm": 581.0, "C_sigma_mm": 0.2014, "box_rmse_mm": 0.1775}


def _value(text: str):
    try:
        return float(text)
    except ValueError:
        return {"true": True, "false": False}.get(text.lower(), text)


def as_built_with(changes: dict, exposure_scaled: bool):
    """The paper-as-built rig with ``{"table.key": value}`` set."""
    from scheimpflug.model.rig import load_preset

    base = load_preset("paper-as-built")
    tables: dict = {}
    for key, value in changes.items():
        table, name = key.split(".", 1)
        tables.setdefault(table, {})[name] = value
    laser = tables.get("laser", {})
    if "waist_um" in laser and "divergence_mrad" not in laser:       # the laser's M² kept
        lam_mm = base.laser.wavelength_nm * 1e-6
        m2 = base.laser.divergence_mrad * 1e-3 * math.pi * base.laser.waist_um * 1e-3 / lam_mm
        laser["divergence_mrad"] = m2 * lam_mm / (math.pi * laser["waist_um"] * 1e-3) * 1e3
    if exposure_scaled:
        n = tables.get("lens", {}).get("f_number", base.lens.f_number)
        tables.setdefault("sensor", {})["exposure_ms"] = base.sensor.exposure_ms * (n / base.lens.f_number) ** 2
    return base.replace(**tables)


def demo_column(rig, seed: int, out: Path) -> dict:
    """The demo's as-built column for ``rig``, measured as the paper measured."""
    from scheimpflug.app import demo

    plan = demo.as_built_plan_for(False)
    timer = demo._Timer()
    res = demo._experiments(rig, plan, out, seed, True, timer)
    p = demo._as_the_paper(rig, plan, out, res, True, timer)
    return {"F2_sigma_px_mm": p["calibration"]["F2_sigma_px_mm"], "C_sigma_mm": p["calibration"]["C_sigma_mm"],
            "box_rmse_mm": p["box_plane"]["rmse_mm"], "ring_mm": p["ring"]["mean_abs_error_mm"],
            "endpoint_residual_px": p["endpoint_lines"]["residual_px"]}


def calibration_only(rig, seed: int, out: Path) -> dict:
    """The 27 calibration frames alone: whole-pixel and sub-pixel σ(F²), σ(C)."""
    from scheimpflug.calibration import calibrate_folder
    from sim.writer import render_folder

    folder = out / "calibration"
    render_folder(rig, "calibration", folder, seed=seed, warn=lambda m: None, steps=27, step_mm=10.0,
                  start_mm=-10.0)
    paper = calibrate_folder(folder, method="paper", detector="paper").best
    ours = calibrate_folder(folder).best
    return {"F2_sigma_px_mm": paper.F2_sigma_px_mm, "C_sigma_mm": paper.C_sigma_mm,
            "pipeline_F2_sigma_px_mm": ours.F2_sigma_px_mm, "pipeline_C_sigma_mm": ours.C_sigma_mm}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--plan", choices=("demo", "calibration"), default="demo")
    ap.add_argument("--set", nargs="*", default=[], metavar="TABLE.KEY=VALUE", help="rig keys to change")
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--exposure-scaled", action="store_true", help="exposure × (N / 5.6)²")
    ap.add_argument("--keep", type=Path, help="keep the frames under this folder")
    args = ap.parse_args()
    changes = dict((k, _value(v)) for k, v in (s.split("=", 1) for s in args.set))
    rig = as_built_with(changes, args.exposure_scaled)
    run = demo_column if args.plan == "demo" else calibration_only
    for seed in args.seeds:
        tmp = Path(tempfile.mkdtemp(prefix="bench_aperture_"))
        out = (args.keep / f"seed{seed}") if args.keep else tmp
        t0 = time.perf_counter()
        try:
            got = run(rig, seed, out)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        ratios = {k: round(got[k] / v, 3) for k, v in PAPER.items() if k in got}
        print(json.dumps({"plan": args.plan, "set": changes, "exposure_ms": rig.sensor.exposure_ms, "seed": seed,
                          **{k: (round(v, 4) if isinstance(v, float) else v) for k, v in got.items()},
                          "ratio_to_paper": ratios, "seconds": round(time.perf_counter() - t0, 1)}), flush=True)


if __name__ == "__main__":
    main()

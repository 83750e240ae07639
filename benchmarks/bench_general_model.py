"""Paper form vs general model on twins with sensor roll and lens distortion (issue 14).

    python benchmarks/bench_general_model.py [--binning 1] [--out DIR]

Renders the calibration plate on four rigs (ideal paper rig; sensor roll 0.5°;
k1 = −0.05; both), calibrates every other frame with both forms and prints per
rig: the model `auto` picks and why, the validation error (stage coordinate of
every lit row of the held-out frames against the plate's stage reading) and the
whole-field calibration error (stage coordinate and height over a 40 × 40 pixel
grid against the twin's exact camera; height after removing the constant offset
of the height origin).  Truth never comes from either model.
"""

import argparse
import tempfile
from pathlib import Path

import numpy as np

RIGS = {"ideal": "", "roll 0.5°": "[sensor]\nroll_deg = 0.5\n", "k1 −0.05": "[lens]\nk1 = -0.05\n",
        "both": "[lens]\nk1 = -0.05\n[sensor]\nroll_deg = 0.5\n"}


def field_error(model, ff):
    from scheimpflug.model.camera import sheet_point_from_pixel
    from scheimpflug.model.hinge import hinge_geometry
    from scheimpflug.model.rig import rig_from_dict

    rig = rig_from_dict(ff.rig)
    u, v = np.meshgrid(np.linspace(0, ff.columns - 1, 40), np.linspace(0, ff.rows - 1, 40))
    D, h, _ = hinge_geometry(rig).sheet_from_rig(sheet_point_from_pixel(rig, np.stack([u, v], -1)))
    s_m, h_m = model.stage_from_pixel(u, v)
    ds, dh = s_m - D - rig.stage.d0_mm, h_m - h
    return float(np.sqrt(np.mean(ds ** 2))), float(np.sqrt(np.mean((dh - dh.mean()) ** 2))), float(dh.mean())


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--binning", type=int, default=1)
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    from scheimpflug.app.cli import main as cli
    from scheimpflug.calibration import calibrate_measurements, measure_plate_frame
    from scheimpflug.io.frames import open_frame_folder
    from scheimpflug.sheet_model import fit_sheet_models

    root = Path(args.out or tempfile.mkdtemp())
    print(f"binning {args.binning}; validation = held-out frames (stage), field = 40×40 grid vs exact camera")
    print(f"{'rig':10s} {'auto':8s} {'valid. paper':>13s} {'valid. gen.':>12s} {'field s paper':>14s} "
          f"{'field s gen.':>13s} {'field h paper':>14s} {'field h gen.':>13s}  [mm]")
    for name, text in RIGS.items():
        key = name.split()[0]
        (root / f"{key}.toml").write_text(text)
        cli(["render", "calibration", "--rig", str(root / f"{key}.toml"), "--binning", str(args.binning),
             "--truth-pixels", "none", "--quiet", "--out", str(root / key)])
        ff = open_frame_folder(root / key)
        ms = [measure_plate_frame(ff.read(i), r.stage_mm, saturation_dn=ff.saturation_dn(ff.read(i)))
              for i, r in enumerate(ff.frames)]
        cal, val = ms[0::2], ms[1::2]
        paper = calibrate_measurements([m for m in cal if m.top_px and m.bottom_px], columns=ff.columns,
                                       rows=ff.rows)
        rig = ff.rig
        _, _, gen, sel = fit_sheet_models(cal, paper, focal_length_mm=rig["lens"]["focal_length_mm"],
                                          pixel_pitch_um=rig["sensor"]["pixel_pitch_um"])
        vals = []
        for model in (paper.best, gen):
            e = np.concatenate([model.stage_from_pixel(m.u, m.rows.astype(float))[0] - m.stage_mm for m in val])
            vals.append(float(np.sqrt(np.mean(e ** 2))))
        fp, fg = field_error(paper.best, ff), field_error(gen, ff)
        print(f"{name:10s} {sel.chosen:8s} {vals[0]:13.4f} {vals[1]:12.4f} {fp[0]:14.4f} {fg[0]:13.4f} "
              f"{fp[1]:14.4f} {fg[1]:13.4f}")
        print(f"           {sel.reason}")


if __name__ == "__main__":
    main()

"""The twin of a FabScan-like scanner with its back walls beside a real FabScan frame: docs/fabscan_twin_vs_real.png.

    .venv/bin/python benchmarks/fabscan_figure.py [--real ../shared/realdata/fabscan/scan-2_1/20210213-230603_000.jpg]
        [--part pile] [--flood-w-m2 0.5] [--out docs/fabscan_twin_vs_real.png]

The twin: the rig of ``benchmarks/fabscan_like.toml`` (a Raspberry Pi camera and a red line laser,
assumed values), the part on the rotary table, ``--background walls`` (two boards meeting behind
the table, :mod:`scenes.backgrounds`), the flood light at ``--flood-w-m2`` and the room's
environment: one frame, the laser pass plus the camera pass (4 samples per pixel), the sensor's
noise, its 12-bit raw values.  The real frame: one of the FabScanPi's own frames (GPL-2.0, not in
this project: read from ``../shared/realdata``, the red channel of an 8-bit JPEG).  The twin's frame
is turned by 90° (its stripe runs along rows there, as the real camera is mounted), both are shown
with one display rule ((value − median) / (99.9th percentile − median), square root), side by side,
each 640 × 480.
"""

from __future__ import annotations

import argparse
import tomllib
from pathlib import Path

import cv2
import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
REAL = ROOT.parent / "shared" / "realdata" / "fabscan" / "scan-2_1" / "20210213-230603_000.jpg"


def _display(img: np.ndarray) -> np.ndarray:
    """(value − median) over (99.9th percentile − median), square root, 8 bit."""
    black = float(np.median(img))
    v = np.clip((img.astype(np.float64) - black) / max(np.percentile(img, 99.9) - black, 1.0), 0.0, 1.0)
    return (np.sqrt(v) * 255).astype(np.uint8)


def twin_frame(part: str, flood_w_m2: float, seed: int) -> np.ndarray:
    """One raw frame of the FabScan-like twin with its walls [DN] (rows, columns)."""
    from scheimpflug.model.rig import rig_from_dict
    from sim.scenarios import build_scenario
    from sim.sensor import SensorModel, apply_sensor, frame_rng
    from sim.writer import MitsubaTwin

    rig = rig_from_dict(tomllib.loads((HERE / "fabscan_like.toml").read_text()))
    rig = rig.replace(environment={"flood_irradiance_w_m2": flood_w_m2}, twin={"camera_spp": 4})
    sc = build_scenario("rotary", rig, seed=seed, part=part, step_deg=90.0, frames=1, background="walls",
                        truth_pixels_every=0)
    twin = MitsubaTwin(rig, sc.assembly, background=sc.background)
    electrons = twin.render(sc.frames[0])
    return apply_sensor(electrons, SensorModel.from_rig(rig), frame_rng(seed, 0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real", type=Path, default=REAL)
    ap.add_argument("--part", default="pile")
    ap.add_argument("--flood-w-m2", type=float, default=0.5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "fabscan_twin_vs_real.png")
    args = ap.parse_args()
    real = cv2.imread(str(args.real), cv2.IMREAD_COLOR)
    if real is None:
        raise SystemExit(f"cannot read the real frame {args.real} (../shared/realdata is not part of the project)")
    twin = twin_frame(args.part, args.flood_w_m2, args.seed)
    left = cv2.resize(_display(np.rot90(twin)), (640, 480), interpolation=cv2.INTER_AREA)
    right = cv2.resize(_display(real[..., 2]), (640, 480), interpolation=cv2.INTER_AREA)
    for img, text in ((left, "twin (walls, flood light)"), (right, "real (FabScanPi, scan-2_1)")):
        cv2.putText(img, text, (12, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.7, 255, 2, cv2.LINE_AA)
    side = np.concatenate([left, np.full((480, 8), 128, np.uint8), right], axis=1)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), side, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e3:.0f} kB)")


if __name__ == "__main__":
    main()

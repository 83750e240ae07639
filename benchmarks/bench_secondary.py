"""Wrong-peak choices of the stripe detectors under secondary light (issue 10, item 5).

Renders a rotary scan of a part with the twin's realistic light (``--bounces``,
subsurface scattering, speckle, sensor noise) into a temporary frame folder,
then runs every detector with every multi-peak rule on the frames and counts,
against the truth (``stripe_u``, ``secondary_u``;
:func:`scheimpflug.stripe.peak_choices`), how often a row's choice is right,
sits on a secondary peak, is otherwise wrong, or is missing.

    .venv/bin/python benchmarks/bench_secondary.py --part knurled-ring --frames 36 --step-deg 10
    .venv/bin/python benchmarks/bench_secondary.py --part pile --frames 36 --step-deg 10
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from scheimpflug.model.binning import binned_rig  # noqa: E402
from scheimpflug.model.rig import load_preset  # noqa: E402
from scheimpflug.stripe import MULTI_PEAK_RULES, PeakChoices, extract_stripes, peak_choices  # noqa: E402
from sim.writer import read_png, render_folder  # noqa: E402

METHODS = ("cog", "gaussian3", "blais-rioux")


def render(args, out: Path) -> list[tuple[np.ndarray, dict]]:
    rig = binned_rig(load_preset("paper"), args.binning).replace(
        twin={"bounces": args.bounces, "subsurface": not args.opaque},
        laser={"speckle_contrast": args.speckle})
    t0 = time.perf_counter()
    render_folder(rig, "rotary", out, seed=args.seed, part=args.part, step_deg=args.step_deg,
                  frames=args.frames, truth_pixels_every=0, warn=lambda m: None)
    print(f"rendered {args.frames} frames of {args.part} in {time.perf_counter() - t0:.1f} s "
          f"(bounces {args.bounces}, subsurface {not args.opaque}, speckle {args.speckle}, "
          f"binning {args.binning})")
    frames = []
    for i in range(args.frames):
        with np.load(out / "truth" / f"{i:05d}.npz") as z:
            frames.append((read_png(out / "frames" / f"{i:05d}.png"),
                           {k: z[k] for k in ("stripe_u", "secondary_u", "secondary_fraction")}))
    return frames


def table(frames, rules) -> None:
    rows = sum(int(np.isfinite(t["stripe_u"]).sum()) for _, t in frames)
    with_sec = sum(int((np.isfinite(t["secondary_u"]).any(1) & np.isfinite(t["stripe_u"])).sum())
                   for _, t in frames)
    print(f"{rows} rows with a true stripe, {with_sec} of them with a secondary peak "
          f"(≥ 2 % of the row's light)")
    print(f"{'method':12s} {'rule':10s} {'correct':>9s} {'secondary':>10s} {'other':>8s} "
          f"{'missed':>8s}   [% of rows with a true stripe]")
    for method in METHODS:
        for rule in rules:
            total = PeakChoices()
            for image, truth in frames:
                p = extract_stripes(image, method, multi_peak=rule, window_px=4)
                total = total + peak_choices(p, truth["stripe_u"], truth["secondary_u"])
            pct = [100.0 * x / max(total.rows, 1)
                   for x in (total.correct, total.secondary, total.other, total.missed)]
            print(f"{method:12s} {rule:10s} {pct[0]:8.2f}% {pct[1]:9.2f}% {pct[2]:7.2f}% "
                  f"{pct[3]:7.2f}%")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", default="knurled-ring")
    ap.add_argument("--frames", type=int, default=36)
    ap.add_argument("--step-deg", type=float, default=10.0)
    ap.add_argument("--bounces", type=int, default=3)
    ap.add_argument("--speckle", type=float, default=0.7)
    ap.add_argument("--opaque", action="store_true", help="no subsurface scattering")
    ap.add_argument("--binning", type=int, default=1)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--rules", nargs="*", default=list(MULTI_PEAK_RULES))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        frames = render(args, Path(tmp) / "scan")
        table(frames, args.rules)


if __name__ == "__main__":
    main()

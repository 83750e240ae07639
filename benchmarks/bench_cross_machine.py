"""What is reproducible across machines: the same frames rendered for this CPU and for an AVX2 one.

Bit-identity is promised only on one machine (same seed, same configuration): Dr.Jit compiles
its kernels for the CPU it runs on (AVX-512 here, AVX2 on many AMD EPYC and older Intel
machines), numba does the same, and OpenBLAS picks its kernels at load time, so floats may
differ in the last bits between machines.  This script measures how far, without a second
machine: it runs the same jobs twice in child processes, once as this machine and once
emulating an AVX2 machine (``SCHEIMPFLUG_LLVM_TARGET=avx2``, ``NUMBA_CPU_NAME=haswell``,
``OPENBLAS_CORETYPE=Haswell``), then compares

* the frames (16-bit DN): pixels that differ, the largest difference;
* the exact truth: the per-row stripe centre [px] and the per-pixel 3-D point [mm];
* the calibration constants and the axis the pipeline measures from those frames.

Jobs: the ideal paper rig (calibration, 27 plate positions, and the blocker) and the
realistic ``paper-as-built`` twin (3 bounces, subsurface, surface speckle; 9 calibration
frames), both on a 2 × 2 binned sensor to stay short.

Usage::

    python benchmarks/bench_cross_machine.py [--binning 2] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

AVX2_ENV = {"SCHEIMPFLUG_LLVM_TARGET": "avx2", "NUMBA_CPU_NAME": "haswell", "OPENBLAS_CORETYPE": "Haswell"}
JOBS = {  # name: (render arguments, calibrate?)
    "ideal-calibration": (["render", "calibration", "--preset", "paper"], True),
    "ideal-blocker": (["render", "blocker", "--preset", "paper"], False),
    "as-built-calibration": (["render", "calibration", "--preset", "paper-as-built", "--steps", "9"], True),
}


def _cli(args: list[str], env: dict) -> str:
    cmd = [sys.executable, "-m", "scheimpflug", *args]
    res = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if res.returncode != 0:
        raise SystemExit(f"{' '.join(args)} failed:\n{res.stderr[-2000:]}")
    return res.stdout


def _run(machine: str, root: Path, binning: int) -> float:
    env = dict(os.environ, **(AVX2_ENV if machine == "avx2" else {}))
    for var in AVX2_ENV if machine == "native" else ():
        env.pop(var, None)
    start = time.perf_counter()
    for name, (args, calibrate) in JOBS.items():
        out = root / machine / name
        _cli([*args, "--out", str(out), "--binning", str(binning), "--seed", "1", "--quiet"], env)
        if calibrate:
            cal = json.loads(_cli(["calibrate", str(out), "--json", "--quiet", "--out", str(out / "cal.json")],
                                  env))
            (out / "cal-result.json").write_text(json.dumps(cal))
    blocker = root / machine / "ideal-blocker"
    axis = _cli(["axis", str(blocker), "--calibration", str(root / machine / "ideal-calibration" / "cal.json"),
                 "--json"], env)
    (blocker / "axis-result.json").write_text(axis)
    return time.perf_counter() - start


def _png(path: Path) -> np.ndarray:
    import cv2

    return cv2.imread(str(path), cv2.IMREAD_UNCHANGED).astype(np.int64)


def _truth(path: Path) -> dict:
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def _compare_folder(a: Path, b: Path) -> dict:
    man = json.loads((a / "manifest.json").read_text())
    px_diff = px_total = 0
    dn_max = 0
    stripe_max = point_max = 0.0
    for entry in man["frames"]:
        fa, fb = _png(a / entry["file"]), _png(b / entry["file"])
        d = np.abs(fa - fb)
        px_diff, px_total, dn_max = px_diff + int((d > 0).sum()), px_total + d.size, max(dn_max, int(d.max()))
        if entry.get("truth"):
            ta, tb = _truth(a / entry["truth"]), _truth(b / entry["truth"])
            for key, acc in (("stripe_u", "stripe"), ("point_mm", "point")):
                if key in ta:
                    diff = np.nanmax(np.abs(ta[key].astype(np.float64) - tb[key].astype(np.float64)), initial=0.0)
                    if acc == "stripe":
                        stripe_max = max(stripe_max, float(diff))
                    else:
                        point_max = max(point_max, float(diff))
    return {"frames": len(man["frames"]), "pixels_differing": px_diff / px_total, "max_abs_dn": dn_max,
            "stripe_truth_max_abs_px": stripe_max, "point_truth_max_abs_mm": point_max}


def _relative(a: dict, b: dict, keys: tuple[str, ...]) -> dict:
    out = {}
    for k in keys:
        va, vb = np.asarray(a[k], dtype=np.float64), np.asarray(b[k], dtype=np.float64)
        out[k] = float(np.max(np.abs(va - vb) / np.maximum(np.abs(va), 1e-300)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--binning", type=int, default=2)
    ap.add_argument("--keep", type=Path, help="keep the frames in DIR")
    args = ap.parse_args()
    root = args.keep or Path(tempfile.mkdtemp(prefix="cross-machine-"))
    try:
        times = {m: _run(m, root, args.binning) for m in ("native", "avx2")}
        print(f"native and emulated AVX2 runs: {times['native']:.1f} s, {times['avx2']:.1f} s "
              f"(binning {args.binning})")
        keys = ("hinge_px", "F2_px_mm", "F2_sigma_px_mm", "d0_mm", "C_mm", "C_sigma_mm")
        for name, (_, calibrate) in JOBS.items():
            a, b = root / "native" / name, root / "avx2" / name
            print(f"{name}: {json.dumps(_compare_folder(a, b))}")
            if calibrate:
                ca, cb = (json.loads((p / "cal-result.json").read_text()) for p in (a, b))
                print(f"  calibration, largest relative difference: {json.dumps(_relative(ca, cb, keys))}")
        xa, xb = (json.loads((root / m / "ideal-blocker" / "axis-result.json").read_text()) for m in ("native", "avx2"))
        gap = abs(xa["axis_mm"] - xb["axis_mm"])
        print(f"  axis_mm: {xa['axis_mm']!r} vs {xb['axis_mm']!r} (difference {gap:.3g} mm)")
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()

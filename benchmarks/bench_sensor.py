"""Sensor model speed: expected electrons → 12-bit frame, full 1936 × 1216 paper frames.

    python benchmarks/bench_sensor.py [--frames 20] [--frame stripe|flood] [--threads N]
    PYTHONPATH=DIR python benchmarks/bench_sensor.py --frame flood   # another checkout's sensor

Both backends of sim.sensor.apply_sensor (Dr.Jit LLVM and numba) on the same
synthetic frame, measured in one run; prints ms per frame and the ratio.  Frames:
``stripe`` — ambient 0–4 e⁻ on 900 columns, nothing elsewhere, a 12 000 e⁻ stripe;
``flood`` — 2–4 e⁻ on every pixel (a flood-lit or ambient-lit view), the stripe too.
``--threads`` sizes Dr.Jit's pool and numba's threads (default: all cores).  With
``PYTHONPATH`` pointing at another checkout, ``sim.sensor`` comes from there (the
``apply_sensor`` interface is the same), so two checkouts can be compared by running
this script twice.
"""

import argparse
import os
import time

import numpy as np

import sim.sensor
from scheimpflug.model.rig import load_preset
from sim.sensor import SensorModel, apply_sensor, frame_rng


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--frame", choices=["stripe", "flood"], default="stripe")
    ap.add_argument("--threads", type=int, default=0, help="pool threads (0: all cores)")
    args = ap.parse_args()
    if args.threads:
        import drjit as dr
        import numba

        dr.set_thread_count(args.threads)
        numba.set_num_threads(args.threads)
    rig = load_preset("paper")
    model = SensorModel.from_rig(rig)
    rng = np.random.default_rng(1)
    shape = (rig.sensor.rows, rig.sensor.columns)
    if args.frame == "flood":
        lam = rng.uniform(2, 4, shape).astype(np.float32)
    else:
        lam = np.zeros(shape, np.float32)
        lam[:, :900] = rng.uniform(0, 4, (rig.sensor.rows, 900))
    lam[:, 500:506] = 12000.0
    print(f"sim.sensor from {os.path.dirname(os.path.dirname(sim.sensor.__file__))}; "
          f"{args.frame} frame, threads {args.threads or 'all'}")
    ms = {}
    for backend in ("drjit", "numba"):
        apply_sensor(lam, model, frame_rng(0, 0), backend=backend)  # compile
        t0 = time.perf_counter()
        for i in range(args.frames):
            apply_sensor(lam, model, frame_rng(0, i), backend=backend)
        ms[backend] = (time.perf_counter() - t0) / args.frames * 1e3
        print(f"{backend:6s}: {ms[backend]:6.1f} ms/frame ({lam.size / 1e6:.2f} Mpx)")
    print(f"numba / drjit: {ms['numba'] / ms['drjit']:.1f}×")


if __name__ == "__main__":
    main()

"""Sensor model speed: expected electrons → 12-bit frame, full 1936 × 1216 paper frames.

    python benchmarks/bench_sensor.py [--frames 20]

Both backends of sim.sensor.apply_sensor (Dr.Jit LLVM and numba) on the same
synthetic frame (ambient 0–4 e⁻ on most pixels, a 12 000 e⁻ stripe), measured
in one run; prints ms per frame and the ratio.
"""

import argparse
import time

import numpy as np

from scheimpflug.model.rig import load_preset
from sim.sensor import SensorModel, apply_sensor, frame_rng


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20)
    args = ap.parse_args()
    rig = load_preset("paper")
    model = SensorModel.from_rig(rig)
    rng = np.random.default_rng(1)
    lam = np.zeros((rig.sensor.rows, rig.sensor.columns), np.float32)
    lam[:, :900] = rng.uniform(0, 4, (rig.sensor.rows, 900))
    lam[:, 500:506] = 12000.0
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

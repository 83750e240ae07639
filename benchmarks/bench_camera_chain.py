"""The camera chain's speed: a 1640 × 1232 FabScan-like frame through the whole chain, JPEG written.

    python benchmarks/bench_camera_chain.py [--frames 20] [--threads 2] [--bloom 0.5]

The Raspberry Pi camera v2 preset (``[chain] preset = "raspberry_pi_v2"``: veiling glare,
BGGR mosaic, shot and read noise, bilinear demosaicing, BT.709 tone curve, 8 bits,
JPEG quality 95 at 4:2:0) on a synthetic frame like FabScan's ``scan-2_1`` laser
frames: a red stripe down the frame (Gaussian, σ = 1.5 px, 40 000 e⁻ at its peak:
saturated), an object lit by room light (300 e⁻) over half the frame and a dim
background (20 e⁻), the laser's and the room's light apart (as the camera pass gives
them).  Each frame: :func:`sim.chain.apply_chain` with its own seed, then
:func:`sim.chain.encode_frame` and the file written (``sim.writer.write_frame_file``:
temporary name, rename).  Prints each step's median time and the whole frame's median
and minimum over ``--frames`` frames (after one warm-up frame: kernels compiled, FFT
plans made).  ``--threads`` sizes Dr.Jit's pool, numba's threads and the FFT's workers.
For comparison, today's path on the same light (laser + room): :func:`sim.sensor.apply_sensor`
and the 16-bit grey PNG written (``sim.writer.write_frame_file`` with the sensor model).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from scheimpflug.model.rig import rig_from_dict
from sim.chain import ChainModel, encode_frame, expected_charge, process_raw, raw_frame
from sim.sensor import SensorModel, apply_sensor, frame_rng
from sim.writer import write_frame_file


def _rig(bloom: float):
    """The Pi camera's binned mode: 1640 × 1232, 2.24 µm binned pixels, 10-bit raw (assumed full well)."""
    return rig_from_dict({
        "lens": {"focal_length_mm": 3.04, "f_number": 2.0},
        "laser": {"wavelength_nm": 650.0, "scheimpflug_distance_mm": 150.0, "tan_phi": 0.2},
        "sensor": {"columns": 1640, "rows": 1232, "pixel_pitch_um": 2.24, "hinge_column": 1e5, "adc_bits": 10,
                   "dark_offset_dn": 64.0, "full_well_e": 16000.0, "read_noise_e": 4.0, "exposure_ms": 10.0},
        "chain": {"preset": "raspberry_pi_v2", "bloom_spill_fraction": bloom}})


def _light(shape, qe):
    rows, cols = shape
    u = np.arange(cols, dtype=np.float64)
    centre = 820.0 + 40.0 * np.sin(np.arange(rows) / 200.0)
    laser = 40000.0 * qe * np.exp(-0.5 * ((u[None, :] - centre[:, None]) / 1.5) ** 2)
    room = np.full(shape, 20.0 * qe)
    room[200:1100, 500:1300] = 300.0 * qe
    return laser.astype(np.float32), room.astype(np.float32)


def _timed(seconds: dict, key: str, fn, *args):
    t0 = time.perf_counter()
    out = fn(*args)
    seconds.setdefault(key, []).append(time.perf_counter() - t0)
    return out


def _frame(model, laser, room, i, path, seconds):
    t0 = time.perf_counter()
    charge = _timed(seconds, "glare + mosaic", expected_charge, laser, room, model)
    raw = _timed(seconds, "shot noise, bloom, read-out", raw_frame, charge, model, frame_rng(0, i))
    rgb = _timed(seconds, "demosaic + tone", process_raw, raw, model)
    _timed(seconds, "JPEG encode", encode_frame, rgb, model.chain)
    _timed(seconds, "JPEG encode + write", write_frame_file, path, rgb, model)
    seconds.setdefault("whole frame", []).append(time.perf_counter() - t0 - seconds["JPEG encode"][-1])


def _grey(rig, light, i, path, seconds):
    t0 = time.perf_counter()
    model = SensorModel.from_rig(rig)
    write_frame_file(path, apply_sensor(light, model, frame_rng(0, i)), model)
    seconds.setdefault("16-bit grey path (today)", []).append(time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--threads", type=int, default=2, help="threads of Dr.Jit, numba and the FFT")
    ap.add_argument("--bloom", type=float, default=0.0, help="[chain] bloom_spill_fraction")
    args = ap.parse_args()
    import drjit as dr
    import numba
    import scipy.fft

    dr.set_thread_count(args.threads)
    numba.set_num_threads(args.threads)
    rig = _rig(args.bloom)
    model = ChainModel.from_rig(rig)
    laser, room = _light((rig.sensor.rows, rig.sensor.columns), rig.sensor.quantum_efficiency)
    seconds: dict = {}
    with tempfile.TemporaryDirectory() as tmp, scipy.fft.set_workers(args.threads):
        path = Path(tmp) / "00000.jpg"
        _frame(model, laser, room, 0, path, {})                     # warm-up
        for i in range(args.frames):
            _frame(model, laser, room, i + 1, path, seconds)
        size = path.stat().st_size
        grey = Path(tmp) / "00000.png"
        for i in range(args.frames + 1):
            _grey(rig, laser + room, i, grey, seconds if i else {})
    print(f"camera chain, {rig.sensor.columns} × {rig.sensor.rows}, preset raspberry_pi_v2, bloom "
          f"{args.bloom}, {args.threads} threads, {os.cpu_count()} cores, {args.frames} frames; "
          f"JPEG {size / 1e3:.0f} kB")
    for key, values in seconds.items():
        if key != "JPEG encode":
            print(f"  {key:30s} median {np.median(values) * 1e3:6.1f} ms   min {np.min(values) * 1e3:6.1f} ms")


if __name__ == "__main__":
    main()

"""Surface speckle's coherent sums: the direct tap sums against a tile-wise FFT, same frames.

    python benchmarks/bench_speckle_fft.py [--frames 6] [--step-deg 11] [--threads 1] [--runs 3]

Issue 27 asked for the speckle "by FFT on the lit band".  This measures what that would
cost on the realistic twin's own frames: it renders ``--frames`` frames of the paper pile
(the ``paper`` preset with ``[twin] bounces = 3``, ``subsurface = true``,
``speckle_contrast`` 0.7, as ``bench_frame_loop.py --twin realistic``), captures the
arguments of the speckle's two numba stages as :mod:`sim.speckle` calls them — the
scatterers' deposit (``_deposit_base``) and the coherent sums with the pixel means
(``_pixel_means``) — and replays them:

* ``deposit``: the scatterers' deposit on the tiles' fine grids (which an FFT does not
  replace: it produces the field that is convolved);
* ``direct``: the whole of ``_pixel_means`` — every lit tile's window gathered, the
  field convolved with the coherent PSF tap by tap at the lit pixels' fine samples only,
  the coverage where a window is not full, |U|² averaged per pixel;
* ``fft``: the same windows gathered (the same numba code), then **only** the field's
  convolution by FFT (``scipy.fft``, every tile's window zero-padded to a fast length,
  one transform of the kernel per kernel, multiplied, transformed back) and |U|² — no
  coverage, no pixel means, so a lower bound of what an FFT path would cost.

Before timing, the FFT's field is checked against the tap sums on one tile of every frame
(max |ΔU| printed; the two compute the same convolution).  ``--threads`` sets numba's
threads and ``scipy.fft``'s workers.  Prints ms per frame of each, the tiles, the fine
samples per pixel and the kernels' taps.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import sim.speckle as speckle  # noqa: E402
from scheimpflug.model.rig import load_preset  # noqa: E402
from sim.scenarios import rotary_scenario  # noqa: E402
from sim.writer import MitsubaTwin, build_manifest, generator_info, render_scenario  # noqa: E402


def capture(frames: int, step_deg: float) -> tuple[list, list]:
    """Render realistic pile frames; return the deposit's and the pixel means' arguments per frame."""
    rig = load_preset("paper").replace(twin={"bounces": 3, "subsurface": True},
                                       laser={"speckle_contrast": 0.7})
    scenario = rotary_scenario(rig, part="pile", step_deg=step_deg, frames=frames,
                               truth_pixels_every=0)
    twin = MitsubaTwin(rig, scenario.assembly)
    deposits, means = [], []

    def keep(store, fn, output: int):
        # inputs copied (the model reuses its scratch grids next frame); the output argument
        # only by reference: the replays take its shape for a fresh buffer
        def wrapped(*args):
            store.append([np.array(a, copy=True) if isinstance(a, np.ndarray) and i != output
                          else a for i, a in enumerate(args)])
            return fn(*args)
        return wrapped

    originals = speckle._deposit_base, speckle._pixel_means
    speckle._deposit_base = keep(deposits, originals[0], output=13)
    speckle._pixel_means = keep(means, originals[1], output=14)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            manifest = build_manifest(rig, scenario, 0, twin.spp, twin.variant, generator_info(),
                                      twin.describe())
            render_scenario(rig, scenario, os.path.join(tmp, "scan"), twin, manifest,
                            warn=lambda m: None, overlap=False)
    finally:
        speckle._deposit_base, speckle._pixel_means = originals
    return deposits, means


def share_cells(deposits: list) -> None:
    """Give every captured deposit a view of one cell buffer, reused as the model reuses its own."""
    size = max(d[13].size for d in deposits)
    buffer = np.empty(size, np.float64)
    for d in deposits:
        d[13] = buffer[:d[13].size].reshape(d[13].shape)


def run_deposit(args: list) -> None:
    """The scatterers' deposit into the shared cell buffer (the kernel zeroes each tile's cells)."""
    speckle._deposit_base(*args)


def run_direct(args: list) -> np.ndarray:
    """The whole of ``_pixel_means`` into a fresh speckle image."""
    args = list(args)
    args[14] = np.ones_like(args[14])
    speckle._pixel_means(*args)
    return args[14]


def _windows(args: list) -> np.ndarray:
    """Every tile's (size, size) complex window of the normalised field (numba, as the direct path)."""
    tiles, t, s, margin, _, slot, cells = args[:7]
    n, size = t * s, (t + 2 * margin) * s
    out = np.empty((len(tiles), size, size), np.complex128)
    wr, wi, wo = (np.empty((size, size)) for _ in range(3))
    for i, (tr, tc) in enumerate(tiles):
        speckle._window(slot, cells, n, (tr * t - margin) * s, (tc * t - margin) * s, size,
                        wr, wi, wo)
        out[i].real, out[i].imag = wr, wi
    return out


def fft_field(args: list, windows: np.ndarray, workers: int) -> np.ndarray:
    """U = h ⊛ field on every tile's own (T·s, T·s) samples by FFT; returns U (tiles, T·s, T·s)."""
    import scipy.fft as sfft

    tiles, t, s, margin = args[:4]
    offsets, v_re, v_im, ntaps, kidx = args[8], args[9], args[10], args[11], args[13]
    n, size = t * s, (t + 2 * margin) * s
    length = sfft.next_fast_len(size + 2 * int(np.abs(offsets).max()))
    spectrum = sfft.fft2(windows, s=(length, length), workers=workers)
    for k in np.unique(kidx):
        h = np.zeros((length, length), np.complex128)
        for q in range(ntaps[k]):
            h[offsets[k, q, 0] % length, offsets[k, q, 1] % length] += v_re[k, q] + 1j * v_im[k, q]
        spectrum[kidx == k] *= sfft.fft2(h)
    field = sfft.ifft2(spectrum, workers=workers)
    return field[:, margin * s:margin * s + n, margin * s:margin * s + n]


def check(args: list, workers: int) -> tuple[float, float]:
    """Max |ΔU| between the FFT and the tap sums over the middle tile's samples, and max |U| there."""
    tiles, t, s, margin, _, slot, cells = args[:7]
    offsets, v_re, v_im, ntaps, kidx = args[8], args[9], args[10], args[11], args[13]
    u = fft_field(args, _windows(args), workers)
    i = len(tiles) // 2
    n, size = t * s, (t + 2 * margin) * s
    wr, wi, wo = (np.empty((size, size)) for _ in range(3))
    full = speckle._window(slot, cells, n, (tiles[i, 0] * t - margin) * s,
                           (tiles[i, 1] * t - margin) * s, size, wr, wi, wo)
    ur, ui, cv = np.empty(n), np.empty(n), np.empty(n)
    k = kidx[i]
    err = 0.0
    for a in range(n):
        speckle._convolve_row(wr, wi, wo, a + margin * s, 0, n, margin * s, v_re[k], v_im[k],
                              offsets[k], ntaps[k], full, ur, ui, cv)
        err = max(err, float(np.abs(ur + 1j * ui - u[i, a]).max()))
    return err, float(np.abs(u[i]).max())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--step-deg", type=float, default=11.0)
    ap.add_argument("--threads", type=int, default=1, help="numba threads and FFT workers")
    ap.add_argument("--runs", type=int, default=3)
    opts = ap.parse_args()
    import numba

    deposits, means = capture(opts.frames, opts.step_deg)
    share_cells(deposits)
    numba.set_num_threads(opts.threads)
    first = means[0]
    print(f"{len(means)} realistic pile frames; tiles per frame "
          f"{min(len(m[0]) for m in means)}–{max(len(m[0]) for m in means)}, "
          f"{first[2]} × {first[2]} fine samples per pixel, margin {first[3]} px, kernel taps "
          f"{sorted(set(int(x) for m in means for x in m[11]))}; threads {opts.threads}")
    errors = [check(m, opts.threads) for m in means]
    print(f"FFT against tap sums, one tile per frame: max |ΔU| = {max(e for e, _ in errors):.1e} "
          f"(max |U| there {min(u for _, u in errors):.2f}–{max(u for _, u in errors):.2f})")
    for d, m in zip(deposits, means):       # compile and warm
        run_deposit(d)
        run_direct(m)
    for run in range(opts.runs):
        t_dep = t_dir = t_win = t_fft = 0.0
        for d, m in zip(deposits, means):
            t0 = time.perf_counter()
            run_deposit(d)
            t1 = time.perf_counter()
            run_direct(m)
            t2 = time.perf_counter()
            w = _windows(m)
            t3 = time.perf_counter()
            u = fft_field(m, w, opts.threads)
            np.square(u.real) + np.square(u.imag)
            t4 = time.perf_counter()
            t_dep, t_dir, t_win, t_fft = t_dep + t1 - t0, t_dir + t2 - t1, t_win + t3 - t2, \
                t_fft + t4 - t3
        k = 1e3 / len(means)
        print(f"run {run + 1}: deposit {k * t_dep:.1f} ms/frame; direct (whole pixel means) "
              f"{k * t_dir:.1f}; FFT windows {k * t_win:.1f} + field convolution {k * t_fft:.1f} "
              f"= {k * (t_win + t_fft):.1f} (FFT / direct {(t_win + t_fft) / t_dir:.1f}×)")


if __name__ == "__main__":
    main()

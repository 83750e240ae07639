"""Image sensor: expected photo-electrons → digital numbers (DN), seeded.

The renderer (:mod:`sim.render`) returns, per pixel, the noise-free *expected*
number of photo-electrons collected during the exposure (laser + ambient,
pixel area, exposure time, quantum efficiency already included).  This module
turns it into the value a camera would deliver, in this order:

0. exposure and photo response (error models, off by default): ``λ ← λ·j·g_i``
   with j = 1 + (exposure_jitter_percent/100)·z the frame's exposure factor
   (z a standard normal draw of the frame, :func:`exposure_scale`) and g_i the
   pixel's gain, 1 + (prnu_percent/100)·N(0, 1), clipped at 0;
1. shot noise: ``n_e ~ Poisson(λ)`` [e⁻];
2. dark signal and full-well saturation: ``n_e ← min(n_e + o_i, full_well_e)``
   (charge that does not fit in the pixel is lost), o_i the pixel's fixed
   dark offset: dsnu_e·N(0, 1) plus ``hot_pixel_e`` on a random
   ``hot_pixel_fraction`` of the pixels (0 when both are off);
3. read noise: ``+ σ_read · N(0, 1)`` [e⁻] (Gaussian, added at read-out);
4. conversion gain and black level: ``DN = dark_offset_dn + n_e / g``;
5. ADC: round to the nearest integer and clip to ``[0, 2**adc_bits − 1]``.

The conversion gain ``g`` [e⁻/DN] is ``sensor.gain_e_per_dn``; when that is 0
the gain is chosen so that a full pixel reads exactly full scale:
``g = full_well_e / (2**adc_bits − 1 − dark_offset_dn)``.  No part of the
linear range is then lost to the ADC clip, and a saturated pixel reads
``2**adc_bits − 1`` (read noise can only push it down).

Storage: frames are ``uint16`` arrays holding the *raw ADC value* (0 …
2**adc_bits − 1); they are **not** left-shifted to 16-bit full scale.  The
frame folder's manifest records ``adc_bits`` so readers know full scale.

Statistics (unsaturated, away from the clip):
``E[DN] = dark_offset_dn + λ/g`` and
``Var[DN] = (λ + σ_read²)/g² + 1/12`` (the last term is the rounding of a
distribution wide compared to 1 DN).

Fixed-pattern maps (g, o: :meth:`SensorModel.fixed_pattern`) belong to the
sensor, not the frame: they are drawn once from ``sensor.pattern_seed``
(``SeedSequence((pattern_seed, 0xF1ED, rows, columns))``: PRNU normals, DSNU
normals, hot-pixel uniforms, always all three in this order, so switching one
map on leaves the others unchanged) and are the same in every frame and run.

Random numbers: a :class:`numpy.random.Generator` on PCG64 seeded by
``numpy.random.SeedSequence((seed, frame_index, 0x5E45))`` gives one 64-bit key
per frame; every pixel then draws from its own counter-based SplitMix64
stream started from a hash of (key, pixel index): the shot noise by exact
Poisson sampling (CDF inversion below λ = 10, PTRS above), then the read
noise by the inverse normal CDF of the stream's next uniform.  Two backends
run these streams: Dr.Jit's LLVM kernel (vectorised, the default when
usable) and a parallel numba kernel.  They draw the same shot-noise counts —
the same uniforms through the same float64 arithmetic — and differ only in
the read noise's quantile (single-precision ``erfinv`` in Dr.Jit, Wichura's
AS241 in double precision in numba), by a few 1e-7 e⁻ — a pixel's DN can
differ by 1 where the sum falls within that of a rounding boundary.  The
same ``(seed, frame_index)`` always gives bit-identical frames, independent of
how many frames were rendered before and of the number of threads.

The camera chain (:mod:`sim.chain`, ``[chain]`` on) runs the same steps in two
halves around its blooming: :func:`poisson_counts` (the shot noise, from the
frame's key), then :func:`read_out` (read noise from each pixel's stream under a
second key of the frame's generator, analogue gain, black level, ADC).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numba
import numpy as np

from scheimpflug.model.rig import Rig, Sensor

__all__ = [
    "SensorModel",
    "apply_sensor",
    "conversion_gain_e_per_dn",
    "exposure_scale",
    "fixed_pattern_maps",
    "frame_rng",
    "full_scale_dn",
    "poisson_counts",
    "read_out",
]

_STREAM_SENSOR = 0x5E45  # distinguishes the sensor-noise stream from other seeded streams


def frame_rng(seed: int, frame_index: int, stream: int = _STREAM_SENSOR) -> np.random.Generator:
    """The seeded random generator of one frame.

    Parameters
    ----------
    seed : int
        Run seed (≥ 0).
    frame_index : int
        Frame index (≥ 0).
    stream : int, default 0x5E45
        Stream tag that separates independent uses of the same (seed, frame);
        the default is the sensor-noise stream.

    Returns
    -------
    numpy.random.Generator
        PCG64 seeded by ``SeedSequence((seed, frame_index, stream))``: the same
        arguments always give the same stream, whatever was drawn before.

    Raises
    ------
    ValueError
        When ``seed`` or ``frame_index`` is negative.
    """
    if seed < 0 or frame_index < 0:
        raise ValueError(f"seed and frame_index must be >= 0, got {seed}, {frame_index}")
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence((int(seed), int(frame_index),
                                                                       int(stream)))))


#: below this mean a count comes from inverting the Poisson CDF with one uniform (exact,
#: cost ∝ λ + 1); at and above it from PTRS transformed rejection (Hörmann 1993, the
#: algorithm of numpy's Generator.poisson for λ ≥ 10) with two uniforms.
_PTRS_LAMBDA = 10.0
_MAX_COUNT = 200                                   # inversion cap (P(X ≥ 200 | λ < 10) < 1e-150)
_INV_K = 1.0 / np.arange(1, _MAX_COUNT + 1, dtype=np.float64)   # 1/k: multiply, not divide


def _invert_poisson_numpy(lam, u, out, inv_k=_INV_K) -> None:
    """Reference of the kernel's inversion branch (same arithmetic), λ < _PTRS_LAMBDA."""
    lam = np.asarray(lam, dtype=np.float64)
    p = np.exp(-lam)
    cdf = p.copy()
    k = np.zeros(lam.shape, dtype=np.int64)
    active = u > cdf
    while active.any():
        idx = np.flatnonzero(active)
        p[idx] *= lam[idx] * inv_k[k[idx]]
        k[idx] += 1
        cdf[idx] += p[idx]
        active[idx] = (u[idx] > cdf[idx]) & (k[idx] < _MAX_COUNT)
    out[...] = k


@numba.njit(cache=True, nogil=True)
def _ptrs_once(lam, u, v):  # pragma: no cover - compiled
    """One PTRS trial (Hörmann 1993, as numpy's random_poisson_ptrs): count, or −1 if rejected."""
    b = 0.931 + 2.53 * math.sqrt(lam)
    a = -0.059 + 0.02483 * b
    vr = 0.9277 - 3.6224 / (b - 2.0)
    uu = u - 0.5
    us = 0.5 - abs(uu)
    k = math.floor((2.0 * a / us + b) * uu + lam + 0.43)
    if us >= 0.07 and v <= vr:                     # squeeze: accepted without logarithms
        return k
    if k < 0 or (us < 0.013 and v > us):
        return -1.0
    invalpha = 1.1239 + 1.1328 / (b - 3.4)
    if math.log(v) + math.log(invalpha) - math.log(a / (us * us) + b) \
            <= -lam + k * math.log(lam) - math.lgamma(k + 1.0):
        return k
    return -1.0


@numba.njit(inline="always")
def _invert_one(mean, u, inv_k):  # pragma: no cover - compiled
    """min{k : F(k; mean) ≥ u}: the Poisson CDF inverted by summing the pmf."""
    p = math.exp(-mean)
    cdf = p
    k = 0
    while u > cdf and k < _MAX_COUNT:
        p *= mean * inv_k[k]
        k += 1
        cdf += p
    return k


@numba.njit(parallel=True, cache=True, nogil=True)
def _inversion_kernel(lam, u, out, inv_k, ptrs_lambda):  # pragma: no cover - compiled
    """out[i] = min{k : F(k; λ_i) ≥ u[i]} for λ_i < ptrs_lambda, −1 (left to PTRS) otherwise."""
    for i in numba.prange(lam.shape[0]):
        mean = np.float64(lam[i])
        out[i] = -1.0 if mean >= ptrs_lambda else _invert_one(mean, u[i], inv_k)


# ---------------------------------------------------------------- counter-based random numbers
# Every pixel draws from its own SplitMix64 stream, started from a hash of (frame key,
# pixel index): the kernels run fully parallel, need no pre-generated uniform arrays, and
# the result depends only on the key — never on the thread count or scheduling.

_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_STREAM = np.uint64(0xD1B54A32D192ED03)
_U53 = 1.0 / 9007199254740992.0            # 2⁻⁵³: a 53-bit integer → [0, 1)


@numba.njit(inline="always")
def _mix64(z):  # pragma: no cover - compiled
    """SplitMix64 finaliser (Steele, Lea & Flood 2014): a bijective 64-bit hash."""
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


@numba.njit(inline="always")
def _next_uniform(state):  # pragma: no cover - compiled
    """Advance a SplitMix64 state; return (state, u) with u uniform in (0, 1)."""
    state = state + _GAMMA
    u = (np.float64(_mix64(state) >> np.uint64(11)) + 0.5) * _U53
    return state, u


@numba.njit(inline="always")
def _pixel_state(key, i):  # pragma: no cover - compiled
    return _mix64(key ^ _mix64(np.uint64(i) * _STREAM + _GAMMA))


@numba.njit(inline="always")
def _poisson_one(mean, state, inv_k, ptrs_lambda):  # pragma: no cover - compiled
    """One Poisson(mean) count (exact): CDF inversion below ptrs_lambda, PTRS above."""
    if mean < ptrs_lambda:
        state, u = _next_uniform(state)
        return np.float64(_invert_one(mean, u, inv_k)), state
    while True:
        state, u = _next_uniform(state)
        state, v = _next_uniform(state)
        k = _ptrs_once(mean, u, v)
        if k >= 0:
            return k, state


# Wichura's AS241 (PPND16): the standard normal quantile to ≈ 1e-16 relative, with no
# transcendental function in the central 85 % (M. J. Wichura, Appl. Statist. 37, 1988).
_A = (3.3871328727963666080e0, 1.3314166789178437745e+2, 1.9715909503065514427e+3,
      1.3731693765509461125e+4, 4.5921953931549871457e+4, 6.7265770927008700853e+4,
      3.3430575583588128105e+4, 2.5090809287301226727e+3)
_B = (1.0, 4.2313330701600911252e+1, 6.8718700749205790830e+2, 5.3941960214247511077e+3,
      2.1213794301586595867e+4, 3.9307895800092710610e+4, 2.8729085735721942674e+4,
      5.2264952788528545610e+3)
_C = (1.42343711074968357734e0, 4.63033784615654529590e0, 5.76949722146069140550e0,
      3.64784832476320460504e0, 1.27045825245236838258e0, 2.41780725177450611770e-1,
      2.27238449892691845833e-2, 7.74545014278341407640e-4)
_D = (1.0, 2.05319162663775882187e0, 1.67638483018380384940e0, 6.89767334985100004550e-1,
      1.48103976427480074590e-1, 1.51986665636164571966e-2, 5.47593808499534494600e-4,
      1.05075007164441684324e-9)
_E = (6.65790464350110377720e0, 5.46378491116411436990e0, 1.78482653991729133580e0,
      2.96560571828504891230e-1, 2.65321895265761230930e-2, 1.24266094738807843860e-3,
      2.71155556874348757815e-5, 2.01033439929228813265e-7)
_F = (1.0, 5.99832206555887937690e-1, 1.36929880922735805310e-1, 1.48753612908506148525e-2,
      7.86869131145613259100e-4, 1.84631831751005468180e-5, 1.42151175831644588870e-7,
      2.04426310338993978564e-15)


@numba.njit(inline="always")
def _poly7(c, x):  # pragma: no cover - compiled
    return (((((((c[7] * x + c[6]) * x + c[5]) * x + c[4]) * x + c[3]) * x + c[2]) * x + c[1]) * x
            + c[0])


@numba.njit(inline="always")
def _normal_quantile(p):  # pragma: no cover - compiled
    """Φ⁻¹(p) for p in (0, 1) (AS241)."""
    q = p - 0.5
    if abs(q) <= 0.425:
        r = 0.180625 - q * q
        return q * _poly7(_A, r) / _poly7(_B, r)
    r = math.sqrt(-math.log(p if q < 0.0 else 1.0 - p))
    if r <= 5.0:
        z = _poly7(_C, r - 1.6) / _poly7(_D, r - 1.6)
    else:
        z = _poly7(_E, r - 5.0) / _poly7(_F, r - 5.0)
    return -z if q < 0.0 else z


@numba.njit(parallel=True, cache=True, nogil=True)
def _poisson_kernel(lam, key, inv_k, ptrs_lambda, out):  # pragma: no cover - compiled
    for i in numba.prange(lam.shape[0]):
        state = _pixel_state(key, i)
        out[i], state = _poisson_one(np.float64(lam[i]), state, inv_k, ptrs_lambda)


@numba.njit(parallel=True, cache=True, nogil=True)
def _sensor_kernel(lam, key, inv_k, ptrs_lambda, full_well, read_noise, inv_gain, offset,
                   full_scale, out, dark):  # pragma: no cover - compiled
    """Shot noise, dark offset, full well, read noise (inverse normal CDF), gain, offset and ADC.

    ``dark`` is the per-pixel dark offset [e⁻], or an empty array for none.
    """
    has_dark = dark.shape[0] > 0
    for i in numba.prange(lam.shape[0]):
        state = _pixel_state(key, i)
        n, state = _poisson_one(np.float64(lam[i]), state, inv_k, ptrs_lambda)
        if has_dark:
            n = n + np.float64(dark[i])
        e = min(n, full_well)
        if read_noise > 0.0:
            state, u = _next_uniform(state)
            e += read_noise * _normal_quantile(u)
        dn = np.rint(e * inv_gain + offset)
        out[i] = np.uint16(min(max(dn, 0.0), full_scale))


def _frame_key(rng: np.random.Generator) -> np.uint64:
    """One 64-bit key per frame from the frame's generator."""
    return np.uint64(rng.integers(0, 2**63, dtype=np.int64)) ^ np.uint64(0x5DEECE66D)


# ---------------------------------------------------------------- Dr.Jit (LLVM, SIMD) backend
# The same model and the same per-pixel SplitMix64 streams as the numba kernels, vectorised
# by Dr.Jit's LLVM backend: the shot-noise counts of the two backends are the same numbers
# (the same uniforms, the same float64 arithmetic); only the read noise's quantile differs
# in its last bits (single-precision erfinv here, AS241 in numba).
#
# Speed: the CDF inversion's first _UNROLL + 1 terms are summed without a loop (a packet of
# lanes otherwise iterates as often as its largest count, each step a float64 division);
# the rare lanes whose count exceeds _UNROLL finish in a symbolic loop.

_UNROLL = 8   # λ ≈ 3 e⁻ (a dark frame's ambient): P(X > 8) = 0.4 %


def _drjit_llvm():
    """The ``drjit.llvm`` module when Dr.Jit's LLVM backend is usable, else None."""
    global _DR
    if _DR is None:
        try:
            from .variant import select_variant

            if not select_variant().startswith("llvm"):
                raise ImportError("no LLVM variant")
            import drjit.llvm as llvm

            _DR = llvm
        except Exception:  # noqa: BLE001 - any failure means: use numba
            _DR = False
    return _DR or None


_DR = None


def _dr_mix64(llvm, z):
    """:func:`_mix64` on Dr.Jit UInt64 lanes."""
    z = (z ^ (z >> 30)) * llvm.UInt64(int(_M1))
    z = (z ^ (z >> 27)) * llvm.UInt64(int(_M2))
    return z ^ (z >> 31)


def _dr_pixel_states(llvm, n: int, key: np.uint64):
    """:func:`_pixel_state` of pixels 0 … n − 1 (UInt64), the frame key passed opaque."""
    import drjit as dr

    U64 = llvm.UInt64
    index_hash = _dr_mix64(llvm, dr.arange(U64, n) * U64(int(_STREAM)) + U64(int(_GAMMA)))
    return _dr_mix64(llvm, dr.opaque(U64, int(key)) ^ index_hash)


def _dr_next_uniform(llvm, state):
    """:func:`_next_uniform` on lanes: (advanced state, Float64 uniform in (0, 1))."""
    state = state + llvm.UInt64(int(_GAMMA))
    u = (llvm.Float64(_dr_mix64(llvm, state) >> 11) + 0.5) * _U53
    return state, u


def _dr_invert_poisson(llvm, lam, u):
    """min{k : F(k; λ) ≥ u} (Float64) for λ < _PTRS_LAMBDA, as :func:`_invert_one`.

    The same float64 operations in the same order as the numba kernel and
    :func:`_invert_poisson_numpy`; lanes with λ ≥ _PTRS_LAMBDA hold a meaningless value.
    """
    import drjit as dr

    F64 = llvm.Float64
    one, zero = F64(1.0), F64(0.0)

    def unrolled(k, p, cdf, go):
        p = dr.exp(-lam)
        cdf = F64(p)
        k = dr.select(u > cdf, one, zero)      # k = #{j ≤ K : u > F(j)}, F increasing in j
        for j in range(1, _UNROLL + 1):
            p = p * (lam * (1.0 / j))
            cdf = cdf + p
            k = k + dr.select(u > cdf, one, zero)
        return k, p, cdf, go & False

    # one pass, in a loop so that packets of dark pixels (λ = 0: count 0) skip it
    k, p, cdf, _ = dr.while_loop(state=(F64(0.0), F64(1.0), F64(1.0), lam > 0.0),
                                 cond=lambda k, p, cdf, go: go, body=unrolled)
    more = (k > _UNROLL) & (lam < _PTRS_LAMBDA)    # u > F(K): go on from term K

    def cond(k, p, cdf):
        return more & (u > cdf) & (k < float(_MAX_COUNT))

    def body(k, p, cdf):
        k1 = k + 1.0
        p = p * (lam * (1.0 / k1))
        return k1, p, cdf + p

    k, _, _ = dr.while_loop(state=(dr.select(more, F64(_UNROLL), k), p, cdf), cond=cond,
                            body=body)
    return k


def _dr_poisson(llvm, lam, state):
    """Exact Poisson counts (Float64) of means ``lam`` (Float64), as :func:`_poisson_one`.

    Inversion below _PTRS_LAMBDA, PTRS (as :func:`_ptrs_once`) above; returns the counts
    and each lane's advanced stream ``state`` (UInt64).
    """
    import drjit as dr

    small = lam < _PTRS_LAMBDA
    drawn, u = _dr_next_uniform(llvm, state)
    k = _dr_invert_poisson(llvm, lam, u)
    b = 0.931 + 2.53 * dr.sqrt(lam)
    a = -0.059 + 0.02483 * b
    vr = 0.9277 - 3.6224 / (b - 2.0)
    log_invalpha = dr.log(1.1239 + 1.1328 / (b - 3.4))
    loglam = dr.log(lam)

    def body(s, k, done):
        s, uu = _dr_next_uniform(llvm, s)
        s, vv = _dr_next_uniform(llvm, s)
        uu = uu - 0.5
        us = 0.5 - dr.abs(uu)
        kk = dr.floor((2.0 * a / us + b) * uu + lam + 0.43)
        quick = (us >= 0.07) & (vv <= vr)
        reject = (kk < 0.0) | ((us < 0.013) & (vv > us))
        slow = dr.log(vv) + log_invalpha - dr.log(a / (us * us) + b) <= \
            -lam + kk * loglam - dr.lgamma(kk + 1.0)
        accept = ~done & (quick | (~reject & slow))
        return s, dr.select(accept, kk, k), done | accept

    def cond(s, k, done):
        return ~done

    s, k, _ = dr.while_loop(state=(dr.select(small, drawn, state), k, small), cond=cond, body=body)
    return k, s


def _dr_standard_normal(llvm, u):
    """Φ⁻¹(u) (Float64) of uniforms ``u`` (Float64) in (0, 1), in single precision.

    ``u`` is rounded to float32 and kept in [2⁻²⁵, 1 − 2⁻²⁴] (|z| ≤ 5.5): a uniform that
    rounds to 0 or 1 would give erfinv(∓1) = ∓inf and an out-of-range pixel.
    """
    import drjit as dr

    u32 = dr.clip(llvm.Float(u), 2.0 ** -25, 1.0 - 2.0 ** -24)
    return llvm.Float64(dr.sqrt(2.0) * dr.erfinv(2.0 * u32 - 1.0))


def _dr_sensor(llvm, flat: np.ndarray, key: np.uint64, model: SensorModel,
               dark: np.ndarray | None = None) -> np.ndarray:
    """:func:`_sensor_kernel` on Dr.Jit lanes: (n,) float32 electrons → (n,) uint16 DN."""
    import drjit as dr

    lam = llvm.Float64(llvm.Float(flat))
    n, state = _dr_poisson(llvm, lam, _dr_pixel_states(llvm, flat.size, key))
    if dark is not None:
        n = n + llvm.Float64(llvm.Float(dark))
    e = dr.minimum(n, model.full_well_e)
    if model.read_noise_e > 0:
        _, u = _dr_next_uniform(llvm, state)
        e = e + model.read_noise_e * _dr_standard_normal(llvm, u)
    dn = dr.clip(dr.round(e * (1.0 / model.gain_e_per_dn) + model.dark_offset_dn), 0.0,
                 float(model.full_scale_dn))
    return llvm.UInt32(dn).numpy().astype(np.uint16)


def poisson_counts(lam, rng: np.random.Generator, backend: str | None = None) -> np.ndarray:
    """Poisson-distributed counts with given means.

    Parameters
    ----------
    lam : array_like
        Means λ ≥ 0, any shape (converted to float32) [-].
    rng : numpy.random.Generator
        Generator of the frame (:func:`frame_rng`); one 64-bit key is drawn from it.
    backend : {None, "drjit", "numba"}, optional
        Dr.Jit's LLVM kernel (the default when usable) or the numba kernel; both
        draw from the same per-pixel SplitMix64 streams and give the same counts
        (module docstring).

    Returns
    -------
    ndarray of float32
        Counts, same shape as ``lam``.

    Raises
    ------
    ValueError
        For an unknown ``backend``, or ``"drjit"`` when Dr.Jit's LLVM backend
        is not usable.

    Notes
    -----
    Exact in distribution.  λ < 10: CDF inversion with one uniform per pixel;
    λ ≥ 10: PTRS transformed rejection (Hörmann 1993, the algorithm of numpy's
    ``Generator.poisson``) with two fresh uniforms per trial until one is
    accepted.  The uniforms come from a counter-based stream per pixel keyed by
    one draw of ``rng``, so the kernel is parallel over pixels and deterministic
    whatever the thread count: same generator state → same counts.

    References
    ----------
    .. [1] W. Hörmann, "The transformed rejection method for generating Poisson
       random variables", Insurance: Mathematics and Economics 12, 1993.
    """
    flat = np.ascontiguousarray(lam, dtype=np.float32).reshape(-1)
    llvm = _backend(backend)
    if llvm is not None:
        states = _dr_pixel_states(llvm, flat.size, _frame_key(rng))
        counts, _ = _dr_poisson(llvm, llvm.Float64(llvm.Float(flat)), states)
        counts = counts.numpy().astype(np.float32)
        return counts.reshape(np.shape(lam))
    counts = np.empty(flat.size, dtype=np.float32)
    _poisson_kernel(flat, _frame_key(rng), _INV_K, _PTRS_LAMBDA, counts)
    return counts.reshape(np.shape(lam))


def full_scale_dn(sensor: Sensor) -> int:
    """Largest ADC code of a sensor.

    Parameters
    ----------
    sensor : Sensor
        The rig's sensor (``adc_bits``).

    Returns
    -------
    int
        2**adc_bits − 1 [DN].
    """
    return (1 << sensor.adc_bits) - 1


def conversion_gain_e_per_dn(sensor: Sensor) -> float:
    """Conversion gain of a sensor.

    Parameters
    ----------
    sensor : Sensor
        The rig's sensor (``gain_e_per_dn``, ``full_well_e``,
        ``dark_offset_dn``, ``adc_bits``).

    Returns
    -------
    float
        g [e⁻/DN]: ``sensor.gain_e_per_dn`` when > 0; when 0, the gain at which
        a full pixel reads exactly full scale,
        g = full_well_e / (2**adc_bits − 1 − dark_offset_dn).
    """
    if sensor.gain_e_per_dn > 0:
        return float(sensor.gain_e_per_dn)
    return sensor.full_well_e / (full_scale_dn(sensor) - sensor.dark_offset_dn)


def _pattern_draws(shape: tuple[int, int], seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence((int(seed), 0xF1ED,
                                                                      *map(int, shape)))))
    return rng.standard_normal(shape), rng.standard_normal(shape), rng.random(shape)


@functools.lru_cache(maxsize=4)
def fixed_pattern_maps(shape: tuple[int, int], prnu_percent: float, dsnu_e: float,
                       hot_pixel_fraction: float, hot_pixel_e: float,
                       pattern_seed: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The fixed-pattern maps of one physical sensor (module docstring).

    Parameters
    ----------
    shape : tuple of int
        ``(rows, columns)`` [px].
    prnu_percent : float
        RMS of the pixel gain about 1 [%].
    dsnu_e : float
        RMS of the pixel dark offset [e⁻].
    hot_pixel_fraction : float
        Fraction of hot pixels [-].
    hot_pixel_e : float
        Extra dark signal of a hot pixel [e⁻].
    pattern_seed : int
        Seed of the maps (the sensor's identity) [-].

    Returns
    -------
    gain : (rows, columns) float32 or None
        1 + (prnu_percent/100)·N(0, 1), clipped at 0 [-]; None when PRNU is 0.
    dark_e : (rows, columns) float32 or None
        dsnu_e·N(0, 1) + hot_pixel_e on the pixels whose uniform draw is below
        ``hot_pixel_fraction`` [e⁻]; None when both are off.

    Notes
    -----
    The draws depend only on (pattern_seed, shape); a negative dark offset
    lowers the pixel below the black level (DSNU is symmetric about 0).  The
    maps are cached and read-only.
    """
    if prnu_percent <= 0 and not (dsnu_e > 0 or (hot_pixel_fraction > 0 and hot_pixel_e > 0)):
        return None, None
    z_gain, z_dark, u_hot = _pattern_draws(tuple(shape), int(pattern_seed))
    gain = None
    if prnu_percent > 0:
        gain = np.maximum(1.0 + 0.01 * prnu_percent * z_gain, 0.0).astype(np.float32)
        gain.flags.writeable = False
    dark = None
    if dsnu_e > 0 or (hot_pixel_fraction > 0 and hot_pixel_e > 0):
        dark = (dsnu_e * z_dark + np.where(u_hot < hot_pixel_fraction, hot_pixel_e, 0.0)).astype(np.float32)
        dark.flags.writeable = False
    return gain, dark


def exposure_scale(rig: Rig, z: float) -> float:
    """The exposure factor of one frame (exposure jitter).

    Parameters
    ----------
    rig : Rig
        The rig (``sensor.exposure_jitter_percent``).
    z : float
        Standard normal draw of the frame [-].

    Returns
    -------
    float
        j = max(0, 1 + (exposure_jitter_percent/100)·z) [-]: the frame's real
        exposure time over ``exposure_ms``; exactly 1 when the model is off.
    """
    return max(0.0, 1.0 + 0.01 * rig.sensor.exposure_jitter_percent * z)


@dataclass(frozen=True)
class SensorModel:
    """Noise and ADC parameters of one sensor, taken from ``rig.sensor``.

    Build it with :meth:`from_rig`; the model is in the module docstring.

    Parameters
    ----------
    full_well_e : float
        Saturation charge [e⁻].
    read_noise_e : float
        RMS read noise [e⁻].
    dark_offset_dn : float
        Black level [DN].
    gain_e_per_dn : float
        Conversion gain actually used (> 0) [e⁻/DN].
    adc_bits : int
        ADC depth [bit].
    prnu_percent : float, default 0.0
        RMS photo-response non-uniformity [%].
    dsnu_e : float, default 0.0
        RMS dark-signal non-uniformity [e⁻].
    hot_pixel_fraction : float, default 0.0
        Fraction of hot pixels [-].
    hot_pixel_e : float, default 0.0
        Extra dark signal of a hot pixel [e⁻].
    pattern_seed : int, default 0
        Seed of the fixed-pattern maps [-].
    """

    full_well_e: float
    read_noise_e: float
    dark_offset_dn: float
    gain_e_per_dn: float
    adc_bits: int
    prnu_percent: float = 0.0
    dsnu_e: float = 0.0
    hot_pixel_fraction: float = 0.0
    hot_pixel_e: float = 0.0
    pattern_seed: int = 0

    @classmethod
    def from_rig(cls, rig: Rig) -> SensorModel:
        """The sensor model of a rig.

        Parameters
        ----------
        rig : Rig
            The rig; ``rig.sensor`` gives the parameters, the gain through
            :func:`conversion_gain_e_per_dn` (0 in the rig file → full scale).

        Returns
        -------
        SensorModel
            The model.
        """
        s = rig.sensor
        return cls(s.full_well_e, s.read_noise_e, s.dark_offset_dn,
                   conversion_gain_e_per_dn(s), s.adc_bits, s.prnu_percent, s.dsnu_e,
                   s.hot_pixel_fraction, s.hot_pixel_e, s.pattern_seed)

    def fixed_pattern(self, shape: tuple[int, int]) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The sensor's fixed-pattern maps for frames of a shape.

        Parameters
        ----------
        shape : tuple of int
            ``(rows, columns)`` [px].

        Returns
        -------
        gain : (rows, columns) float32 or None
            Photo-response factor per pixel [-]; None when PRNU is off.
        dark_e : (rows, columns) float32 or None
            Dark offset per pixel [e⁻]; None when DSNU and hot pixels are off.
        """
        return fixed_pattern_maps(tuple(int(n) for n in shape), self.prnu_percent, self.dsnu_e, self.hot_pixel_fraction,
                                  self.hot_pixel_e, self.pattern_seed)

    @property
    def full_scale_dn(self) -> int:
        """Largest ADC code [DN]."""
        return (1 << self.adc_bits) - 1

    def expected_dn(self, electrons) -> np.ndarray:
        """Noise-free mean DN of expected electrons.

        Parameters
        ----------
        electrons : array_like
            Expected photo-electrons λ [e⁻].

        Returns
        -------
        ndarray
            dark_offset_dn + λ/g [DN] (float64, no clipping, no rounding).
        """
        return self.dark_offset_dn + np.asarray(electrons, dtype=np.float64) / self.gain_e_per_dn

    def variance_dn2(self, electrons) -> np.ndarray:
        """Variance of the DN of unsaturated pixels.

        Parameters
        ----------
        electrons : array_like
            Expected photo-electrons λ [e⁻].

        Returns
        -------
        ndarray
            Var[DN] = (λ + σ_read²)/g² + 1/12 [DN²] (float64); the 1/12 is the
            ADC rounding of a distribution wide compared to 1 DN.
        """
        lam = np.asarray(electrons, dtype=np.float64)
        return (lam + self.read_noise_e**2) / self.gain_e_per_dn**2 + 1.0 / 12.0


def _backend(backend: str | None):
    """drjit.llvm for "drjit" (or None = automatic, when usable); None for "numba"."""
    if backend not in (None, "drjit", "numba"):
        raise ValueError(f"unknown sensor backend {backend!r} (drjit, numba)")
    if backend == "numba":
        return None
    llvm = _drjit_llvm()
    if llvm is None and backend == "drjit":
        raise ValueError("the drjit sensor backend needs Dr.Jit's LLVM backend (libLLVM >= 17)")
    return llvm


def apply_sensor(electrons, model: SensorModel, rng: np.random.Generator,
                 backend: str | None = None, exposure_factor: float = 1.0) -> np.ndarray:
    """Turn expected electrons (rows, columns) into a raw ADC frame, (rows, columns) uint16.

    Parameters
    ----------
    electrons : (rows, columns) float
        Expected photo-electrons per pixel, ≥ 0 [e⁻]; NaN or negative values raise.
    model : SensorModel
        Noise and ADC parameters (:meth:`SensorModel.from_rig`).
    rng : numpy.random.Generator
        Generator of the frame; one 64-bit key is drawn from it.  Use
        :func:`frame_rng` for reproducible frames.
    backend : {None, "drjit", "numba"}
        Dr.Jit's vectorised LLVM kernel (default when usable) or the numba
        kernel; both sample the same model exactly from the same per-pixel
        streams: the same shot noise, the read noise's quantile equal to a few
        1e-7 e⁻ (module docstring).
    exposure_factor : float, default 1.0
        The frame's real exposure over the nominal one (:func:`exposure_scale`) [-].

    Returns
    -------
    (rows, columns) uint16
        Raw ADC codes in ``[0, 2**adc_bits − 1]`` [DN] (not shifted to 16 bit).

    Raises
    ------
    ValueError
        When ``electrons`` is not 2-D, holds NaN or negative values; for an
        unknown ``backend``, or ``"drjit"`` when Dr.Jit's LLVM backend is not usable.

    Notes
    -----
    Exposure factor and PRNU, shot noise (Poisson), dark offset (DSNU, hot
    pixels) and full-well clip, Gaussian read noise, conversion gain and black
    level, rounding and ADC clip, in that order (module docstring).
    """
    lam = np.asarray(electrons)
    if lam.ndim != 2:
        raise ValueError(f"electrons must be a (rows, columns) array, got shape {lam.shape}")
    if lam.size and not lam.min() >= 0:  # also catches NaN (min propagates it); no temporary
        raise ValueError("electrons must be finite and >= 0 (expected photo-electrons per pixel)")
    flat = np.ascontiguousarray(lam, dtype=np.float32).reshape(-1)
    gain, dark = model.fixed_pattern(lam.shape)
    if gain is not None or exposure_factor != 1.0:
        factor = np.float32(exposure_factor) if gain is None else gain.reshape(-1) * np.float32(exposure_factor)
        flat = flat * factor
    dark_flat = None if dark is None else dark.reshape(-1)
    llvm = _backend(backend)
    if llvm is not None:
        return _dr_sensor(llvm, flat, _frame_key(rng), model, dark_flat).reshape(lam.shape)
    out = np.empty(flat.size, dtype=np.uint16)
    _sensor_kernel(flat, _frame_key(rng), _INV_K, _PTRS_LAMBDA, np.float64(model.full_well_e),
                   np.float64(model.read_noise_e), np.float64(1.0 / model.gain_e_per_dn),
                   np.float64(model.dark_offset_dn), np.float64(model.full_scale_dn), out,
                   np.zeros(0, np.float32) if dark_flat is None else dark_flat)
    return out.reshape(lam.shape)


@numba.njit(parallel=True, cache=True, nogil=True)
def _read_out_kernel(charge, key, read_noise, dn_per_e, offset, full_scale, out):  # pragma: no cover - compiled
    """Read noise (AS241 quantile of each pixel's own stream), gain, offset and ADC of collected charge."""
    for i in numba.prange(charge.shape[0]):
        e = np.float64(charge[i])
        if read_noise > 0.0:
            _, u = _next_uniform(_pixel_state(key, i))
            e += read_noise * _normal_quantile(u)
        dn = np.rint(e * dn_per_e + offset)
        out[i] = np.uint16(min(max(dn, 0.0), full_scale))


def read_out(charge, model: SensorModel, rng: np.random.Generator | None, analogue_gain: float = 1.0) -> np.ndarray:
    """The ADC codes of collected charge: read noise, analogue gain, black level, rounding and clip.

    The last steps of :func:`apply_sensor` on charge already collected (and already
    limited by the full well: :mod:`sim.blooming`), for the camera chain (:mod:`sim.chain`).

    Parameters
    ----------
    charge : (rows, columns) float
        Collected charge per pixel [e⁻].
    model : SensorModel
        Read noise, conversion gain, black level and ADC depth.
    rng : numpy.random.Generator or None
        The frame's generator: one 64-bit key, then every pixel's read noise from its own
        SplitMix64 stream (the numba kernel's AS241 quantile); None = no read noise.
    analogue_gain : float, default 1.0
        Gain before the ADC [-], > 0.

    Returns
    -------
    (rows, columns) uint16
        clip(round(dark_offset_dn + G·(n_e + σ_read·z)/g), 0, 2**adc_bits − 1) [DN].
    """
    q = np.asarray(charge)
    flat = np.ascontiguousarray(q if q.dtype in (np.float32, np.float64) else q.astype(np.float64)).reshape(-1)
    out = np.empty(flat.size, dtype=np.uint16)
    key = np.uint64(0) if rng is None else _frame_key(rng)
    sigma = 0.0 if rng is None else float(model.read_noise_e)
    _read_out_kernel(flat, key, sigma, float(analogue_gain) / model.gain_e_per_dn, float(model.dark_offset_dn),
                     float(model.full_scale_dn), out)
    return out.reshape(q.shape)

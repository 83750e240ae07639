"""The camera chain: the render's light → the file a real scanner's camera writes.

Order (each step its own module; the keys are the rig's ``[chain]`` table,
:class:`scheimpflug.model.chain.Chain`):

1. veiling glare on the light on the sensor, laser and other light alike
   (:mod:`sim.glare`);
2. the colour filter array: each pixel's expected charge from its channel's
   quantum efficiency for the laser's and for the other light (:mod:`sim.mosaic`);
3. exposure factor and PRNU, shot noise (Poisson, :func:`sim.sensor.poisson_counts`,
   the frame's seeded streams), dark offset (DSNU, hot pixels) — as :mod:`sim.sensor`;
4. blooming along columns, which also caps every pixel at the full well
   (:mod:`sim.blooming`);
5. read noise (Gaussian, each pixel's own stream keyed by the frame's generator:
   :func:`sim.sensor.read_out`), analogue gain G and the ADC:
   D = clip(round(b + G·n_e/g), 0, 2^bits − 1), b = ``[sensor] dark_offset_dn``,
   g the sensor's conversion gain (:func:`sim.sensor.conversion_gain_e_per_dn`);
6. the camera's processing: demosaicing of the raw codes (:mod:`sim.mosaic`), then
   black level, tone curve, pedestal and 8 bits by one lookup table (:mod:`sim.tone`);
   with ``sharpen_amount`` > 0 the levels are sharpened (an unsharp mask on the
   luminance, :mod:`sim.sharpen`) before the rounding to 8 bits;
7. the file: RGB JPEG at the chain's quality and subsampling, or 8-bit RGB PNG
   (:mod:`sim.jpeg`).

Without a generator (``rng=None``) steps 3 and 5 use the expected charge and no
noise: the chain's deterministic response, what the closed-form tests check.
The same (seed, frame) always gives the same file.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from scheimpflug.model.chain import Chain, chain_is_on, tone_table_points
from scheimpflug.model.rig import Rig

from .blooming import bloom_columns
from .glare import apply_glare
from .jpeg import encode_jpeg, encode_png8
from .mosaic import channel_factors, demosaic
from .sensor import SensorModel, poisson_counts, read_out
from .sharpen import unsharp_mask
from .tone import output_levels, output_lut

__all__ = ["ChainModel", "apply_chain", "encode_frame", "expected_charge", "frame_suffix", "process_raw",
           "raw_frame"]


@dataclass(frozen=True)
class ChainModel:
    """Everything the chain needs of a rig: its ``[chain]`` table, the sensor's noise and ADC, the render's QE.

    Parameters
    ----------
    chain : Chain
        The ``[chain]`` table.
    sensor : SensorModel
        Noise, full well, conversion gain, black level and ADC depth (``[sensor]``).
    qe_sensor : float
        ``[sensor] quantum_efficiency``, at which the render counts electrons [e⁻/photon].
    pixel_pitch_um : float
        ``[sensor] pixel_pitch_um``, the frame's pixel [µm] (the glare's scale in pixels).
    """

    chain: Chain
    sensor: SensorModel
    qe_sensor: float
    pixel_pitch_um: float

    @classmethod
    def from_rig(cls, rig: Rig) -> ChainModel:
        """The chain of a rig.

        Parameters
        ----------
        rig : Rig
            The rig (``[chain]``, ``[sensor]``).

        Returns
        -------
        ChainModel
            The model.
        """
        return cls(rig.chain, SensorModel.from_rig(rig), rig.sensor.quantum_efficiency, rig.sensor.pixel_pitch_um)

    @property
    def suffix(self) -> str:
        """The frame file's suffix: ``.jpg``, or ``.png`` (8-bit RGB or today's 16-bit grey)."""
        return frame_suffix(self.chain)


def frame_suffix(chain: Chain) -> str:
    """The suffix of a frame file the chain writes.

    Parameters
    ----------
    chain : Chain
        The ``[chain]`` table.

    Returns
    -------
    str
        ``".jpg"`` for ``format = "jpeg"``, ``".png"`` otherwise.
    """
    return ".jpg" if chain.format == "jpeg" else ".png"


@functools.lru_cache(maxsize=8)
def _factors(shape: tuple[int, int], pattern: str, qe: tuple[float, float, float], qe_sensor: float) -> np.ndarray:
    f = channel_factors(shape, pattern, qe, qe_sensor)
    f.flags.writeable = False
    return f


def expected_charge(laser_e, other_e, model: ChainModel) -> np.ndarray:
    """Expected charge of each pixel of the mosaic (steps 1–2), before noise.

    Parameters
    ----------
    laser_e : (rows, columns) float
        The laser's light, as electrons at ``qe_sensor`` [e⁻].
    other_e : (rows, columns) float or None
        All other light (flood, environment) likewise [e⁻]; None for none.
    model : ChainModel
        The chain.

    Returns
    -------
    (rows, columns) float32
        λ = f_laser,c · G(laser) + f_other,c · G(other) [e⁻], G the glare, f = qe_c / qe_sensor.
    """
    c = model.chain
    scale_px = c.glare_scale_um / model.pixel_pitch_um
    laser = apply_glare(laser_e, c.glare_fraction, scale_px)
    shape = laser.shape
    lam = laser * _factors(shape, c.bayer_pattern, (c.laser_qe_r, c.laser_qe_g, c.laser_qe_b), model.qe_sensor)
    if other_e is not None:
        other = apply_glare(other_e, c.glare_fraction, scale_px)
        lam += other * _factors(shape, c.bayer_pattern, (c.flood_qe_r, c.flood_qe_g, c.flood_qe_b), model.qe_sensor)
    return lam


def raw_frame(charge, model: ChainModel, rng: np.random.Generator | None = None,
              exposure_factor: float = 1.0) -> np.ndarray:
    """The sensor's raw codes of a mosaic's expected charge (steps 3–5).

    Parameters
    ----------
    charge : (rows, columns) float
        Expected charge per pixel [e⁻] (:func:`expected_charge`).
    model : ChainModel
        The chain.
    rng : numpy.random.Generator or None, default None
        The frame's generator (:func:`sim.sensor.frame_rng`): one key for the shot noise,
        then the read noise; None = no noise (the expected charge, rounded at the ADC).
    exposure_factor : float, default 1.0
        The frame's real exposure over the nominal one [-].

    Returns
    -------
    (rows, columns) uint16
        Raw ADC codes in [0, 2^adc_bits − 1] [DN].
    """
    s, c = model.sensor, model.chain
    lam = np.asarray(charge, dtype=np.float32)
    gain, dark = s.fixed_pattern(lam.shape)
    if gain is not None or exposure_factor != 1.0:
        lam = lam * (np.float32(exposure_factor) if gain is None else gain * np.float32(exposure_factor))
    n = lam if rng is None else poisson_counts(lam, rng)
    if dark is not None:
        n = n + dark
    e = bloom_columns(n, s.full_well_e, c.bloom_spill_fraction)
    return read_out(e, s, rng, c.analogue_gain)


def process_raw(raw, model: ChainModel) -> np.ndarray:
    """The camera's 8-bit RGB image of its raw codes (step 6).

    Parameters
    ----------
    raw : (rows, columns) uint16
        Raw ADC codes [DN].
    model : ChainModel
        The chain.

    Returns
    -------
    (rows, columns, 3) uint8
        R, G, B [DN]: demosaiced raw codes through the black level, tone curve and pedestal
        (and the sharpening).
    """
    c, s = model.chain, model.sensor
    table = tone_table_points(c.tone_table) if c.tone_curve == "table" else ()
    tone = (s.adc_bits, float(s.dark_offset_dn), float(c.black_level_dn), c.tone_curve, float(c.gamma), table)
    if c.sharpen_amount <= 0:
        return output_lut(*tone)[demosaic(raw, c.bayer_pattern, c.demosaic)]
    levels = output_levels(*tone).astype(np.float32)[demosaic(raw, c.bayer_pattern, c.demosaic)]
    sharp = unsharp_mask(levels, float(c.sharpen_amount), float(c.sharpen_sigma_px))
    return np.clip(np.rint(sharp), 0, 255).astype(np.uint8)


def apply_chain(laser_e, other_e, model: ChainModel, rng: np.random.Generator | None = None,
                exposure_factor: float = 1.0) -> np.ndarray:
    """The camera's 8-bit RGB frame of the render's light (steps 1–6).

    Parameters
    ----------
    laser_e : (rows, columns) float
        The laser's light as electrons at ``[sensor] quantum_efficiency`` [e⁻], ≥ 0.
    other_e : (rows, columns) float or None
        All other light likewise [e⁻]; None for none.
    model : ChainModel
        The chain (:meth:`ChainModel.from_rig`).
    rng : numpy.random.Generator or None, default None
        The frame's generator; None = no noise.
    exposure_factor : float, default 1.0
        The frame's real exposure over the nominal one [-].

    Returns
    -------
    (rows, columns, 3) uint8
        R, G, B [DN].

    Raises
    ------
    ValueError
        When the light is not 2-D, not finite or negative, or the two images differ in shape.
    """
    laser = np.asarray(laser_e)
    if laser.ndim != 2 or (other_e is not None and np.shape(other_e) != laser.shape):
        raise ValueError(f"the light must be (rows, columns) arrays of one shape, got {laser.shape}, "
                         f"{None if other_e is None else np.shape(other_e)}")
    for light in (laser, other_e):
        if light is not None and np.size(light) and not np.min(light) >= 0:
            raise ValueError("the light must be finite and >= 0 (expected electrons per pixel)")
    charge = expected_charge(laser, other_e, model)
    return process_raw(raw_frame(charge, model, rng, exposure_factor), model)


def encode_frame(rgb, chain: Chain) -> bytes:
    """A frame file's content as the chain's camera writes it (step 7).

    Parameters
    ----------
    rgb : (rows, columns, 3) uint8
        The frame [DN].
    chain : Chain
        The ``[chain]`` table (``format``, ``jpeg_quality``, ``jpeg_subsampling``).

    Returns
    -------
    bytes
        JPEG or 8-bit RGB PNG.

    Raises
    ------
    ValueError
        For ``format = "png16"`` (the chain is off: :func:`sim.writer.encode_png16` writes those).
    """
    if not chain_is_on(chain):
        raise ValueError('[chain] format = "png16" is the 16-bit grey frame, not the camera chain\'s')
    if chain.format == "jpeg":
        return encode_jpeg(rgb, chain.jpeg_quality, chain.jpeg_subsampling)
    return encode_png8(rgb)

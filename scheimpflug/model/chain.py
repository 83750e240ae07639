"""The camera chain of a real scanner's camera (the ``[chain]`` table of the rig file).

What happens to the light between the lens and the file a camera writes: veiling
glare of the lens, the colour filter array (Bayer mosaic) and its per-channel
quantum efficiency, blooming of saturated pixels, analogue gain, demosaicing,
tone curve, 8-bit output and JPEG compression.  The twin simulates it
(:mod:`sim.chain`); the instrument pipeline reads the files it writes like any
real camera's (``scheimpflug import``).

``format = "png16"`` (the default) is today's 16-bit grey frame of raw ADC codes:
the chain is off and every other key of the table is ignored, so a rig without
a ``[chain]`` table renders bit-identical frames.

Named cameras (``preset``): ``presets/cameras/<name>.toml`` holds each camera's
chain values with their source, or "assumed" where no source was found; a
``[chain]`` table that names a preset takes the preset's value for every key it
does not set (:func:`expand_chain_table`).  A rig written out (``rig_to_toml``, a
frame folder's manifest) holds every key, so there the name only records where
the values came from: reading it back gives the same chain.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import resources
from typing import Any

from scheimpflug.errors import RigError

__all__ = [
    "BAYER_PATTERNS",
    "CAMERA_PRESETS",
    "CHAIN_FORMATS",
    "CHAIN_KEY_RANGES",
    "DEMOSAIC_METHODS",
    "JPEG_SUBSAMPLINGS",
    "TONE_CURVES",
    "Chain",
    "camera_preset_tables",
    "chain_is_on",
    "expand_chain_table",
    "tone_table_points",
    "validate_chain",
]

#: Bayer colour-filter layouts, named by the 2 × 2 cell read row by row from the frame's top-left pixel.
BAYER_PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")
#: Demosaicing the camera does: OpenCV's bilinear ``COLOR_Bayer*2RGB`` or its edge-aware ``*_EA``.
DEMOSAIC_METHODS = ("bilinear", "edge_aware")
#: How the frames are written: 16-bit grey raw codes (the chain off), 8-bit RGB PNG, 8-bit RGB JPEG.
CHAIN_FORMATS = ("png16", "png8", "jpeg")
#: Tone curves: a power law, sRGB (IEC 61966-2-1), ITU-R BT.709's camera transfer function, a table.
TONE_CURVES = ("gamma", "srgb", "bt709", "table")
#: JPEG chroma subsampling (J:a:b).
JPEG_SUBSAMPLINGS = ("4:4:4", "4:2:2", "4:2:0")
#: Named cameras (``presets/cameras/<name>.toml``); ``none`` names none.
CAMERA_PRESETS = ("none", "raspberry_pi_v2", "logitech_c270")


def _choices(values: tuple[str, ...]) -> str:
    return "{" + ", ".join(f'"{v}"' for v in values) + "}"


CHAIN_KEY_RANGES: dict[str, str] = {
    "preset": _choices(CAMERA_PRESETS), "format": _choices(CHAIN_FORMATS),
    "bayer_pattern": _choices(BAYER_PATTERNS), "demosaic": _choices(DEMOSAIC_METHODS),
    "laser_qe_r": "[0, 1]", "laser_qe_g": "[0, 1]", "laser_qe_b": "[0, 1]",
    "flood_qe_r": "[0, 1]", "flood_qe_g": "[0, 1]", "flood_qe_b": "[0, 1]",
    "analogue_gain": "[1, 64]", "black_level_dn": "[0, 254]", "tone_curve": _choices(TONE_CURVES),
    "gamma": "[0.1, 10]", "tone_table": '{"", "x:y, x:y, …"}', "jpeg_quality": "[1, 100]",
    "jpeg_subsampling": _choices(JPEG_SUBSAMPLINGS),
    "bloom_spill_fraction": "[0, 1]", "glare_fraction": "[0, 0.99]", "glare_scale_um": "[0.1, 1e5]",
    "sharpen_amount": "[0, 10]", "sharpen_sigma_px": "[0.3, 100]",
}
"""The range of every ``[chain]`` key (merged into :data:`scheimpflug.model.rig.KEY_RANGES`)."""


@dataclass(frozen=True)
class Chain:
    """The camera chain: what the camera does to the light before its file is written (the ``[chain]`` table).

    Applied in this order (:mod:`sim.chain`): veiling glare on the light (laser and
    flood light alike), the colour filter array with each channel's quantum
    efficiency, shot noise, blooming, read noise, analogue gain and the ADC
    (``[sensor]``), black-level subtraction, demosaicing, tone curve, sharpening, 8 bits, file.

    Parameters
    ----------
    preset : str, default "none"
        A named camera whose values fill the keys this table leaves out, range
        {"none", "raspberry_pi_v2", "logitech_c270"} (``presets/cameras/``: each
        value's source).
    format : str, default "png16"
        Frame files: ``"png16"`` — 16-bit grey raw ADC codes, the chain off (every
        other key ignored); ``"png8"`` — 8-bit RGB PNG; ``"jpeg"`` — 8-bit RGB JPEG;
        range {"png16", "png8", "jpeg"}.
    bayer_pattern : str, default "RGGB"
        Colour filter layout: the 2 × 2 cell read row by row from the frame's
        top-left pixel, range {"RGGB", "BGGR", "GRBG", "GBRG"}.
    demosaic : str, default "bilinear"
        The camera's demosaicing: OpenCV's bilinear interpolation or its
        edge-aware variant, range {"bilinear", "edge_aware"}.
    laser_qe_r, laser_qe_g, laser_qe_b : float, default 0.75
        Quantum efficiency of the red, green and blue pixels (colour filter
        included) at the laser's wavelength [e⁻/photon], each in [0, 1].  The
        render counts electrons at ``[sensor] quantum_efficiency``; channel c gets
        them times qe_c / quantum_efficiency.
    flood_qe_r, flood_qe_g, flood_qe_b : float, default 0.75
        The same for all light but the laser's (flood light, environment),
        averaged over its spectrum [e⁻/photon], each in [0, 1].
    analogue_gain : float, default 1.0
        Gain before the ADC: DN = black + gain · n_e / ``[sensor]`` conversion
        gain [-], in [1, 64]; above 1 the ADC clips before the full well.
    black_level_dn : float, default 0.0
        The output's pedestal: the 8-bit value of a black pixel after the camera
        subtracted its sensor's black level [DN], in [0, 254].
    tone_curve : str, default "gamma"
        Transfer function from linear signal to output code: a power law
        (``gamma``), sRGB (IEC 61966-2-1), BT.709 (ITU-R BT.709-6) or ``tone_table``,
        range {"gamma", "srgb", "bt709", "table"}.
    gamma : float, default 1.0
        Exponent of the power law, code ∝ x^(1/gamma) (1 = linear) [-], in [0.1, 10].
    tone_table : str, default ""
        The tone curve as a table (``tone_curve = "table"``): points ``"x:y, x:y, …"`` of
        linear signal x and output y, both in [0, 1], x increasing from 0 to 1,
        joined by straight lines, e.g. ``"0:0, 0.05:0.2, 0.3:0.7, 1:1"``; range
        {"", "x:y, x:y, …"}.
    jpeg_quality : int, default 95
        IJG quality of the JPEG encoder (libjpeg's scaling of the standard tables) [-],
        in [1, 100].
    jpeg_subsampling : str, default "4:2:0"
        Chroma subsampling of the JPEG, range {"4:4:4", "4:2:2", "4:2:0"}.
    bloom_spill_fraction : float, default 0.0
        Fraction of the charge above the full well that spills along the pixel's
        column (half up, half down, filling neighbours to their full well and
        passing the rest on; :mod:`sim.blooming`); the rest is drained [-], in
        [0, 1].  0 = no blooming (charge above the full well is lost).
    glare_fraction : float, default 0.0
        Veiling glare: fraction of the light on the sensor spread by the lens's
        long-tailed point spread instead of its core [-], in [0, 0.99]; 0 = off.
    glare_scale_um : float, default 50.0
        Scale s of that tail on the sensor, K(r) = s / (2π (s² + r²)^(3/2)), whose line
        spread is the Cauchy profile (s/π)/(s² + x²) [µm], in [0.1, 1e5]; in pixels
        s / ``[sensor] pixel_pitch_um`` (so binning keeps the lens's glare).
    sharpen_amount : float, default 0.0
        The camera's sharpening, an unsharp mask on the luminance after the tone curve:
        each channel gains a·(Y − G_σ * Y) before rounding to 8 bits (:mod:`sim.sharpen`);
        beside a bright line on a dark ground it digs a moat the clip floors at 0 [-], in
        [0, 10]; 0 = off.
    sharpen_sigma_px : float, default 1.0
        Standard deviation σ of the mask's Gaussian, in the frame's own pixels (the camera's
        processor works on the frame it writes) [px], in [0.3, 100].
    """

    preset: str = "none"
    format: str = "png16"
    bayer_pattern: str = "RGGB"
    demosaic: str = "bilinear"
    laser_qe_r: float = 0.75
    laser_qe_g: float = 0.75
    laser_qe_b: float = 0.75
    flood_qe_r: float = 0.75
    flood_qe_g: float = 0.75
    flood_qe_b: float = 0.75
    analogue_gain: float = 1.0
    black_level_dn: float = 0.0
    tone_curve: str = "gamma"
    gamma: float = 1.0
    tone_table: str = ""
    jpeg_quality: int = 95
    jpeg_subsampling: str = "4:2:0"
    bloom_spill_fraction: float = 0.0
    glare_fraction: float = 0.0
    glare_scale_um: float = 50.0
    sharpen_amount: float = 0.0
    sharpen_sigma_px: float = 1.0


_CHOICES = {"preset": CAMERA_PRESETS, "format": CHAIN_FORMATS, "bayer_pattern": BAYER_PATTERNS,
            "demosaic": DEMOSAIC_METHODS, "tone_curve": TONE_CURVES, "jpeg_subsampling": JPEG_SUBSAMPLINGS}


def chain_is_on(chain: Chain) -> bool:
    """Whether the twin runs the camera chain.

    Parameters
    ----------
    chain : Chain
        The rig's ``[chain]`` table.

    Returns
    -------
    bool
        False for ``format = "png16"`` (today's 16-bit grey raw frames), True otherwise.
    """
    return chain.format != "png16"


def validate_chain(chain: Chain) -> None:
    """Check the ``[chain]`` keys that are names (the numbers are checked against their ranges by the rig).

    Parameters
    ----------
    chain : Chain
        The table.

    Returns
    -------
    None
        Nothing; the table is valid when no error is raised.

    Raises
    ------
    RigError
        ``[chain] key = value: must be one of …`` for a name not in its list.
    """
    for key, allowed in _CHOICES.items():
        value = getattr(chain, key)
        if value not in allowed:
            raise RigError(f"[chain] {key} = {value!r}: must be one of {', '.join(repr(a) for a in allowed)}")
    if chain.tone_curve == "table" or chain.tone_table:
        tone_table_points(chain.tone_table)


def tone_table_points(text: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The points of a ``tone_table``.

    Parameters
    ----------
    text : str
        ``"x:y, x:y, …"``: linear signal x and output y, both in [0, 1], x strictly
        increasing from 0 to 1.

    Returns
    -------
    xs, ys : tuple of float
        The points [-].

    Raises
    ------
    RigError
        ``[chain] tone_table = …: …`` for a table that is not such points.
    """
    def fail(reason: str) -> RigError:
        shown = text if len(text) <= 40 else text[:20] + "…"
        return RigError(f"[chain] tone_table = {shown!r}: {reason}")

    try:
        pairs = [tuple(float(v) for v in item.split(":")) for item in str(text).split(",")]
    except ValueError:
        raise fail("must be points x:y separated by commas, e.g. \"0:0, 0.3:0.7, 1:1\"") from None
    if any(len(p) != 2 for p in pairs) or len(pairs) < 2:
        raise fail("must be at least two points x:y separated by commas, e.g. \"0:0, 1:1\"")
    xs, ys = (tuple(v) for v in zip(*pairs))
    if not all(0.0 <= v <= 1.0 for v in xs + ys):
        raise fail("x and y must be in [0, 1]")
    if xs[0] != 0.0 or xs[-1] != 1.0 or any(b <= a for a, b in zip(xs, xs[1:])):
        raise fail("x must increase strictly from 0 to 1")
    return xs, ys


def camera_preset_tables(name: str) -> dict:
    """A named camera's file: its ``[chain]`` values and what else is known of it.

    Parameters
    ----------
    name : str
        One of :data:`CAMERA_PRESETS` but ``"none"``.

    Returns
    -------
    dict
        ``{"chain": {...}, "camera": {...}}`` of ``presets/cameras/<name>.toml``: the
        chain keys, and the camera's lens and sensor (pixel pitch, focal length,
        f-number, frame size) for an instrument description.

    Raises
    ------
    RigError
        For an unknown camera, listing the known ones.
    """
    if name not in CAMERA_PRESETS or name == "none":
        raise RigError(f"[chain] preset = {name!r}: unknown camera (known: "
                       f"{', '.join(repr(c) for c in CAMERA_PRESETS)})")
    path = resources.files("scheimpflug.model").joinpath("presets", "cameras", f"{name}.toml")
    return tomllib.loads(path.read_text("utf-8"))


def expand_chain_table(values: Any) -> Any:
    """A ``[chain]`` table with its preset's values filled in where it sets none.

    Parameters
    ----------
    values : Mapping or any
        The table as read from the rig file (anything else is returned as is,
        for the rig's own type check).

    Returns
    -------
    Mapping or any
        ``{**preset's [chain], **values}`` when ``values`` names a preset, else ``values``.

    Raises
    ------
    RigError
        For an unknown preset name.
    """
    if not isinstance(values, Mapping) or values.get("preset", "none") == "none":
        return values
    preset = values["preset"]
    if not isinstance(preset, str):
        raise RigError(f"[chain] preset = {preset!r}: must be a string")
    return {**camera_preset_tables(preset)["chain"], **values}

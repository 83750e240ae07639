"""The twin of a real instrument built from one of its scans (``scheimpflug twin build``).

:mod:`sim.twin.build` runs the steps, :mod:`sim.twin.part` makes the part's model from the
scan, :mod:`sim.twin.layout` is the folder ``render rotary --twin`` reads.
"""

from .build import BuildOptions, build_twin
from .layout import TWIN_FORMAT, TwinFiles, load_twin
from .part import PartModel, part_model

__all__ = ["TWIN_FORMAT", "BuildOptions", "PartModel", "TwinFiles", "build_twin", "load_twin", "part_model"]

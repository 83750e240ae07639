"""Parts to scan, with their exact geometry: presets, procedural generators, user meshes, scene files.

Pure numpy/trimesh (no Mitsuba).  Every part is a watertight triangle mesh in
millimetres plus an analytic description (``Part.analytic``) for scoring.

Frames
------
Part frame (= assembly frame) [mm]: ``z = 0`` is the face on the stage table,
``+z`` up; the rotary axis is the ``z`` axis.  The simulator places the
assembly on the table and turns it by the stage angle about ``z``; in the
stage frame at angle 0, ``+x`` is the laser's propagation direction and the
sheet is the plane ``y = 0`` (:func:`sheet_section` cuts that profile).

Entry points
------------
``load_part(name_or_path, *, seed=0, units="mm", axis_offset_mm=(0, 0), **overrides)``
    a preset name of :data:`PART_NAMES`, a mesh file (.stl/.ply/.obj, in the
    part frame; ``units`` "mm"/"m"/"inch"), or a scene file (.toml).
``load_scene(path, seed=None)``
    a scene file: parts with poses, materials, parameters and seeded
    variations.  The format is documented in :mod:`scenes.scenefile`; an
    example is ``scenes/examples/pile_variations.toml``.
Generators (each returns a :class:`Part`)
    :func:`plate`, :func:`cylinder`, :func:`knurled_cylinder`,
    :func:`knurled_ring`, :func:`box`, :func:`tape_roll`, :func:`blocker`,
    :func:`sphere`, :func:`ball_bar`.
:meth:`Assembly.to_ply`
    one binary PLY (double vertices) with a per-face ``object_id``: the
    simulator's ``truth/mesh.ply``; :func:`read_ply` reads it back.

Materials are tags (:data:`MATERIALS`) that the renderer maps to BSDFs.
Errors: :class:`~scheimpflug.errors.MeshError` for unknown parts and bad files;
:class:`MeshWarning` for usable but suspicious meshes (not watertight, not on
the table).

Mesh resolution: smooth curved walls have a chord sagitta ≤ 0.1 µm; knurls are
meshed *exactly* on an aligned grid (:mod:`scenes.knurl`) with edges ≤ 0.15 mm.
Knurled faces are flat facets: render them with face normals, not
interpolated vertex normals.
"""

from .generators import (
                         ball_bar,
                         blocker,
                         box,
                         cylinder,
                         knurled_cylinder,
                         knurled_ring,
                         plate,
                         sphere,
                         tape_roll,
)
from .knurl import knurl_radius_mm
from .loading import load_part
from .meshfile import load_mesh
from .part import MATERIALS, Assembly, MeshWarning, Part, read_ply, yaw_matrix
from .presets import PART_NAMES, build_preset
from .scenefile import load_scene
from .section import sheet_section

__all__ = [
    "Assembly",
    "MATERIALS",
    "MeshWarning",
    "PART_NAMES",
    "Part",
    "ball_bar",
    "blocker",
    "box",
    "build_preset",
    "cylinder",
    "knurl_radius_mm",
    "knurled_cylinder",
    "knurled_ring",
    "load_mesh",
    "load_part",
    "load_scene",
    "plate",
    "read_ply",
    "sheet_section",
    "sphere",
    "tape_roll",
    "yaw_matrix",
]

"""``scheimpflug studio``: design a rig in the browser, on the engine of ``scheimpflug design``.

* :mod:`~scheimpflug.app.studio.api` — a query (``preset=NAME&lens.focal_length_mm=35&…``) → the rig,
  its ``design --json`` figures, its rig file; the command line's one-line errors;
* :mod:`~scheimpflug.app.studio.keys` — the controls' table, read from the rig's dataclasses, their
  docstrings and ``KEY_RANGES`` (as the rig-key reference);
* :mod:`~scheimpflug.app.studio.views` — what the page draws (meridian plane, wedge of focus, field
  trapezoid, datasheet) from :mod:`scheimpflug.model.hinge` and :mod:`scheimpflug.model.camera`;
* :mod:`~scheimpflug.app.studio.occlusion` — the sheet's line on a preset part on the rotary table: seen,
  or lost to laser and camera shadow (rays in the twin's Mitsuba scene);
* :mod:`~scheimpflug.app.studio.preview` — that part rendered by the twin, 4 × 4 binned, the newest
  request winning;
* :mod:`~scheimpflug.app.studio.server` — the local HTTP server (127.0.0.1) and the page's files
  (``static/``: plain JavaScript, SVG and a canvas, no framework, nothing from the internet).
"""

from scheimpflug.app.studio.api import design_json, parse_query, rig_file_text, rig_of_query
from scheimpflug.app.studio.keys import key_table
from scheimpflug.app.studio.server import StudioServer, make_server
from scheimpflug.app.studio.views import datasheet, studio_views

__all__ = ["StudioServer", "datasheet", "design_json", "key_table", "make_server", "parse_query", "rig_file_text",
           "rig_of_query", "studio_views"]

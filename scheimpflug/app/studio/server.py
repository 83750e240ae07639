"""The studio's local web server: the page, its files and the API, on 127.0.0.1 only.

Standard library only (:mod:`http.server`, one thread per connection).  Paths:

* ``GET /``: the page (``static/index.html``); its files under ``/static/``;
* ``GET /api/keys``: the controls' key table (:func:`scheimpflug.app.studio.keys.key_table`);
* ``GET /api/design?QUERY``: exactly the JSON ``scheimpflug design --json`` prints for the rig;
* ``GET /api/rig.toml?QUERY``: the rig file of that rig;
* ``GET /api/studio?QUERY``: what the page draws: ``design`` (as above without ``pattern_advice``),
  ``views``, ``rig``, ``derived``, ``label``, ``warnings`` (each with the key it names);
* ``GET /api/datasheet.md?QUERY``, ``GET /api/datasheet.csv?QUERY``: the datasheet as Markdown or CSV;
* ``GET /api/study.toml?QUERY``: a tolerance-study spec of the design (``scheimpflug study tolerance``);
* ``GET /api/solve?QUERY&near_mm=A&far_mm=B``: rigs that cover a wanted range (``design --near-mm``);
* ``GET /api/focus?QUERY``: the smallest f-number whose wedge of focus holds the whole sheet
  (:func:`scheimpflug.app.studio.views.f_number_for_focus`);
* ``GET /api/occlusion?QUERY&part=NAME&angle_deg=A[&turn=1]``: the sheet's line on a preset part at a
  table angle, seen or lost to laser and camera shadow (:mod:`scheimpflug.app.studio.occlusion`);
* ``POST /api/mesh?name=FILE.stl`` (the file as the body; .stl, .ply or .obj in mm, the rotary axis on
  z): a part of one's own for the occlusion and the preview, answered ``{"part": "upload:ID", "name",
  "faces", "warnings"}``;
  more than :data:`MAX_UPLOAD_BYTES` is refused (413) before it is read, a file that is not a mesh
  with the reason (400); the newest :data:`MAX_UPLOADS` are kept, in a folder removed on exit;
* ``GET /api/preview.png?QUERY&part=NAME&angle_deg=A``: that part rendered by the twin on a 4 × 4
  binned sensor (:mod:`scheimpflug.app.studio.preview`; its render time in ``X-Render-Seconds``; 409 when
  a newer preview was asked for while it waited).

QUERY: :mod:`scheimpflug.app.studio.api`.  A bad query answers 400 with ``{"error": MESSAGE, "key":
"table.key" or null}``, MESSAGE the one line the command line prints; an unknown path 404; more than
:data:`MAX_BUSY` requests at work at once 503 (the page asks again: the newest request wins, no queue
grows); a bug 500 with one line, never a traceback.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import shutil
import sys
import tempfile
import threading
import uuid
import warnings
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from scheimpflug.app.studio.api import (
    StudioQuery,
    design_json,
    key_of_message,
    parse_query,
    query_number,
    rig_file_text,
    rig_of_query,
    solve_range,
    split_query,
    split_solve_query,
    tolerance_spec_text,
)
from scheimpflug.app.studio.keys import key_table
from scheimpflug.app.studio.preview import PreviewQueue, Superseded
from scheimpflug.app.studio.views import datasheet, f_number_for_focus, studio_views
from scheimpflug.errors import MeshError, ScheimpflugError
from scheimpflug.model.rig import PRESETS, Rig, rig_to_dict

__all__ = ["MAX_BUSY", "MAX_UPLOADS", "MAX_UPLOAD_BYTES", "StudioServer", "datasheet_csv", "datasheet_markdown",
           "make_server"]

MAX_BUSY = 4
"""Requests computed at once; one more is answered 503 at once (2 cores: more would only queue)."""

MAX_UPLOAD_BYTES = 50 * 2**20
"""Largest mesh upload [bytes] (a million-triangle binary STL is 48 MB)."""

MAX_UPLOADS = 4
"""Uploaded meshes kept per studio (the oldest is dropped) [-]."""

_STATIC = {"index.html": "text/html; charset=utf-8", "studio.js": "text/javascript; charset=utf-8",
           "studio.css": "text/css; charset=utf-8"}


class StudioServer(ThreadingHTTPServer):
    """An HTTP server on 127.0.0.1 holding the studio's own rig (``--rig`` / ``--preset``).

    Parameters
    ----------
    port : int
        TCP port; 0 takes a free one (:attr:`port` says which).
    base_tables : dict, optional
        The rig file's tables a query without ``preset=`` starts from; default the paper preset.
    base_label : str, default "preset 'paper'"
        What the page calls that rig.
    base_file : str, optional
        The rig file those tables came from (absolute path), for the exported study spec.
    """

    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, port: int = 0, base_tables: dict | None = None, base_label: str = "preset 'paper'",
                 base_file: str | None = None):
        super().__init__(("127.0.0.1", port), _Handler)
        self.base_tables = base_tables
        self.base_label = base_label
        self.base_file = base_file
        self.busy = threading.BoundedSemaphore(MAX_BUSY)
        self.previews = PreviewQueue()
        self.upload_dir = Path(tempfile.mkdtemp(prefix="scheimpflug-studio-"))
        self.uploads: dict[str, tuple[str, str]] = {}      # "upload:ID" → (file, its name), oldest first
        self.upload_lock = threading.Lock()

    def server_close(self) -> None:
        """Close the socket and remove the uploaded meshes."""
        super().server_close()
        if getattr(self, "upload_dir", None) is not None:     # not yet there when the port was refused
            shutil.rmtree(self.upload_dir, ignore_errors=True)

    def source_of(self, part: str) -> str | None:
        """The file of an uploaded part (None for a preset name).

        Raises
        ------
        MeshError
            For an ``upload:`` name this studio does not hold (any more).
        """
        if not part.startswith("upload:"):
            return None
        with self.upload_lock:
            if part not in self.uploads:
                raise MeshError(f"part = {part[:40]!r}: no such upload in this studio (it keeps the newest "
                                f"{MAX_UPLOADS}; upload the mesh again)")
            return self.uploads[part][0]

    def handle_error(self, request, client_address) -> None:
        """A connection the browser dropped (a closed tab, an aborted request) is not an error: quiet."""
        exc = sys.exc_info()[1]
        if not isinstance(exc, ConnectionError):
            print(f"scheimpflug studio: error serving {client_address[0]}: {type(exc).__name__}: {exc}",
                  file=sys.stderr)

    @property
    def port(self) -> int:
        """The TCP port the server listens on."""
        return self.server_address[1]

    @property
    def url(self) -> str:
        """The page's address."""
        return f"http://127.0.0.1:{self.port}/"


def make_server(port: int = 0, base_tables: dict | None = None, base_label: str = "preset 'paper'",
                base_file: str | None = None) -> StudioServer:
    """A :class:`StudioServer`, bound and ready for ``serve_forever`` (e.g. in a thread)."""
    return StudioServer(port, base_tables, base_label, base_file)


def datasheet_markdown(rows: list[dict], label: str) -> str:
    """The datasheet as a Markdown table (figure, value, unit), headed by what the rig is."""
    lines = [f"# Datasheet — {label}", "", "| figure | value | unit |", "|---|---:|---|"]
    lines += [f"| {r['label']} | {_fmt(r['value'])} | {r['unit']} |" for r in rows]
    return "\n".join(lines) + "\n"


def datasheet_csv(rows: list[dict]) -> str:
    """The datasheet as CSV: ``key,figure,value,unit`` (full precision; empty where undefined)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["key", "figure", "value", "unit"])
    for r in rows:
        w.writerow([r["key"], r["label"], "" if r["value"] is None else repr(r["value"]), r["unit"]])
    return buf.getvalue()


def _fmt(value: float | None) -> str:
    return "–" if value is None else f"{value:.6g}"


class _Answer(Exception):
    """An HTTP answer other than 200, raised inside a handler."""

    def __init__(self, status: int, message: str, key: str | None = None):
        super().__init__(message)
        self.status, self.key = status, key


class _Handler(BaseHTTPRequestHandler):
    server: StudioServer
    server_version = "scheimpflug-studio"
    protocol_version = "HTTP/1.1"       # keep-alive: one connection per tab
    disable_nagle_algorithm = True      # headers and body leave at once (no 40 ms delayed-ACK stall)

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - the base class's name
        pass            # quiet: the terminal shows the address and errors only

    def do_GET(self) -> None:  # noqa: N802 - http.server's name
        if not self.server.busy.acquire(blocking=False):
            self._json(503, {"error": "busy: too many requests at once; the newest is answered next"},
                       extra={"Retry-After": "1"})
            return
        try:
            self._route()
        except _Answer as a:
            self._json(a.status, {"error": str(a), "key": a.key})
        except ScheimpflugError as exc:
            message = " ".join(str(exc).split())
            self._json(400, {"error": message, "key": key_of_message(message)})
        except ConnectionError:
            pass        # the tab went away: its answer is not wanted
        except Exception as exc:  # noqa: BLE001 - one line to the page, never a traceback
            self._json(500, {"error": f"internal error: {type(exc).__name__}: {' '.join(str(exc).split())[:300]} "
                                      "— this is a bug, please report it with the query"})
        finally:
            self.server.busy.release()

    def do_POST(self) -> None:  # noqa: N802 - http.server's name
        if urlsplit(self.path).path != "/api/mesh":
            self.close_connection = True            # its body is not read
            self._json(405, {"error": "the studio answers GET, and POST only at /api/mesh"}, extra={"Allow": "GET"})
            return
        self.do_GET()

    def _upload(self, query: str) -> None:
        from scenes.loading import load_part
        from scenes.meshfile import MESH_SUFFIXES

        _, taken = split_query(query, ("name",))
        name = taken.get("name", "")
        suffix = Path(name).suffix.lower()
        if suffix not in MESH_SUFFIXES:
            raise _Answer(400, f"name = {name[:40]!r}: a mesh file ({', '.join(MESH_SUFFIXES)}) in mm")
        size = self._body_size()
        path = self.server.upload_dir / f"{uuid.uuid4().hex}{suffix}"
        digest = hashlib.sha256()
        with path.open("wb") as fh:
            left = size
            while left > 0:
                chunk = self.rfile.read(min(left, 2**20))
                if not chunk:
                    break
                fh.write(chunk)
                digest.update(chunk)
                left -= len(chunk)
        try:
            if left:
                raise _Answer(400, f"the upload ended after {size - left} of {size} bytes")
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                asm = load_part(str(path))
        except MeshError as exc:                    # said with the user's file name, not the server's
            path.unlink(missing_ok=True)
            raise MeshError(str(exc).replace(str(path), name)) from None
        except BaseException:
            path.unlink(missing_ok=True)
            raise
        part = f"upload:{digest.hexdigest()[:12]}"
        self._keep(part, str(path), name)
        self._json(200, {"part": part, "name": name, "faces": int(sum(len(p.mesh.faces) for p in asm.parts)),
                         "warnings": [str(w.message).replace(str(path), name) for w in caught]})

    def _body_size(self) -> int:
        text = self.headers.get("Content-Length")
        if text is None or not text.strip().isdigit():
            self.close_connection = True
            raise _Answer(411, "an upload needs its Content-Length")
        size = int(text)
        if size > MAX_UPLOAD_BYTES:
            self.close_connection = True            # its body is not read
            raise _Answer(413, f"the mesh is {size / 2**20:.1f} MB: at most {MAX_UPLOAD_BYTES / 2**20:g} MB")
        return size

    def _keep(self, part: str, path: str, name: str) -> None:
        with self.server.upload_lock:
            old = self.server.uploads.pop(part, None)
            if old is not None and old[0] != path:
                Path(old[0]).unlink(missing_ok=True)
            self.server.uploads[part] = (path, name)
            while len(self.server.uploads) > MAX_UPLOADS:
                Path(self.server.uploads.pop(next(iter(self.server.uploads)))[0]).unlink(missing_ok=True)

    # ------------------------------------------------------------ routing
    def _route(self) -> None:
        parts = urlsplit(self.path)
        path, query = parts.path, parts.query
        if path in ("/", "/index.html"):
            self._static("index.html")
        elif path == "/favicon.ico":
            self._send(204, b"", "image/x-icon")
        elif path.startswith("/static/"):
            self._static(path[len("/static/"):])
        elif path == "/api/keys":
            from scenes import PART_NAMES

            self._json(200, {"keys": list(key_table()), "presets": list(PRESETS), "base": self.server.base_label,
                             "base_is_preset": self.server.base_tables is None, "parts": list(PART_NAMES),
                             "max_upload_bytes": MAX_UPLOAD_BYTES})
        elif path == "/api/solve":
            rest, near, far = split_solve_query(query)
            q = parse_query(rest)
            self._json(200, {"near_mm": near, "far_mm": far,
                             "proposals": solve_range(q, near, far, self.server.base_tables)})
        elif path == "/api/mesh" and self.command == "POST":
            self._upload(query)
        elif path == "/api/occlusion":
            self._occlusion(query)
        elif path == "/api/preview.png":
            self._preview(query)
        elif path in _API:
            _API[path](self, parse_query(query))
        else:
            raise _Answer(404, f"no such page: {path[:80]}")

    def _rig(self, q: StudioQuery) -> Rig:
        return rig_of_query(q, self.server.base_tables)

    def _label(self, q: StudioQuery) -> str:
        return f"preset '{q.preset}'" if q.preset else self.server.base_label

    def _design(self, q: StudioQuery) -> None:
        self._json(200, design_json(self._rig(q)))

    def _rig_toml(self, q: StudioQuery) -> None:
        self._send(200, rig_file_text(self._rig(q)).encode(), "application/toml; charset=utf-8",
                   extra={"Content-Disposition": 'inline; filename="rig.toml"'})

    def _occlusion(self, query: str) -> None:
        from scheimpflug.app.studio.occlusion import occlusion

        rest, taken = split_query(query, ("part", "angle_deg", "turn"))
        q = parse_query(rest)
        angle = query_number(taken, "angle_deg", -360, 360, "deg")
        turn = taken.get("turn", "0") not in ("", "0", "false")
        part = taken.get("part", "cylinder")
        self._json(200, occlusion(self._rig(q), part, angle, 36 if turn else 0, source=self.server.source_of(part)))

    def _preview(self, query: str) -> None:
        rest, taken = split_query(query, ("part", "angle_deg"))
        rig = self._rig(parse_query(rest))
        angle = query_number(taken, "angle_deg", -360, 360, "deg")
        part = taken.get("part", "cylinder")
        try:
            png, seconds = self.server.previews.render(rig, part, angle, source=self.server.source_of(part))
        except Superseded as exc:
            raise _Answer(409, str(exc)) from None
        self._send(200, png, "image/png", extra={"X-Render-Seconds": f"{seconds:.3f}"})

    def _study(self, q: StudioQuery) -> None:
        self._rig(q)                    # a rig the engine refuses is refused here too
        self._send(200, tolerance_spec_text(q, self.server.base_file).encode(), "application/toml; charset=utf-8",
                   extra={"Content-Disposition": 'inline; filename="tolerance.toml"'})

    def _studio(self, q: StudioQuery) -> None:
        rig = self._rig(q)
        report = design_json(rig, advice=False)     # the page does not show the pattern advice (the slow part)
        self._json(200, {"design": report, "views": studio_views(rig, report, q.subpixel), "rig": rig_to_dict(rig),
                         "derived": list(rig.derived), "label": self._label(q),
                         "warnings": [{"message": w, "key": key_of_message(w)} for w in report["warnings"]]})

    def _datasheet(self, q: StudioQuery, kind: str) -> None:
        rig = self._rig(q)
        rows = datasheet(rig, design_json(rig), q.subpixel)
        if kind == "md":
            self._send(200, datasheet_markdown(rows, self._label(q)).encode(), "text/markdown; charset=utf-8")
        else:
            self._send(200, datasheet_csv(rows).encode(), "text/csv; charset=utf-8",
                       extra={"Content-Disposition": 'inline; filename="datasheet.csv"'})

    # ------------------------------------------------------------ answers
    def _static(self, name: str) -> None:
        if name not in _STATIC:
            raise _Answer(404, f"no such file: {name[:80]}")
        body = resources.files("scheimpflug.app.studio").joinpath("static", name).read_bytes()
        self._send(200, body, _STATIC[name])

    def _json(self, status: int, obj: Any, extra: dict | None = None) -> None:
        self._send(status, json.dumps(obj, allow_nan=False).encode(), "application/json", extra)

    def _send(self, status: int, body: bytes, ctype: str, extra: dict | None = None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        for k, v in (extra or {}).items():
            self.send_header(k, v)
        self.end_headers()
        self.wfile.write(body)


_API = {
    "/api/design": _Handler._design,
    "/api/rig.toml": _Handler._rig_toml,
    "/api/studio": _Handler._studio,
    "/api/study.toml": _Handler._study,
    "/api/focus": lambda h, q: h._json(200, f_number_for_focus(h._rig(q))),
    "/api/datasheet.md": lambda h, q: h._datasheet(q, "md"),
    "/api/datasheet.csv": lambda h, q: h._datasheet(q, "csv"),
}

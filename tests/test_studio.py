"""``scheimpflug studio`` without a browser: the API against ``scheimpflug design``, errors, the server.

The contract (issue 37, docs/reference/interface.md): ``GET /api/design?QUERY`` answers exactly the JSON
``design --json`` prints for the rig the query names, ``GET /api/rig.toml?QUERY`` a rig file whose
``design`` is the same, and a bad key or value 400 with the command line's one-line message.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import urllib.error
import urllib.request
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from scheimpflug.app.cli import main
from scheimpflug.app.studio import api
from scheimpflug.app.studio.keys import key_table
from scheimpflug.app.studio.server import make_server
from scheimpflug.model.rig import preset_tables

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def server():
    srv = make_server(0)
    thread = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    yield srv
    srv.shutdown()
    srv.server_close()


def _get(srv, path: str) -> tuple[int, bytes, str]:
    try:
        with urllib.request.urlopen(srv.url.rstrip("/") + path, timeout=10) as r:
            return r.status, r.read(), r.headers.get("Content-Type", "")
    except urllib.error.HTTPError as e:
        return e.code, e.read(), e.headers.get("Content-Type", "")


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    return repr(v)


def _rig_file(tmp_path: Path, tables: dict) -> Path:
    """A rig file holding these tables (the query's values written as a TOML file would hold them)."""
    text = "\n".join(f"[{t}]\n" + "".join(f"{k} = {_toml_value(v)}\n" for k, v in keys.items())
                     for t, keys in tables.items())
    path = tmp_path / "rig.toml"
    path.write_text(text)
    return path


def _design_cli(capsys, *argv: str) -> tuple[int, dict | None, str]:
    status = main(["design", *argv, "--json"])
    out, err = capsys.readouterr()
    return status, (json.loads(out) if status == 0 else None), err


QUERIES = [
    "",
    "preset=paper",
    "lens.focal_length_mm=35",
    "lens.focal_length_mm=75&lens.f_number=11&laser.tan_phi=0.1",
    "sensor.columns=2048&sensor.rows=1536&sensor.pixel_pitch_um=3.45&sensor.hinge_column=5000",
    "preset=paper-as-built&laser.scheimpflug_distance_mm=180",
    "stage.d0_mm=&stage.axis_mm=&lens.focal_length_mm=50",      # stage keys left out: derived
]


@pytest.mark.parametrize("query", QUERIES)
def test_api_design_is_what_design_json_prints(server, capsys, tmp_path, query):
    q = api.parse_query(query)
    status, body, ctype = _get(server, f"/api/design?{query}")
    assert status == 200 and ctype == "application/json"
    cli_status, cli, _ = _design_cli(capsys, "--rig", str(_rig_file(tmp_path, api.rig_tables(q))))
    assert cli_status == 0
    assert json.loads(body) == cli


@pytest.mark.parametrize("query", [
    "lens.focal_length_mm=-1",
    "lens.focal_length_mm=abc",
    "lens.focal_length_mm=nan",
    "lens.focus=3",
    "optics.f=3",
    "laser.tan_phi=10",
    "sensor.columns=1.5",
    "sensor.hinge_column=100",
    "twin.speckle_model=laser",
])
def test_a_bad_key_or_value_answers_400_with_the_command_lines_message(server, capsys, tmp_path, query):
    status, body, _ = _get(server, f"/api/design?{query}")
    assert status == 400
    answer = json.loads(body)
    cli_status, _, err = _design_cli(capsys, "--rig", str(_rig_file(tmp_path, api.rig_tables(api.parse_query(query)))))
    assert cli_status == 2
    assert err.strip() == f"scheimpflug design: error: {answer['error']}"
    assert "Traceback" not in answer["error"] and "\n" not in answer["error"]
    table, key = query.split("=")[0].split(".")
    if answer["key"] is not None:       # the control that breaks it is named (relations: the key the engine names)
        assert answer["key"].startswith(f"{table}.")


@pytest.mark.parametrize("query, words", [
    ("lens", "expected preset=NAME"),
    ("preset=nope", "unknown preset 'nope'"),
    ("lens.f_number=4&lens.f_number=5", "given twice"),
    ("subpixel=0.5", "sub-pixel factor"),
    ("lens.f_number=" + "9" * 9000, "at most 8192"),
])
def test_a_bad_query_is_named(server, query, words):
    status, body, _ = _get(server, f"/api/design?{query}")
    assert status == 400 and words in json.loads(body)["error"]


@pytest.mark.parametrize("query", ["lens.focal_length_mm=35&laser.tan_phi=0.15",
                                   "stage.d0_mm=&stage.axis_mm=&laser.waist_distance_mm=&sensor.exposure_ms="])
def test_the_rig_file_gives_the_same_design(server, capsys, tmp_path, query):
    status, body, ctype = _get(server, f"/api/rig.toml?{query}")
    assert status == 200 and ctype.startswith("application/toml")
    path = tmp_path / "exported.toml"
    path.write_bytes(body)
    cli_status, cli, _ = _design_cli(capsys, "--rig", str(path))
    assert cli_status == 0
    assert cli == json.loads(_get(server, f"/api/design?{query}")[1])
    if "stage.d0_mm=&" in query:
        assert "stage.d0_mm" in cli["derived"]


def test_the_page_answer_holds_the_design_and_the_datasheet_agrees(server):
    status, body, _ = _get(server, "/api/studio?lens.f_number=8&subpixel=1")
    page = json.loads(body)
    design = json.loads(_get(server, "/api/design?lens.f_number=8")[1])
    assert status == 200 and page["design"] == {k: v for k, v in design.items() if k != "pattern_advice"}
    rows = {r["key"]: r for r in page["views"]["datasheet"]}
    for r in rows.values():
        if r["design"]:
            scale = 1e3 if r["unit"] == "µm" else 1.0
            assert r["value"] == pytest.approx(design[r["design"]] * scale, rel=1e-12), r["key"]
    assert rows["focus_margin_mm"]["value"] > 0     # the hinge rule: the sheet is the plane of sharp focus
    halved = {r["key"]: r["value"] for r in json.loads(_get(server, "/api/studio?lens.f_number=8&subpixel=4")[1])[
        "views"]["datasheet"]}
    assert halved["dz_middle_um"] == pytest.approx(rows["dz_middle_um"]["value"] / 4)


def test_a_mis_tilted_sensor_leaves_the_wedge_of_focus(server):
    rows = {r["key"]: r["value"] for r in json.loads(_get(server, "/api/studio?sensor.tilt_error_deg=2")[1])[
        "views"]["datasheet"]}
    assert rows["focus_margin_mm"] < 0


def test_the_sharp_plane_of_the_hinge_rule_is_the_sheet(server):
    m = json.loads(_get(server, "/api/studio")[1])["views"]["meridian"]
    f = json.loads(_get(server, "/api/design")[1])
    (x0, y0), (x1, y1) = m["sharp"]
    tan_phi = preset_tables("paper")["laser"]["tan_phi"]
    d = preset_tables("paper")["laser"]["scheimpflug_distance_mm"]
    for x, y in ((x0, y0), (x1, y1)):
        assert y == pytest.approx(d - x * tan_phi, abs=1e-3)        # on the sheet
    assert m["object_hinge"] == pytest.approx(f["object_hinge_mm"][:2])


def test_the_warnings_name_their_control(server):
    page = json.loads(_get(server, "/api/studio?stage.axis_mm=900")[1])
    assert page["warnings"] and page["warnings"][0]["key"] == "stage.axis_mm"


def test_the_datasheet_exports(server):
    status, md, ctype = _get(server, "/api/datasheet.md?lens.f_number=8")
    assert status == 200 and ctype.startswith("text/markdown")
    assert "| measurement range Z | 274.276 | mm |" in md.decode()
    status, csv_text, _ = _get(server, "/api/datasheet.csv")
    lines = csv_text.decode().splitlines()
    assert lines[0] == "key,figure,value,unit" and lines[1].startswith("range_z_mm,measurement range Z,274.27")


def test_the_page_and_its_files_are_served_from_the_package(server):
    status, html, ctype = _get(server, "/")
    assert status == 200 and ctype.startswith("text/html")
    text = html.decode()
    assert "http://" not in text and "https://" not in text        # nothing from the internet
    for name in ("studio.js", "studio.css"):
        status, body, _ = _get(server, f"/static/{name}")
        assert status == 200 and b"https://" not in body
    assert _get(server, "/static/../server.py")[0] == 404
    assert _get(server, "/static/api.py")[0] == 404
    keys = json.loads(_get(server, "/api/keys")[1])
    assert len(keys["keys"]) == len(key_table()) and "paper" in keys["presets"]


def test_post_and_unknown_paths_are_refused(server):
    req = urllib.request.Request(server.url + "api/design", data=b"x", method="POST")
    with pytest.raises(urllib.error.HTTPError) as exc:
        urllib.request.urlopen(req, timeout=5)
    assert exc.value.code == 405
    status, body, _ = _get(server, "/api/nothing")
    assert status == 404 and "no such page" in json.loads(body)["error"]


def test_many_requests_at_once_are_all_answered(server):
    with ThreadPoolExecutor(32) as pool:
        statuses = list(pool.map(lambda k: _get(server, f"/api/studio?lens.focal_length_mm={40 + k}")[0], range(64)))
    assert set(statuses) <= {200, 503} and statuses.count(200) >= 4


def test_the_key_table_is_the_rig_key_references(tmp_path):
    sys.path.insert(0, str(ROOT / "docs" / "_ext"))
    try:
        import scheimpflug_docs as ref
    finally:
        sys.path.pop(0)
    mine = {k["name"]: k for k in key_table()}
    for r in ref.rig_keys():
        k = mine.pop(r.name)
        assert (k["unit"], k["range"], " ".join(k["description"].split())) == (
            r.unit, r.range, " ".join(r.description.split())), r.name
    assert not mine
    assert {k["name"] for k in key_table() if k["main"]} >= {"lens.focal_length_mm", "laser.tan_phi",
                                                              "sensor.tilt_error_deg"}


def test_the_command_serves_and_stops_on_ctrl_c(tmp_path):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    # SIGINT as a terminal's Ctrl-C finds it: a shell starts background jobs with SIGINT ignored, and an
    # ignored SIGINT is inherited (Python then installs no KeyboardInterrupt handler)
    proc = subprocess.Popen([sys.executable, "-m", "scheimpflug", "studio", "--no-browser", "--port", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        line = proc.stdout.readline()
        assert "http://127.0.0.1:" in line
        url = line.split(" at ", 1)[1].split()[0]
        with urllib.request.urlopen(url + "api/design", timeout=10) as r:
            assert json.loads(r.read())["tilt_deg"] == pytest.approx(21.6462, abs=1e-4)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10) == 0
        assert "stopped" in proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()


def test_the_command_refuses_a_bad_rig_file_and_a_busy_port(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[lens]\nfocal_length_mm = -1\n")
    assert main(["studio", "--rig", str(bad), "--no-browser"]) == 2
    assert "focal_length_mm = -1" in capsys.readouterr().err
    srv = make_server(0)
    try:
        assert main(["studio", "--port", str(srv.port), "--no-browser"]) == 2
        assert "cannot listen" in capsys.readouterr().err
    finally:
        srv.server_close()


@pytest.mark.parametrize("query", ["lens.focal_length_mm=50&laser.tan_phi=0.15&twin.speckle_model=sensor",
                                   "preset=paper-as-built&lens.f_number=8"])
def test_the_tolerance_study_spec_holds_the_design(server, query):
    import tomllib

    from sim.study.spec import parse_study_spec

    status, body, _ = _get(server, f"/api/study.toml?{query}")
    assert status == 200
    spec = parse_study_spec(tomllib.loads(body.decode()), "tolerance")
    assert {t.key for t in spec.tolerances} == set(api.STUDY_TOLERANCES)
    from scheimpflug.model.rig import rig_from_dict

    assert api.design_json(rig_from_dict(spec.rig_tables)) == json.loads(_get(server, f"/api/design?{query}")[1])
    assert _get(server, "/api/study.toml?lens.focal_length_mm=-5")[0] == 400


def test_solve_for_a_range_proposes_rigs_that_cover_it(server, capsys, tmp_path):
    status, body, _ = _get(server, "/api/solve?lens.focal_length_mm=50&near_mm=300&far_mm=600")
    assert status == 200
    proposals = json.loads(body)["proposals"]
    ok = [p for p in proposals if "design" in p]
    assert ok and all("error" in p for p in proposals if "design" not in p)
    for p in ok:
        tables = api.rig_tables(api.parse_query("lens.focal_length_mm=50"))
        for name, value in p["keys"].items():
            t, k = name.split(".")
            tables[t][k] = value
        assert main(["design", "--rig", str(_rig_file(tmp_path, tables)), "--json"]) == 0
        design = json.loads(capsys.readouterr().out)
        assert design == p["design"]
        hinge_from_laser = 50 * (1 + tables["laser"]["tan_phi"] ** 2) ** 0.5       # f / cos φ
        assert [d + hinge_from_laser for d in design["distance_range_mm"]] == pytest.approx([300, 600], abs=1e-6)
    assert _get(server, "/api/solve?near_mm=300")[0] == 400
    assert _get(server, "/api/solve?near_mm=600&far_mm=300")[0] == 200          # refused per proposal, said why


def _occlusion(server, query: str):
    status, body, _ = _get(server, f"/api/occlusion?{query}")
    answer = json.loads(body)
    if status == 400 and any(w in answer["error"].lower() for w in ("renderer", "variant", "llvm")):
        pytest.skip(f"the twin's renderer cannot start here: {answer['error']}")
    return status, answer


def test_occlusion_of_a_cylinder_on_the_axis_is_its_near_face(server):
    status, occ = _occlusion(server, "part=cylinder&angle_deg=0")
    assert status == 200
    design = json.loads(_get(server, "/api/design")[1])
    radius, height = 50.0, 108.0                                     # scenes preset "cylinder": Ø100 × 108 mm
    # the sheet holds the axis: the profile is the rectangle 2R × H; the laser (at h = 0, below the top)
    # and the camera both reach only the near face, D = axis − R, over the whole height
    assert occ["fractions"]["seen"] == pytest.approx(height / (2 * height + 4 * radius), abs=0.01)
    seen = [(d0 + d1) / 2 for d0, _, d1, _, k in occ["segments"] if occ["classes"][int(k)] == "seen"]
    assert seen and all(abs(d - (design["axis_distance_mm"] - radius)) < 0.5 for d in seen)
    assert sum(occ["fractions"].values()) == pytest.approx(1.0)


def test_occlusion_of_a_knurled_ring_has_camera_shadow_and_a_turn(server):
    status, occ = _occlusion(server, "part=knurled-ring&angle_deg=30&turn=1")
    assert status == 200
    assert occ["fractions"]["camera_shadow"] > 0.005              # the teeth hide some of the lit flanks
    assert sum(occ["turn"].values()) == pytest.approx(1.0) and occ["turn"]["seen"] > 0.2


@pytest.mark.parametrize("query, words", [
    ("part=/etc/passwd.stl&angle_deg=0", "unknown (known: "),
    ("part=cylinder", "angle_deg"),
    ("part=cylinder&angle_deg=abc", "angle_deg"),
    ("part=cylinder&angle_deg=0&lens.focal_length_mm=-1", "focal_length_mm"),
])
def test_occlusion_refuses_what_is_not_a_preset_part_or_a_rig(server, query, words):
    status, body, _ = _get(server, f"/api/occlusion?{query}")
    assert status == 400 and words in json.loads(body)["error"]


def test_the_preview_frame_shows_the_stripe_where_the_engine_puts_it(server):
    status, body, ctype = _get(server, "/api/preview.png?part=cylinder&angle_deg=0")
    if status == 400 and any(w in json.loads(body)["error"].lower() for w in ("renderer", "variant", "llvm")):
        pytest.skip("the twin's renderer cannot start here")
    assert status == 200 and ctype == "image/png"
    import cv2
    import numpy as np

    image = cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_UNCHANGED)
    assert image.shape == (1936 // 4, 1216 // 4)                    # the paper sensor, 4 × 4 binned
    design = json.loads(_get(server, "/api/design")[1])
    # the cylinder's near face (D = axis − R, R = 50 mm) at the column D = F²/(u − u_h) gives, binned
    u = design["hinge_px"][0] + design["F2_px_mm"] / (design["axis_distance_mm"] - 50.0)
    rows = image[image.max(axis=1) > 128]
    assert len(rows) > 100
    assert np.median(rows.argmax(axis=1)) == pytest.approx((u + 0.5) / 4 - 0.5, abs=1.0)


def test_a_waiting_preview_is_superseded_by_a_newer_one(monkeypatch):
    import threading
    import time

    from scheimpflug.app.studio import preview

    monkeypatch.setattr(preview, "render_preview", lambda *a, **k: (time.sleep(0.3), (b"png", 0.3))[1])
    queue, results = preview.PreviewQueue(), {}

    def ask(name):
        try:
            results[name] = queue.render(None, "cylinder", 0.0)
        except preview.Superseded:
            results[name] = "superseded"

    threads = [threading.Thread(target=ask, args=(n,)) for n in ("first", "middle", "newest")]
    for t in threads:
        t.start()
        time.sleep(0.05)
    for t in threads:
        t.join()
    assert results == {"first": (b"png", 0.3), "middle": "superseded", "newest": (b"png", 0.3)}


def test_the_preview_refuses_an_unknown_part(server):
    status, body, _ = _get(server, "/api/preview.png?part=../../etc/passwd.stl&angle_deg=0")
    assert status == 400 and "unknown (known: " in json.loads(body)["error"]


def test_the_preview_refuses_a_giant_sensor(server):
    status, body, _ = _get(server, "/api/preview.png?part=cylinder&angle_deg=0&sensor.columns=60000&sensor.rows=60000"
                                   "&sensor.hinge_column=200000")
    assert status == 400 and "at most 2 Mpx" in json.loads(body)["error"]


@pytest.mark.parametrize("tilt_error_deg", [0.0, 1.5])
def test_the_f_number_for_a_sharp_sheet_is_the_smallest_that_holds_it(server, tilt_error_deg):
    from scheimpflug.app.studio.views import SAMPLES, focus_wedge

    query = f"sensor.tilt_error_deg={tilt_error_deg}"
    status, body, _ = _get(server, f"/api/focus?{query}")
    assert status == 200
    answer = json.loads(body)
    rig = api.rig_of_query(api.parse_query(query))
    cols = [-0.5 + k * rig.sensor.columns / (SAMPLES - 1) for k in range(SAMPLES)]

    def margin(n):
        return focus_wedge(rig.replace(lens={"f_number": n}, rederive=False), cols)["margin_mm"].min()

    need = rig.laser.waist_um * 1e-3
    assert margin(answer["f_number"]) >= need - 1e-9
    if tilt_error_deg == 0:
        assert answer["f_number"] == 0.5           # the hinge rule: the sheet is the plane of sharp focus
    else:
        assert margin(answer["f_number"] * 0.99) < need and 5.6 < answer["f_number"] < 256


def _post(srv, path: str, body: bytes, length: int | None = None) -> tuple[int, dict]:
    import http.client

    conn = http.client.HTTPConnection("127.0.0.1", srv.port, timeout=20)
    try:
        conn.putrequest("POST", path)
        conn.putheader("Content-Length", str(len(body) if length is None else length))
        conn.endheaders()
        if body:
            conn.send(body)
        resp = conn.getresponse()
        return resp.status, json.loads(resp.read())
    finally:
        conn.close()


def test_an_uploaded_mesh_is_a_part_for_the_occlusion(server, tmp_path):
    import trimesh

    box = trimesh.creation.box(extents=(60.0, 60.0, 80.0))
    box.apply_translation((0.0, 0.0, 40.0))                          # on the table, the axis through it
    status, answer = _post(server, "/api/mesh?name=block.stl", box.export(file_type="stl"))
    assert status == 200 and answer["part"].startswith("upload:") and answer["faces"] == 12
    status, occ = _occlusion(server, f"part={answer['part']}&angle_deg=0")
    assert status == 200 and occ["fractions"]["seen"] > 0.1
    for k in range(5):                                               # the oldest uploads are dropped
        other = trimesh.creation.box(extents=(10.0 + k, 10.0, 10.0))
        assert _post(server, f"/api/mesh?name=b{k}.ply", other.export(file_type="ply"))[0] == 200
    status, body, _ = _get(server, f"/api/occlusion?part={answer['part']}&angle_deg=0")
    assert status == 400 and "no such upload" in json.loads(body)["error"]


@pytest.mark.parametrize("name, body, length, status, words", [
    ("big.stl", b"solid x", 200 * 2**20, 413, "200.0 MB: at most 50 MB"),     # refused before it is read
    ("note.stl", b"this is not a mesh at all", None, 400, "note"),
    ("mesh.exe", b"MZ", None, 400, "a mesh file"),
])
def test_a_hostile_upload_is_refused_with_the_reason(server, name, body, length, status, words):
    got, answer = _post(server, f"/api/mesh?name={name}", body, length)
    assert got == status and words in answer["error"]
    assert len(list(server.upload_dir.iterdir())) <= 4                # nothing of it kept


def test_the_focus_map_covers_the_sensor_and_its_meridian_row_is_the_curve(server):
    views = json.loads(_get(server, "/api/studio?sensor.axis_row=968")[1])["views"]
    fm = views["focus_map"]
    assert len(fm["margin_mm"]) == len(fm["rows_px"]) == 17 and len(fm["margin_mm"][0]) == 33
    middle = fm["margin_mm"][8]                                      # row 968 = axis_row: the meridian row
    assert fm["rows_px"][8] == pytest.approx(967.5, abs=0.6)
    assert min(middle) == pytest.approx(min(m for m in views["curves"]["margin_mm"]), rel=0.05)
    rolled = json.loads(_get(server, "/api/studio?sensor.roll_deg=5")[1])["views"]["focus_map"]["margin_mm"]
    column = [row[16] for row in rolled]
    assert max(column) - min(column) > 0.1                           # a rolled sensor's margin changes along rows

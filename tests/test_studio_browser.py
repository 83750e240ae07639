"""``scheimpflug studio`` in a real browser: Playwright drives Debian's Chromium headless (issue 37).

Values are compared, not pixels: what the page shows against what ``scheimpflug design`` gives for the
rig the page encodes.  Skipped, saying why, without Chromium (``apt-get install chromium``) or the
Playwright package (the ``test`` extra).  Playwright's own browser download needs the internet; this
launches the system's ``chromium`` instead (``STUDIO_CHROMIUM`` names another executable).  With
``STUDIO_SCREENSHOTS=DIR`` the tutorial's screenshots are written to DIR
(``docs/tutorials/design-in-the-studio.md`` uses ``docs/studio_*.png``).
"""

from __future__ import annotations

import json
import os
import shutil
import threading
import urllib.request
from pathlib import Path

import pytest

from scheimpflug.app.cli import main
from scheimpflug.app.studio.server import make_server

CHROMIUM = os.environ.get("STUDIO_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
if not Path(CHROMIUM).is_file():
    pytest.skip(f"no Chromium at {CHROMIUM} (apt-get install -y chromium, or set STUDIO_CHROMIUM): "
                "the studio's browser tests are skipped", allow_module_level=True)
sync_api = pytest.importorskip("playwright.sync_api", reason="the Playwright package is not installed "
                               "(pip install -e '.[test]'): the studio's browser tests are skipped")

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu"]
IDLE = ("() => window.studio && window.studio.state.seq > 0 && !window.studio.state.inflight"
        " && window.studio.drawnSeq === window.studio.state.seq")
PREVIEW_DONE = ("() => Number(document.body.dataset.preview || 0) > 0 && !window.studio.state.preview.inflight"
                " && window.studio.state.preview.done === window.studio.state.preview.want")


@pytest.fixture(scope="module")
def server():
    srv = make_server(0)
    threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True).start()
    yield srv
    srv.shutdown()
    srv.server_close()


@pytest.fixture(scope="module")
def browser():
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        yield b
        b.close()


@pytest.fixture
def page(browser, server):
    pg = browser.new_page(viewport={"width": 1500, "height": 1000})
    problems: list[str] = []
    pg.on("pageerror", lambda e: problems.append(str(e)))
    pg.goto(server.url)
    pg.wait_for_function(IDLE, timeout=15000)
    yield pg
    pg.close()
    assert not problems, problems        # no JavaScript error, whatever the test typed


def _design(server, query: str) -> dict:
    with urllib.request.urlopen(f"{server.url}api/design?{query}", timeout=10) as r:
        return json.loads(r.read())


def _query(pg) -> str:
    """The query of the design the page shows (its address shows it too, a moment later)."""
    return pg.evaluate("window.studio.state.lastQuery")


def _shown(pg) -> dict[str, float | None]:
    """The datasheet as the page shows it (the full-precision value behind each cell)."""
    return pg.evaluate("""() => Object.fromEntries([...document.querySelectorAll('#datasheet tr[data-key]')]
        .map(tr => [tr.dataset.key, tr.querySelector('td.current').dataset.value === '' ? null
                    : Number(tr.querySelector('td.current').dataset.value)]))""")


def _agrees_with_design(shown: dict, design: dict) -> None:
    assert shown["range_z_mm"] == pytest.approx(design["depth_range_mm"], rel=1e-12)
    assert shown["field_x_near_mm"] == pytest.approx(design["height_range_near_mm"], rel=1e-12)
    assert shown["field_x_far_mm"] == pytest.approx(design["height_range_far_mm"], rel=1e-12)
    assert shown["dz_middle_um"] == pytest.approx(design["distance_resolution_center_mm"] * 1e3, rel=1e-12)
    assert shown["dx_middle_um"] == pytest.approx(design["height_resolution_center_mm"] * 1e3, rel=1e-12)
    assert shown["tilt_deg"] == pytest.approx(design["tilt_deg"], rel=1e-12)


def _drag(pg, name: str, dx: float) -> None:
    box = pg.locator(f'input[type=range][name="{name}"]').bounding_box()
    x, y = box["x"] + 0.25 * box["width"], box["y"] + box["height"] / 2
    pg.mouse.move(x, y)
    pg.mouse.down()
    pg.mouse.move(x + dx, y, steps=12)
    pg.mouse.up()
    pg.wait_for_function(IDLE, timeout=10000)


def _type(pg, name: str, text: str) -> None:
    pg.fill(f'input[type=text][name="{name}"]', text)
    pg.wait_for_function(IDLE, timeout=10000)


def test_dragging_a_slider_shows_what_design_gives(page, server):
    before = page.input_value('input[type=text][name="lens.focal_length_mm"]')
    _drag(page, "lens.focal_length_mm", 40)
    after = page.input_value('input[type=text][name="lens.focal_length_mm"]')
    assert after != before and "lens.focal_length_mm=" in _query(page)
    _agrees_with_design(_shown(page), _design(server, _query(page)))
    drawn = page.evaluate("window.studio.latencies.length")
    assert drawn >= 2                    # redrawn while the slider moved, not only on release


def test_an_invalid_value_is_explained_at_its_control_and_the_page_keeps_working(page, server):
    _type(page, "lens.f_number", "abc")
    why = page.inner_text('[id="ctl-lens.f_number"] .why')
    assert "[lens] f_number = 'abc': must be a number" in why
    _type(page, "lens.f_number", "8")
    _type(page, "laser.tan_phi", "10")   # a relation: d − f·tan φ must be > 0
    assert "d − f·tan φ" in page.inner_text('[id="ctl-laser.tan_phi"] .why')
    _type(page, "laser.tan_phi", "0.15")
    assert page.locator(".ctl.bad").count() == 0
    assert "lens.f_number=8" in _query(page) and "laser.tan_phi=0.15" in _query(page)
    _agrees_with_design(_shown(page), _design(server, _query(page)))


def test_a_warning_is_shown_at_the_control_it_names(page):
    _type(page, "stage.axis_mm", "900")
    assert "axis_mm = 900" in page.inner_text('[id="ctl-stage.axis_mm"] .warn')
    assert "warning" in page.inner_text("#plans")


def test_the_exported_rig_file_gives_the_pages_figures(page, server, tmp_path, capsys):
    _type(page, "lens.focal_length_mm", "35")
    _type(page, "sensor.pixel_pitch_um", "3.45")
    href = page.get_attribute("#export-toml", "href")
    with urllib.request.urlopen(server.url.rstrip("/") + href, timeout=10) as r:
        (tmp_path / "rig.toml").write_bytes(r.read())
    assert main(["design", "--rig", str(tmp_path / "rig.toml"), "--json"]) == 0
    _agrees_with_design(_shown(page), json.loads(capsys.readouterr().out))


def test_a_pinned_baseline_shows_the_differences_of_two_design_runs(page, server):
    base_query = _query(page)
    page.click("#pin")
    _type(page, "lens.focal_length_mm", "45")
    base, now = _design(server, base_query), _design(server, _query(page))
    change = page.evaluate("""() => Object.fromEntries([...document.querySelectorAll('#datasheet tr[data-key]')]
        .map(tr => [tr.dataset.key, Number(tr.querySelector('td.change').dataset.value)]))""")
    assert change["range_z_mm"] == pytest.approx(now["depth_range_mm"] - base["depth_range_mm"], rel=1e-9)
    assert change["dz_middle_um"] == pytest.approx(
        (now["distance_resolution_center_mm"] - base["distance_resolution_center_mm"]) * 1e3, rel=1e-9)
    assert change["tilt_deg"] == pytest.approx(now["tilt_deg"] - base["tilt_deg"], rel=1e-9)
    page.click("#unpin")
    assert page.locator("#datasheet td.change").count() == 0


def test_the_link_encodes_the_design(page, browser, server):
    _type(page, "laser.scheimpflug_distance_mm", "170")
    _type(page, "sensor.tilt_error_deg", "1")
    link = page.get_attribute("#export-link", "href")
    page.wait_for_function("() => location.search.slice(1) === window.studio.state.lastQuery")   # the address too
    assert link == page.url
    shown = _shown(page)
    other = browser.new_page()
    try:
        other.goto(link)
        other.wait_for_function(IDLE, timeout=15000)
        assert other.input_value('input[type=text][name="laser.scheimpflug_distance_mm"]') == "170"
        assert _shown(other) == shown
        assert shown["focus_margin_mm"] < 0          # the mis-tilted sensor leaves the wedge of focus
    finally:
        other.close()


def test_solve_for_a_range_then_apply_a_proposal(page, server):
    _type(page, "lens.focal_length_mm", "50")
    page.fill("#solve-near", "300")
    page.fill("#solve-far", "600")
    page.click("#solve button[type=submit]")
    page.wait_for_selector("#proposals li")
    page.locator("#proposals li button").first.click()
    page.wait_for_function(IDLE, timeout=10000)
    design = _design(server, _query(page))
    hinge_from_laser = 50 * (1 + float(page.input_value(
        'input[type=text][name="laser.tan_phi"]')) ** 2) ** 0.5
    assert [d + hinge_from_laser for d in design["distance_range_mm"]] == pytest.approx([300, 600], abs=1e-6)
    _agrees_with_design(_shown(page), design)


def test_the_f_number_for_a_sharp_sheet_applies(page, server):
    _type(page, "sensor.tilt_error_deg", "1.5")
    assert _shown(page)["focus_margin_mm"] < 0
    page.click("#focus")
    page.wait_for_selector("#focus-result button")
    assert page.inner_text("#focus-result").startswith("f/")
    page.click("#focus-result button")
    page.wait_for_function(IDLE, timeout=10000)
    assert _shown(page)["focus_margin_mm"] >= 0.15 - 1e-9        # the paper sheet's half-thickness, 150 µm
    _agrees_with_design(_shown(page), _design(server, _query(page)))


def _occlusion_shown(pg) -> dict[str, float]:
    return pg.evaluate("""() => Object.fromEntries([...document.querySelectorAll('#occ-result b')].slice(0, 5)
        .map(b => [b.dataset.class, Number(b.dataset.value)]))""")


def test_occlusion_on_a_part_follows_the_design_and_the_table(page, server):
    page.select_option("#occ-part", "sphere")
    page.check("#occ-on")
    page.wait_for_function("() => Number(document.body.dataset.occ || 0) > 0 && !window.studio.state.occ.inflight"
                           " && window.studio.state.occ.done === window.studio.state.occ.want", timeout=20000)
    if "renderer" in page.inner_text("#occ-result").lower():
        pytest.skip("the twin's renderer cannot start here")
    with urllib.request.urlopen(f"{server.url}api/occlusion?{_query(page)}&part=sphere&angle_deg=0",
                                timeout=20) as r:
        api = json.loads(r.read())["fractions"]
    assert _occlusion_shown(page) == pytest.approx(api, abs=1e-12)
    assert page.locator("#occ-layer line").count() > 50             # the profile drawn on the field
    page.locator("#occ-angle").fill("90")                           # a range input: fill sets it, fires input
    page.wait_for_function("() => window.studio.state.occ.angle === 90 && !window.studio.state.occ.inflight"
                           " && window.studio.state.occ.done === window.studio.state.occ.want", timeout=20000)
    assert page.inner_text("#occ-result").startswith("at 90°")
    page.click("#occ-turn")
    page.wait_for_function("() => document.querySelectorAll('#occ-result b').length === 10", timeout=20000)


def test_an_uploaded_mesh_is_checked_for_occlusion(page, tmp_path):
    import trimesh

    box = trimesh.creation.box(extents=(60.0, 60.0, 80.0))
    box.apply_translation((0.0, 0.0, 40.0))
    box.export(tmp_path / "block.stl")
    (tmp_path / "note.stl").write_text("not a mesh")
    page.set_input_files("#occ-file", str(tmp_path / "note.stl"))
    page.wait_for_function("() => document.getElementById('occ-result').textContent.includes('cannot read')"
                           " || document.getElementById('occ-result').textContent.startsWith('the upload')")
    assert "note.stl: cannot read" in page.inner_text("#occ-result")     # said with the user's file name
    page.set_input_files("#occ-file", str(tmp_path / "block.stl"))
    page.wait_for_function("() => document.getElementById('occ-part').value.startsWith('upload:')")
    page.wait_for_function("() => (window.studio.state.occ.last || {part: ''}).part.startsWith('upload:')"
                           " && !window.studio.state.occ.inflight", timeout=20000)
    assert _occlusion_shown(page)["seen"] > 0.1


def test_the_preview_arrives(page):
    page.select_option("#occ-part", "sphere")
    page.check("#prev-on")
    page.wait_for_function(PREVIEW_DONE, timeout=30000)
    caption = page.inner_text("#preview-cap")
    if "renderer" in caption.lower():
        pytest.skip("the twin's renderer cannot start here")
    assert "rendered in" in caption
    page.wait_for_function("() => document.getElementById('preview-img').naturalWidth > 0")
    assert page.evaluate("document.getElementById('preview-img').naturalWidth") == 1216 // 4


def test_tutorial_screenshots(page, server, tmp_path):
    out = Path(os.environ.get("STUDIO_SCREENSHOTS") or tmp_path)
    out.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(out / "studio_start.png"), full_page=True)
    page.click("#pin")
    _drag(page, "lens.focal_length_mm", -30)
    page.screenshot(path=str(out / "studio_baseline.png"))
    _type(page, "sensor.tilt_error_deg", "1.5")
    page.locator("#meridian").screenshot(path=str(out / "studio_mistilt.png"))
    _type(page, "sensor.tilt_error_deg", "0")
    _type(page, "laser.tan_phi", "10")
    page.locator("#controls").screenshot(path=str(out / "studio_error.png"))
    _type(page, "laser.tan_phi", "0.2075")
    page.click("#unpin")
    page.fill("#solve-near", "300")
    page.fill("#solve-far", "600")
    page.click("#solve button[type=submit]")
    page.wait_for_selector("#proposals li")
    page.locator("figure:has(#proposals)").screenshot(path=str(out / "studio_solve.png"))
    page.select_option("#preset", "paper")                          # the paper rig again: its axis in view
    page.wait_for_function(IDLE, timeout=10000)
    page.select_option("#occ-part", "pile")
    page.locator("#occ-angle").fill("20")
    page.click("#occ-turn")
    page.wait_for_function("() => document.querySelectorAll('#occ-result b').length === 10", timeout=30000)
    page.check("#prev-on")
    page.wait_for_function(PREVIEW_DONE, timeout=30000)
    page.locator("figure:has(#occ-result)").screenshot(path=str(out / "studio_occlusion.png"))
    names = ("start", "baseline", "mistilt", "error", "solve", "occlusion")
    assert all((out / f"studio_{n}.png").stat().st_size > 10_000 for n in names)

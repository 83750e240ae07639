"""`scheimpflug import` against a hostile user (issue 34 items 2–5, 8, 10–12, 14 and progress; issue 38's
room light): each test failed on the import of before (named in its docstring) and passes now.

Small synthetic frames written with OpenCV in ``tmp_path``; the tests about real frames read
``../shared/realdata/`` and skip, saying so, where it is absent.
"""

import json
import os
import signal
import struct
import subprocess
import sys
import warnings
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from synth_frames import grey_pngs

from scheimpflug.app.cli import main
from scheimpflug.errors import FrameError
from scheimpflug.io.folder import LOCK_NAME, FolderLock
from scheimpflug.io.frames import open_frame_folder
from scheimpflug.io.importer import (
    frames_with_angles,
    import_frames,
    natural_key,
    positions_from_names,
    read_image,
    stripe_direction,
    target_frames,
)

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "realdata"
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason=f"real frames absent ({REAL}): see its README")


def _fails(args, capsys, *needles):
    """The command fails with one error line (warnings before it are fine) and no traceback."""
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    lines = [line for line in err.splitlines() if not line.startswith("warning")]
    assert len(lines) == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in err, err
    return err


_grey = grey_pngs


def _stripe(seed, across=False, shape=(48, 64), peak=900.0, back=None):
    """A 12-bit frame with a slanted Gaussian stripe down the image (or across it) on noise."""
    rng = np.random.default_rng(seed)
    r, c = np.mgrid[:shape[0], :shape[1]].astype(np.float64)
    dist = r - (0.4 * shape[0] + 0.1 * c) if across else c - (0.4 * shape[1] + 0.15 * r)
    base = 100.0 + rng.normal(0.0, 3.0, shape) if back is None else back
    return np.clip(base + peak * np.exp(-0.5 * (dist / 1.5) ** 2), 0, 4095).astype(np.uint16)


def _write(tmp_path, name, img):
    p = tmp_path / name
    assert cv2.imwrite(str(p), img)
    return p


def _manifest(folder):
    return json.loads((Path(folder) / "manifest.json").read_text())


# ------------------------------------------------------------------ item 2: truncated files


def test_a_truncated_jpeg_is_refused_naming_the_file(tmp_path, capsys):
    """It was imported (exit 0), its lower half the value 128; libjpeg's warning did not name the file."""
    rng = np.random.default_rng(1)
    files = [_write(tmp_path, f"s_{k}.jpg", rng.integers(0, 255, (60, 80, 3), dtype=np.uint8)) for k in range(3)]
    data = files[1].read_bytes()
    files[1].write_bytes(data[:len(data) // 2])
    _fails(["import", *map(str, files), "--channel", "r", "--angles-deg=0:1", "--out", str(tmp_path / "o")], capsys,
           "'" + str(files[1]) + "' is truncated", "end-of-image marker")
    assert not (tmp_path / "o").exists()
    files[1].write_bytes(data + b"\x00" * 7)               # bytes after the end-of-image marker are fine
    assert read_image(files[1], "r").shape == (60, 80)


def test_a_truncated_png_says_truncated(tmp_path):
    """It was called 'unreadable or corrupt'."""
    p = _write(tmp_path, "t.png", np.random.default_rng(2).integers(0, 4095, (40, 50)).astype(np.uint16))
    p.write_bytes(p.read_bytes()[:-12])                    # without its IEND chunk
    with pytest.raises(FrameError, match=r"t.png' is truncated: it ends before its IEND chunk"):
        read_image(p)


@needs_real
def test_half_of_a_fabscan_jpeg_is_refused(tmp_path, capsys):
    """The issue's case: half a FabScan JPEG's bytes, exit 0, the missing half grey."""
    src = sorted((REAL / "fabscan" / "scan-2_1").glob("*.jpg"))[:3]
    half = tmp_path / src[1].name
    half.write_bytes(src[1].read_bytes()[:src[1].stat().st_size // 2])
    err = _fails(["import", str(src[0]), str(half), str(src[2]), "--channel", "r", "--angles-deg=0:1.8", "--out",
                  str(tmp_path / "o")], capsys, str(half), "truncated")
    assert "Premature end of JPEG file" not in err


# ------------------------------------------------------------------ item 10: multi-page TIFF


def test_a_multi_page_tiff_is_refused_with_its_page_count(tmp_path, capsys):
    """Its first page was imported without a word."""
    pages = [np.full((20, 30), 100 * k, np.uint16) for k in range(1, 4)]
    multi = tmp_path / "m_1.tif"
    assert cv2.imwritemulti(str(multi), pages)
    files = [_write(tmp_path, "m_0.tif", pages[0] + 7), multi]
    _fails(["import", *map(str, files), "--positions-from-names", "m_{stage_mm}.tif", "--out", str(tmp_path / "o")],
           capsys, "'" + str(multi) + "' holds 3 pages (a multi-page TIFF)")
    assert read_image(files[0]).shape == (20, 30)          # a one-page TIFF is fine
    if hasattr(cv2, "imwriteanimation"):                    # an animated PNG likewise
        anim = cv2.Animation()
        anim.frames, anim.durations = [np.full((20, 30, 3), 50 * k, np.uint8) for k in range(1, 3)], [100, 100]
        assert cv2.imwriteanimation(str(tmp_path / "a.png"), anim)
        with pytest.raises(FrameError, match=r"a.png' holds 2 pages \(a multi-page PNG \(animated\)\)"):
            read_image(tmp_path / "a.png", "r")


# ------------------------------------------------------------------ item 3: the stripe's direction


def test_the_stripe_direction_of_one_frame():
    assert stripe_direction(_stripe(0)) == "columns"
    assert stripe_direction(_stripe(0, across=True)) == "rows"
    assert stripe_direction(np.full((48, 64), 300, np.uint16)) is None
    noise = np.random.default_rng(3).normal(500, 20, (48, 64)).astype(np.uint16)
    assert stripe_direction(noise) is None


@pytest.mark.parametrize("across, want", [(False, "columns"), (True, "rows")])
def test_import_finds_the_stripe_direction_and_records_it(tmp_path, capsys, across, want):
    """It recorded "columns" whatever the frames showed (FabScan's frames: a garbage cloud, exit 0)."""
    files = [_write(tmp_path, f"f_{k}.png", _stripe(k, across)) for k in range(4)]
    capsys.readouterr()
    assert main(["import", *map(str, files), "--angles-deg=0:1", "--out", str(tmp_path / "o"), "--json"]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["stripe_along"] == want and f"stripe_along {want}" in out.err
    assert "found in 4 of the 4 frame(s)" in out.err
    m = _manifest(tmp_path / "o")
    assert m["stripe_along"] == want and open_frame_folder(tmp_path / "o").stripe_along == want
    assert m["stripe_detection"] == {"given": "auto", "found": want, "examined": 4, want: 4,
                                     ({"columns", "rows"} - {want}).pop(): 0, "unclear": 0}


def test_a_stripe_direction_the_frames_contradict_is_refused(tmp_path, capsys):
    """`--stripe-along columns` on frames whose stripe runs across them was imported (exit 0)."""
    files = [_write(tmp_path, f"f_{k}.png", _stripe(k, across=True)) for k in range(4)]
    _fails(["import", *map(str, files), "--angles-deg=0:1", "--stripe-along", "columns", "--out",
            str(tmp_path / "o")], capsys, "--stripe-along columns, but the stripe runs across the image",
           "in 4 of the 4", "--stripe-along rows")
    assert not (tmp_path / "o").exists()
    assert main(["import", *map(str, files), "--angles-deg=0:1", "--stripe-along", "rows", "--out",
                 str(tmp_path / "o")]) == 0


def test_a_weak_contradiction_is_a_warning_and_disagreeing_frames_an_error(tmp_path, capsys):
    files = [_write(tmp_path, "f_0.png", _stripe(0, across=True))]
    files += [_write(tmp_path, f"f_{k}.png", np.full((48, 64), 100 + k, np.uint16)) for k in (1, 2, 3)]
    capsys.readouterr()
    assert main(["import", *map(str, files), "--angles-deg=0:1", "--stripe-along", "columns", "--out",
                 str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert "warning: --stripe-along columns, but the stripe runs across the image (one point per column) in 1 of " \
           "the 4" in err and "kept as given" in err
    mixed = [_write(tmp_path, f"g_{k}.png", _stripe(k, across=k % 2 == 1)) for k in range(4)]
    _fails(["import", *map(str, mixed), "--angles-deg=0:1", "--out", str(tmp_path / "p")], capsys,
           "the frames disagree on the stripe's direction", "give --stripe-along columns or rows")


def test_frames_without_a_stripe_are_said_to_have_none(tmp_path, capsys):
    files = _grey(tmp_path, ["u_0.png", "u_1.png"])
    capsys.readouterr()
    assert main(["import", *map(str, files), "--angles-deg=0:1", "--out", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert "warning: no laser stripe found in the 2 frame(s)" in err and "assumed, no stripe found" in err
    assert _manifest(tmp_path / "o")["stripe_detection"]["found"] is None


def test_a_pattern_sets_stripe_is_found_in_its_laser_frames_only(tmp_path, capsys):
    """Flood frames hold no stripe (here: a ridge the other way, which must not vote)."""
    flood = [_write(tmp_path, f"p{k}.png", _stripe(10 + k, across=False, peak=2000.0)) for k in range(3)]
    laser = [_write(tmp_path, f"p{k}_laser.png", _stripe(20 + k, across=True)) for k in range(3)]
    (tmp_path / "poses.csv").write_text("file,pose,light\n" + "".join(
        f"p{k}.png,{k},flood\np{k}_laser.png,{k},laser\n" for k in range(3)))
    capsys.readouterr()
    assert main(["import", *map(str, flood + laser), "--scenario", "target", "--positions",
                 str(tmp_path / "poses.csv"), "--out", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    m = _manifest(tmp_path / "o")
    assert m["stripe_along"] == "rows" and m["stripe_detection"]["examined"] == 3, err
    assert "import: 3 poses, 6 frames (3 poses: 3 flood, 3 laser)" in err
    assert main(["import", *map(str, flood), "--scenario", "target", "--out", str(tmp_path / "f")]) == 0
    err = capsys.readouterr().err
    assert "no laser frames to examine" in err and "warning" not in err
    assert _manifest(tmp_path / "f")["stripe_detection"]["examined"] == 0


@needs_real
def test_fabscan_frames_imported_without_a_direction_run_along_the_rows(tmp_path, capsys):
    """The issue's case: imported without --stripe-along rows they gave a garbage cloud (exit 0)."""
    files = [str(f) for f in sorted((REAL / "fabscan" / "scan-2_1").glob("*.jpg"))[:200:40]]
    assert main(["import", *files, "--channel", "r", "--angles-deg=-1.8:-1.8", "--out", str(tmp_path / "o")]) == 0
    m = _manifest(tmp_path / "o")
    assert m["stripe_along"] == "rows" and m["stripe_detection"]["rows"] == len(files)
    _fails(["import", *files, "--channel", "r", "--angles-deg=-1.8:-1.8", "--stripe-along", "columns", "--out",
            str(tmp_path / "p")], capsys, "--stripe-along columns, but the stripe runs across the image")


@needs_real
def test_3dscanscience_laser_frames_run_down_the_image(tmp_path):
    folder = REAL / "3dscanscience" / "laser-on-object"
    import_frames(frames_with_angles([folder / "laser.png"], [0.0]), tmp_path / "o", channel="r",
                  backgrounds=[folder / "laser_background.png"])
    assert _manifest(tmp_path / "o")["stripe_along"] == "columns"


# ------------------------------------------------------------------ item 3: EXIF orientation


def _exif(tag):
    """A TIFF-structured EXIF block with one entry: orientation (274) = tag."""
    return b"II*\x00" + struct.pack("<IHHHIHHI", 8, 1, 274, 3, 1, tag, 0, 0)


def _jpeg_with_orientation(path, img, tag):
    ok, buf = cv2.imencode(".jpg", img)
    app1 = b"Exif\x00\x00" + _exif(tag)
    data = buf.tobytes()
    path.write_bytes(data[:2] + b"\xff\xe1" + struct.pack(">H", len(app1) + 2) + app1 + data[2:])
    return path


def _png_with_orientation(path, img, tag):
    ok, buf = cv2.imencode(".png", img)
    data, body = buf.tobytes(), _exif(tag)
    chunk = struct.pack(">I", len(body)) + b"eXIf" + body + struct.pack(">I", zlib.crc32(b"eXIf" + body))
    path.write_bytes(data[:33] + chunk + data[33:])        # after the signature and IHDR
    return path


def test_an_exif_orientation_is_named_and_recorded_not_applied(tmp_path, capsys):
    """An orientation tag 6 was ignored without a note."""
    from PIL import Image

    rng = np.random.default_rng(4)
    files = [_jpeg_with_orientation(tmp_path / f"e_{k}.jpg", rng.integers(0, 255, (24, 40, 3), dtype=np.uint8), 6)
             for k in range(2)]
    assert Image.open(files[0]).getexif()[274] == 6          # a tag other readers see
    capsys.readouterr()
    assert main(["import", *map(str, files), "--channel", "r", "--angles-deg=0:1", "--out", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert "warning: 2 frame(s) carry an EXIF orientation tag" in err
    assert f"'{files[0]}' (orientation 6: turn it 90° clockwise)" in err and "imported as stored" in err
    m = _manifest(tmp_path / "o")
    assert m["exif_orientation"] == "stored" and [e["exif_orientation"] for e in m["frames"]] == [6, 6]
    assert open_frame_folder(tmp_path / "o").read(0).shape == (24, 40)
    assert main(["import", *map(str, files), "--channel", "r", "--angles-deg=0:1", "--exif-orientation", "apply",
                 "--out", str(tmp_path / "a")]) == 0
    assert "EXIF" not in capsys.readouterr().err
    assert _manifest(tmp_path / "a")["exif_orientation"] == "applied"
    assert open_frame_folder(tmp_path / "a").read(0).shape == (40, 24)


@pytest.mark.parametrize("tag", range(1, 9))
def test_an_applied_exif_orientation_turns_the_frame_as_viewers_do(tmp_path, tag):
    from PIL import Image, ImageOps

    img = np.random.default_rng(tag).integers(0, 255, (5, 7), dtype=np.uint8)
    p = _png_with_orientation(tmp_path / "o.png", img, tag)
    shown = np.asarray(ImageOps.exif_transpose(Image.open(p)))      # Pillow, an independent reader
    np.testing.assert_array_equal(read_image(p, exif_orientation="apply"), shown)  # exact: copy (a permutation)
    np.testing.assert_array_equal(read_image(p), img)                # exact: copy (as stored)


# ------------------------------------------------------------------ item 4: natural order, and the order printed


def test_a_folder_is_taken_in_natural_order_and_the_order_printed(tmp_path, capsys):
    """frame0, frame1, frame10, frame11, frame2 got their angles in that (text) order."""
    src = tmp_path / "src"
    src.mkdir()
    _grey(src, [f"frame{k}.png" for k in (0, 1, 10, 11, 2)])
    capsys.readouterr()
    assert main(["import", str(src), "--angles-deg=0:10", "--out", str(tmp_path / "o"), "--json"]) == 0
    out = capsys.readouterr()
    got = [(Path(e["source_file"]).name, e["angle_deg"]) for e in _manifest(tmp_path / "o")["frames"]]
    assert got == [("frame0.png", 0), ("frame1.png", 10), ("frame2.png", 20), ("frame10.png", 30), ("frame11.png", 40)]
    assert [(o["file"], o["angle_deg"]) for o in json.loads(out.out)["order"]] == got
    assert "order: frame0.png (0), frame1.png (10), frame2.png (20), frame10.png (30), frame11.png (40)" in out.err
    assert sorted(["f10.png", "f2.png", "f1.png"], key=natural_key) == ["f1.png", "f2.png", "f10.png"]


def test_files_listed_in_text_order_whose_order_sets_their_angles_are_warned_of(tmp_path, capsys):
    files = _grey(tmp_path, [f"frame{k}.png" for k in (0, 1, 10, 2)])
    capsys.readouterr()
    assert main(["import", *map(str, files), "--angles-deg=0:10", "--out", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert "warning: the frames are taken in the order given, which sorts their names as text ('frame10.png' " \
           "before 'frame2.png'" in err


@needs_real
def test_3dscanscience_frames_become_poses_in_their_numbers_order(tmp_path, capsys):
    """The set's names frame0 … frame15 were posed 0, 1, 10, 11, … (text order)."""
    assert main(["import", str(REAL / "3dscanscience" / "camera-calibration"), "--scenario", "target",
                 "--channel", "gray", "--out", str(tmp_path / "o"), "--quiet"]) == 0
    frames = _manifest(tmp_path / "o")["frames"]
    assert [(Path(e["source_file"]).name, e["pose"]) for e in frames] == [(f"frame{k}.jpg", k) for k in range(16)]
    assert "import: 16 poses, 16 frames (16 poses: 16 flood)" in capsys.readouterr().err


# ------------------------------------------------------------------ item 5: colour beside grey


def _colour(tmp_path, name, red, seed=0):
    img = np.random.default_rng(seed).integers(0, 40, (20, 30, 3), dtype=np.uint8)
    img[:, :, 2] = red
    return _write(tmp_path, name, img)


def test_a_grey_frame_beside_a_colour_frame_is_refused(tmp_path, capsys):
    """The grey file's luminance was taken beside the colour file's red, the manifest saying channel r for both."""
    c = _colour(tmp_path, "c_0.png", 200)
    g = _write(tmp_path, "c_1.png", np.full((20, 30), 90, np.uint8))
    _fails(["import", str(c), str(g), "--channel", "r", "--positions-from-names", "c_{stage_mm}.png", "--out",
            str(tmp_path / "o")], capsys, f"frame '{g}' is grey but '{c}' is colour")
    assert not (tmp_path / "o").exists()


def test_grey_backgrounds_of_colour_frames_are_refused(tmp_path, capsys):
    """A grey background was subtracted from the colour frames' red channel."""
    frames = [_colour(tmp_path, f"laser_{k}.png", 150 + k, seed=k) for k in range(2)]
    for k in range(2):
        _write(tmp_path, f"off_{k}.png", np.full((20, 30), 30, np.uint8))
    _fails(["import", *map(str, frames), "--channel", "r", "--angles-deg=0:1", "--background-names", "laser=off",
            "--out", str(tmp_path / "o")], capsys, f"background '{tmp_path / 'off_0.png'}' is grey",
           f"'{frames[0]}' is colour")


def test_a_channel_for_grey_frames_is_not_recorded(tmp_path, capsys):
    files = _grey(tmp_path, ["g_0.png", "g_1.png"])
    capsys.readouterr()
    assert main(["import", *map(str, files), "--channel", "r", "--angles-deg=0:1", "--out", str(tmp_path / "o")]) == 0
    assert "--channel r has no effect: every frame is grey" in capsys.readouterr().err
    assert "channel" not in _manifest(tmp_path / "o")


# ------------------------------------------------------------------ items 8 and 12: the target CSV


def test_a_target_csv_listing_a_file_twice_is_refused_and_unused_rows_named(tmp_path):
    """The last row won silently; rows for files not given were dropped without a word."""
    files = _grey(tmp_path, ["p0.png", "p1.png"])
    (tmp_path / "twice.csv").write_text("file,pose,light\np0.png,0,flood\np1.png,1,flood\np0.png,0,laser\n")
    with pytest.raises(FrameError, match=r"lists 'p0.png' twice \(lines 2 and 4\)"):
        target_frames(files, tmp_path / "twice.csv")
    (tmp_path / "more.csv").write_text("file,pose,light\np0.png,0,flood\np1.png,1,flood\np9.png,9,laser\n")
    with pytest.warns(UserWarning, match="1 row\\(s\\) for files not given are left out: 'p9.png'"):
        assert len(target_frames(files, tmp_path / "more.csv")) == 2


def test_a_short_row_in_a_target_csv_names_the_file_and_line(tmp_path, capsys):
    """It was `internal error: IndexError` (exit 70)."""
    files = _grey(tmp_path, ["p0.png", "p1.png"])
    (tmp_path / "short.csv").write_text("pose,light,file\n0,flood,p0.png\n1,flood\n")
    _fails(["import", *map(str, files), "--scenario", "target", "--positions", str(tmp_path / "short.csv"),
            "--out", str(tmp_path / "o")], capsys, f"'{tmp_path / 'short.csv'}' line 3 has 2 cell(s) but needs 3")


# ------------------------------------------------------------------ item 11: killed imports, the folder's mode


def test_a_killed_imports_temporary_folder_is_removed_by_the_next_import(tmp_path):
    """kill -9 left a hidden .NAME.xxxx folder that nothing removed."""
    files = _grey(tmp_path, ["p_0.png", "p_1.png"])
    out = tmp_path / "o"
    script = ("import os, signal\nimport scheimpflug.io.importer as imp\n"
              "imp._move_into_place = lambda tmp, out: os.kill(os.getpid(), signal.SIGKILL)\n"
              f"imp.import_frames(imp.positions_from_names({[str(f) for f in files]!r}, 'p_{{stage_mm}}.png'), "
              f"{str(out)!r}, stripe_along='columns')\n")
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, cwd=ROOT)
    assert res.returncode == -signal.SIGKILL, res.stderr
    dead = [p for p in tmp_path.iterdir() if p.name.startswith(".o.")]
    assert len(dead) == 1 and (dead[0] / LOCK_NAME).is_file() and not out.exists()
    ownerless, live = tmp_path / ".o.zzzzzzzz", tmp_path / ".o.running1"
    ownerless.mkdir()
    live.mkdir()
    with FolderLock(live), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        import_frames(positions_from_names(files, "p_{stage_mm}.png"), out, stripe_along="columns")
    said = " ".join(str(w.message) for w in caught)
    assert not dead[0].exists() and f"removed '{dead[0]}'" in said
    assert ownerless.is_dir() and f"'{ownerless}' looks like the temporary folder" in said
    assert live.is_dir() and str(live) not in said                   # a running import's folder is left alone
    assert (out / "manifest.json").is_file() and not (out / LOCK_NAME).exists()


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_the_output_folder_gets_the_umasks_mode(tmp_path, umask):
    """It was 0700 (tempfile.mkdtemp's) whatever the umask."""
    files = _grey(tmp_path, ["p_0.png", "p_1.png"])
    old = os.umask(umask)
    try:
        out = import_frames(positions_from_names(files, "p_{stage_mm}.png"), tmp_path / "o", stripe_along="columns")
    finally:
        os.umask(old)
    assert out.stat().st_mode & 0o777 == 0o777 & ~umask


# ------------------------------------------------------------------ item 14: messages and outputs


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="no /proc here")
def test_an_output_that_cannot_be_created_is_named(tmp_path, capsys):
    """`--out /proc/x` named a temporary path (/proc/.x.abcd1234)."""
    files = _grey(tmp_path, ["p_0.png"])
    err = _fails(["import", str(files[0]), "--angles-deg=0", "--out", "/proc/x"], capsys, "'/proc/x'")
    assert "/proc/.x." not in err


def test_an_output_that_is_a_file_is_named_as_a_file(tmp_path, capsys):
    """It said "folder … exists and is not empty"."""
    files = _grey(tmp_path, ["p_0.png"])
    (tmp_path / "f.txt").write_text("x")
    err = _fails(["import", str(files[0]), "--angles-deg=0", "--out", str(tmp_path / "f.txt")], capsys,
                 "is a file, not a folder")
    assert "not empty" not in err


@pytest.mark.parametrize("value", ["nan", "inf", "0", "-5"])
def test_a_plate_height_that_is_not_a_positive_number_is_refused_at_import(tmp_path, capsys, value):
    """`--plate-height-mm nan` was written as a bare NaN into manifest.json (invalid JSON)."""
    files = _grey(tmp_path, ["p_0.png", "p_1.png"])
    _fails(["import", *map(str, files), "--positions-from-names", "p_{stage_mm}.png", "--plate-height-mm", value,
            "--out", str(tmp_path / "o")], capsys, "--plate-height-mm")
    assert not (tmp_path / "o").exists()


def test_non_finite_scenario_parameters_are_refused_by_the_library(tmp_path):
    files = positions_from_names(_grey(tmp_path, ["p_0.png", "p_1.png"]), "p_{stage_mm}.png")
    with pytest.raises(FrameError, match=r"^plate_height_mm = nan: must be a finite number > 0$") as info:
        import_frames(files, tmp_path / "o", scenario_params={"plate_height_mm": np.float64("nan")})
    assert "np.float64" not in str(info.value) and not (tmp_path / "o").exists()
    with pytest.raises(FrameError, match="step_mm = inf"):
        import_frames(files, tmp_path / "o", scenario_params={"step_mm": float("inf")})


# ------------------------------------------------------------------ progress


def test_import_reports_progress_and_the_command_shows_a_bar(tmp_path, capsys, monkeypatch):
    """`import` showed no progress, and had no --quiet."""
    import scheimpflug.app.commands.import_frames as command

    files = _grey(tmp_path, ["p_0.png", "p_1.png", "p_2.png"])
    calls = []
    import_frames(positions_from_names(files, "p_{stage_mm}.png"), tmp_path / "lib",
                  progress=lambda done, total: calls.append((done, total)))
    assert calls == [(k, 6) for k in range(1, 7)]
    monkeypatch.setattr(command, "_BAR_DELAY_S", 0.0)
    capsys.readouterr()
    args = ["import", *map(str, files), "--positions-from-names", "p_{stage_mm}.png", "--out"]
    assert main([*args, str(tmp_path / "o")]) == 0
    assert "import         [####################] 6/6" in capsys.readouterr().err
    assert main([*args, str(tmp_path / "q"), "--quiet"]) == 0
    assert "6/6" not in capsys.readouterr().err


# ------------------------------------------------------------------ issue 38: pattern sets in room light


def test_a_room_light_set_pairs_each_laser_frame_with_its_poses_laser_off_frame(tmp_path, capsys):
    """`--room-light` did not exist."""
    rng = np.random.default_rng(7)
    files, rows = [], []
    for k in range(3):
        room = np.clip(rng.normal(2000, 300, (48, 64)), 0, 4095)          # a lit, textured board
        files += [_write(tmp_path, f"p{k}_off.png", room.astype(np.uint16)),
                  _write(tmp_path, f"p{k}_on.png", _stripe(k, across=True, peak=300.0, back=room))]
        rows += [f"p{k}_off.png,{k},flood\n", f"p{k}_on.png,{k},laser\n"]
    files.append(_write(tmp_path, "p3_on.png", _stripe(3, across=True, peak=300.0, back=room + 5)))
    rows.append("p3_on.png,3,laser\n")
    (tmp_path / "poses.csv").write_text("file,pose,light\n" + "".join(rows))
    base = ["import", *map(str, files), "--scenario", "target", "--positions", str(tmp_path / "poses.csv")]
    capsys.readouterr()
    assert main([*base, "--room-light", "--out", str(tmp_path / "o"), "--json"]) == 0
    out = capsys.readouterr()
    m = _manifest(tmp_path / "o")
    assert m["scenario_params"]["room_light"] is True and json.loads(out.out)["room_light"] is True
    by_file = {Path(e["source_file"]).name: e for e in m["frames"]}
    for k in range(3):
        assert by_file[f"p{k}_on.png"]["laser_off_file"] == by_file[f"p{k}_off.png"]["file"]
    assert "laser_off_file" not in by_file["p3_on.png"]
    assert "laser frame(s) without a laser-off (flood) frame of their pose ('p3_on.png' (pose 3))" in out.err
    assert "import: 4 poses, 7 frames (4 poses: 3 flood, 4 laser), room light" in out.err
    # the line is found in the differences; in the frames as taken the room's light hides it
    assert m["stripe_along"] == "rows" and m["stripe_detection"]["rows"] == 3
    assert main([*base, "--out", str(tmp_path / "p")]) == 0
    assert _manifest(tmp_path / "p")["stripe_detection"]["found"] is None and "room_light" not in _manifest(
        tmp_path / "p")["scenario_params"]


def test_room_light_is_for_pattern_sets(tmp_path, capsys):
    files = _grey(tmp_path, ["p_0.png"])
    _fails(["import", str(files[0]), "--angles-deg=0", "--room-light", "--out", str(tmp_path / "o")], capsys,
           "--room-light marks a pattern set's frames (--scenario target)")


def test_the_copy_of_the_frames_is_lossless_after_all_checks(tmp_path):
    """The files are read twice (their structure, their pixels): the frame written is still the file's."""
    img = np.random.default_rng(8).integers(0, 4095, (30, 40)).astype(np.uint16)
    files = [_write(tmp_path, "x_1.tif", img), _write(tmp_path, "x_3.tif", img + 1)]
    out = import_frames(positions_from_names(files, "x_{stage_mm}.tif"), tmp_path / "o", stripe_along="columns")
    np.testing.assert_array_equal(open_frame_folder(out).read(0), img)   # exact: copy (lossless PNG)

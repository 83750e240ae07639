"""`scheimpflug import`: positions from a CSV or file names; one clear error per bad input."""

import json

import cv2
import numpy as np
import pytest
from synth_frames import grey_pngs

from scheimpflug.app.cli import main
from scheimpflug.errors import FrameError
from scheimpflug.io.frames import open_frame_folder
from scheimpflug.io.importer import import_frames, positions_from_csv, positions_from_names, target_frames

_frames = grey_pngs


def test_positions_from_names_and_csv(tmp_path):
    files = _frames(tmp_path, ["a_10p5.tif", "a_-2.tif", "a_3e1.png"])
    got = positions_from_names(files, "a_{stage_mm}.*")
    assert [f.value for f in got] == [10.5, -2.0, 30.0]
    (tmp_path / "pos.csv").write_text("file,angle_deg\na_10p5.tif,0\na_-2.tif,1.5\na_3e1.png,3\n")
    assert [f.value for f in positions_from_csv(files, tmp_path / "pos.csv")] == [0.0, 1.5, 3.0]
    out = import_frames(got, tmp_path / "out", adc_bits=12)
    ff = open_frame_folder(out)
    assert [r.stage_mm for r in ff.frames] == [-2.0, 10.5, 30.0] and ff.adc_bits == 12
    assert int(ff.read(0)[0, 0]) == 101 and ff.read(0).dtype == np.uint16


def test_cli_json(tmp_path, capsys):
    _frames(tmp_path, ["s_1.png", "s_2.png", "s_3.png"])
    assert main(["import", str(tmp_path), "--positions-from-names", "s_{angle_deg}.png", "--out",
                 str(tmp_path / "o"), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["frames"] == 3 and d["key"] == "angle_deg"


@pytest.mark.parametrize("case", ["missing", "non-numeric", "sizes", "depths", "unreadable"])
def test_bad_input_is_one_clear_error_naming_the_file(tmp_path, case):
    files = _frames(tmp_path, ["p_1.png", "p_2.png"])
    bad = tmp_path / "p_3.png"
    if case == "sizes":
        files += _frames(tmp_path, ["p_3.png"], shape=(21, 30))
    elif case == "depths":
        files += _frames(tmp_path, ["p_3.png"], dtype=np.uint8)
    elif case == "unreadable":
        bad.write_bytes(b"not an image at all")
        files.append(bad)
    elif case == "non-numeric":
        bad = tmp_path / "p_x.png"
        files += _frames(tmp_path, ["p_x.png"])
    if case == "missing":
        (tmp_path / "pos.csv").write_text("file,stage_mm\np_1.png,1\n")
        with pytest.raises(FrameError, match="p_2.png"):
            positions_from_csv(files, tmp_path / "pos.csv")
        return
    with pytest.raises(FrameError, match=bad.name):
        import_frames(positions_from_names(files, "p_{stage_mm}.png"), tmp_path / "out")
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------ frames as real cameras give them (issue 24 item 3)

def _rgb(tmp_path, name, bgr, shape=(24, 32), suffix=".png"):
    img = np.zeros((*shape, 3), np.uint8)
    img[:] = bgr
    p = tmp_path / f"{name}{suffix}"
    assert cv2.imwrite(str(p), img)
    return p


@pytest.mark.parametrize("channel, want", [("r", 200), ("g", 50), ("b", 10),
                                           ("gray", round(0.299 * 200 + 0.587 * 50 + 0.114 * 10)),
                                           ("0.5,0.5,0", 125)])
def test_a_colour_frame_becomes_the_grey_frame_its_channel_says(tmp_path, channel, want):
    from scheimpflug.io.importer import read_image

    p = _rgb(tmp_path, "c", (10, 50, 200))           # OpenCV's order: blue, green, red
    assert int(read_image(p, channel)[3, 4]) == want


def test_a_colour_frame_without_a_channel_and_a_bad_channel_are_refused(tmp_path):
    from scheimpflug.io.importer import read_image

    p = _rgb(tmp_path, "c", (10, 50, 200))
    with pytest.raises(FrameError, match="colour.*--channel"):
        read_image(p)
    for bad in ("red", "1,2", "-1,0,0", "0,0,0", "nan,0,1"):
        with pytest.raises(FrameError, match="--channel"):
            read_image(p, bad)


def test_a_jpeg_scan_with_angles_and_backgrounds_imports_with_the_laser_alone(tmp_path, capsys):
    laser = [_rgb(tmp_path, f"laser_{k}", (0, 0, 90 + 40 * k), suffix=".jpg") for k in range(3)]
    for k in range(3):
        _rgb(tmp_path, f"laser-off_{k}", (0, 0, 30), suffix=".jpg")
    assert main(["import", *map(str, laser), "--channel", "r", "--angles-deg=-1.8:-1.8",
                 "--background-names", "laser=laser-off", "--stripe-along", "rows", "--out", str(tmp_path / "o"),
                 "--json"]) == 0
    ff = open_frame_folder(tmp_path / "o")
    assert ff.stripe_along == "rows" and [r.angle_deg for r in ff.frames] == [-5.4, -3.6, -1.8]
    # JPEG rounds: the laser-on minus the laser-off red level, within the codec's error
    assert [abs(int(ff.read(i)[5, 5]) - (90 + 40 * k - 30)) <= 2 for i, k in enumerate((2, 1, 0))] == [True] * 3
    m = json.loads((tmp_path / "o" / "manifest.json").read_text())
    assert m["channel"] == "r" and m["frames"][0]["background_file"].endswith("laser-off_2.jpg")


@pytest.mark.parametrize("args, match", [(["--angles-deg=0:0"], "step must not be 0"),
                                         (["--angles-deg=1,2"], "2 angles for 3 frames"),
                                         (["--angles-deg=a:b"], "START:STEP"),
                                         (["--angles-deg=0:1", "--background-names", "x=y"], "does not contain"),
                                         (["--angles-deg=0:1", "--background", "b.png"], "1 background"),
                                         ([], "need positions")])
def test_bad_angles_and_backgrounds_are_one_line_and_write_nothing(tmp_path, capsys, args, match):
    files = _frames(tmp_path, ["f_1.png", "f_2.png", "f_3.png"])
    _frames(tmp_path, ["b.png"])
    rc = main(["import", *map(str, files), *[a if a != "b.png" else str(tmp_path / "b.png") for a in args],
               "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and match in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_a_pattern_set_imports_as_poses_from_the_files_or_a_csv(tmp_path):
    files = _frames(tmp_path, ["p0.png", "p1.png", "p0_laser.png", "p1_laser.png"])
    assert main(["import", *map(str, files[:2]), "--scenario", "target", "--out", str(tmp_path / "a")]) == 0
    ff = open_frame_folder(tmp_path / "a")
    assert ff.scenario == "target" and [(r.extra["pose"], r.extra["light"]) for r in ff.frames] == \
        [(0, "flood"), (1, "flood")]
    (tmp_path / "poses.csv").write_text("file,pose,light,angle_deg\np0.png,0,flood,\np1.png,1,flood,30\n"
                                        "p0_laser.png,0,laser,\np1_laser.png,1,laser,30\n")
    assert main(["import", *map(str, files), "--scenario", "target", "--positions", str(tmp_path / "poses.csv"),
                 "--out", str(tmp_path / "b")]) == 0
    got = [(r.extra["pose"], r.extra["light"], r.angle_deg) for r in open_frame_folder(tmp_path / "b").frames]
    assert got == [(0, "flood", None), (1, "flood", 30.0), (0, "laser", None), (1, "laser", 30.0)]
    (tmp_path / "bad.csv").write_text("file,pose,light\np0.png,0,lamp\np1.png,1,flood\n")
    with pytest.raises(FrameError, match="light one of"):
        target_frames(files[:2], tmp_path / "bad.csv")


def test_a_manifest_with_an_unknown_stripe_orientation_is_refused(tmp_path):
    files = _frames(tmp_path, ["s_1.png", "s_2.png"])
    out = import_frames(positions_from_names(files, "s_{angle_deg}.png"), tmp_path / "o")
    m = json.loads((out / "manifest.json").read_text())
    m["stripe_along"] = "diagonal"
    (out / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(FrameError, match="stripe_along"):
        open_frame_folder(out)


def test_plate_methods_refuse_a_stripe_along_the_rows(tmp_path, capsys):
    files = _frames(tmp_path, ["s_1.png", "s_2.png", "s_3.png"])
    assert main(["import", *map(str, files), "--positions-from-names", "s_{stage_mm}.png", "--stripe-along", "rows",
                 "--out", str(tmp_path / "o")]) == 0
    for method in ("paper", "general"):
        capsys.readouterr()
        assert main(["calibrate", str(tmp_path / "o"), "--method", method, "--quiet"]) == 2
        err = capsys.readouterr().err
        assert "stripe runs along the rows" in err and "--method target" in err

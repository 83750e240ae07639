"""`scheimpflug import`: positions from a CSV or file names; one clear error per bad input."""

import json

import cv2
import numpy as np
import pytest

from scheimpflug.app.cli import main
from scheimpflug.errors import FrameError
from scheimpflug.io.frames import open_frame_folder
from scheimpflug.io.importer import import_frames, positions_from_csv, positions_from_names


def _frames(tmp_path, names, shape=(20, 30), dtype=np.uint16):
    paths = []
    for k, n in enumerate(names):
        p = tmp_path / n
        assert cv2.imwrite(str(p), np.full(shape, 100 + k, dtype))
        paths.append(p)
    return paths


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

"""The importer's known stripe direction (issue 36's leftover): a twin's frames whose faint stripe
the direction check refuses are imported with the direction the caller knows, read as every import
reads them (channel, angles, manifest, atomic write); ``grey_twin_frames`` is that one path.

Small synthetic RGB PNG frames (lossless: the grey frame must be the file's red channel exactly).
"""

import json
import warnings

import cv2
import numpy as np
import pytest

from scheimpflug.app.cli import main
from scheimpflug.errors import FrameError
from scheimpflug.io.frames import open_frame_folder
from scheimpflug.io.importer import frames_with_angles, import_frames
from scheimpflug.io.twin_frames import grey_twin_frames

SHAPE = (48, 64)
ANGLES = (-3.0, -1.2, 0.6, 2.4)


def _faint_across(seed: int) -> np.ndarray:
    """An 8-bit RGB frame: a faint stripe across the image (red, 12 DN) and a bright glare line down it.

    The glare line (a wall's edge lit by the room) is what the direction check sees: it runs down the
    image in every row, the stripe across it is at the noise's level.
    """
    rng = np.random.default_rng(seed)
    r, c = np.mgrid[:SHAPE[0], :SHAPE[1]].astype(np.float64)
    red = 20.0 + rng.normal(0.0, 2.0, SHAPE) + 12.0 * np.exp(-0.5 * ((r - 20.0 - 0.1 * c) / 1.5) ** 2)
    red += 200.0 * np.exp(-0.5 * ((c - 10.0 - 0.05 * r) / 1.2) ** 2)
    rgb = np.zeros((*SHAPE, 3), np.uint8)                     # OpenCV's order: B, G, R
    rgb[..., 2] = np.clip(np.rint(red), 0, 255)
    rgb[..., 1] = 7 + seed
    rgb[..., 0] = 3
    return rgb


def _twin(tmp_path, n=len(ANGLES)):
    """A twin's frame folder as render rotary writes it with a camera chain: RGB files, angles in the manifest."""
    folder = tmp_path / "twin"
    (folder / "frames").mkdir(parents=True)
    entries, reds = [], []
    for k in range(n):
        img = _faint_across(k)
        assert cv2.imwrite(str(folder / f"frames/{k:05d}.png"), img)
        entries.append({"file": f"frames/{k:05d}.png", "angle_deg": ANGLES[k]})
        reds.append(img[..., 2])
    (folder / "manifest.json").write_text(json.dumps({"format": "scheimpflug-frames/1", "complete": True,
                                                      "adc_bits": 12, "stripe_along": "rows",
                                                      "frames": entries}))
    return folder, reds


def _manifest(folder):
    return json.loads((folder / "manifest.json").read_text())


def test_the_direction_check_refuses_these_frames(tmp_path):
    """The precondition: detection sees the glare line down the image and refuses rows (and finds columns)."""
    folder, _ = _twin(tmp_path)
    frames = frames_with_angles(sorted((folder / "frames").glob("*.png")), list(ANGLES))
    refused = r"--stripe-along rows, but the stripe runs down the image \(one point per row\) in 4 of the 4"
    with pytest.raises(FrameError, match=refused):
        import_frames(frames, tmp_path / "o", channel="r", stripe_along="rows")
    assert not (tmp_path / "o").exists()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import_frames(frames, tmp_path / "auto", channel="r")
    assert _manifest(tmp_path / "auto")["stripe_along"] == "columns"


def test_a_known_direction_is_recorded_without_looking_and_the_rest_is_the_import(tmp_path):
    folder, reds = _twin(tmp_path)
    files = sorted((folder / "frames").glob("*.png"))
    order = [2, 0, 3, 1]                                     # given out of order: sorted by angle as always
    frames = frames_with_angles([files[k] for k in order], [ANGLES[k] for k in order])
    with warnings.catch_warnings():
        warnings.simplefilter("error")                       # no stripe warning, nor any other
        out = import_frames(frames, tmp_path / "o", channel="r", stripe_along="rows", stripe_known=True)
    m = _manifest(out)
    assert m["stripe_along"] == "rows" and m["channel"] == "r" and m["adc_bits"] == 8
    assert m["stripe_detection"] == {"given": "rows", "known": True, "found": None, "examined": 0, "columns": 0,
                                     "rows": 0, "unclear": 0}
    ff = open_frame_folder(out)
    assert [r.angle_deg for r in ff.frames] == list(ANGLES)
    assert [e["source_file"] for e in m["frames"]] == [str(f) for f in files]
    for k in range(len(ANGLES)):
        assert np.array_equal(ff.read(k), reds[k])           # exact: copy (the red channel stored, read back)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o", "twin"]      # no temporary left


def test_a_known_direction_needs_a_direction(tmp_path):
    folder, _ = _twin(tmp_path, 2)
    frames = frames_with_angles(sorted((folder / "frames").glob("*.png")), list(ANGLES[:2]))
    with pytest.raises(FrameError, match="--stripe-known needs the direction: --stripe-along columns or rows, "
                                         "not 'auto'"):
        import_frames(frames, tmp_path / "o", channel="r", stripe_known=True)
    assert not (tmp_path / "o").exists()


def test_the_cli_takes_a_known_direction(tmp_path, capsys):
    folder, _ = _twin(tmp_path, 3)
    files = [str(p) for p in sorted((folder / "frames").glob("*.png"))]
    capsys.readouterr()
    assert main(["import", *files, "--channel", "r", "--angles-deg=0:1", "--stripe-along", "rows",
                 "--stripe-known", "--out", str(tmp_path / "o"), "--json"]) == 0
    got = capsys.readouterr()
    assert "stripe_along rows (across the image, one point per column), known" in got.err
    assert "warning" not in got.err
    assert json.loads(got.out)["stripe_detection"]["known"] is True
    assert main(["import", *files, "--channel", "r", "--angles-deg=0:1", "--stripe-known", "--out",
                 str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--stripe-known needs the direction" in err and "Traceback" not in err
    assert not (tmp_path / "p").exists()


def test_a_twins_colour_frames_become_grey_frames_through_the_import(tmp_path):
    folder, reds = _twin(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = grey_twin_frames(folder, tmp_path / "grey", channel=None, stripe_along="rows")
    assert out == tmp_path / "grey"
    m, ff = _manifest(out), open_frame_folder(out)
    assert m["source"] == "scheimpflug import" and m["stripe_detection"]["known"] and m["channel"] == "r"
    assert ff.stripe_along == "rows" and [r.angle_deg for r in ff.frames] == list(ANGLES)
    assert all(np.array_equal(ff.read(k), reds[k]) for k in range(len(ANGLES)))   # exact: copy (PNG, lossless)
    assert grey_twin_frames(out, tmp_path / "again", channel="r", stripe_along="rows") == out   # grey: as it is
    assert not (tmp_path / "again").exists()


def test_a_twins_colour_frame_without_an_angle_is_refused(tmp_path):
    folder, _ = _twin(tmp_path, 2)
    m = _manifest(folder)
    del m["frames"][1]["angle_deg"]
    (folder / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(FrameError, match="frame 'frames/00001.png' has no angle_deg"):
        grey_twin_frames(folder, tmp_path / "grey", channel="r", stripe_along="rows")
    assert not (tmp_path / "grey").exists()

"""opal.read_exr / opal.write_exr: exact round trip, grey images, bad input."""

import numpy as np
import pytest

import opal


def test_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(1)
    img = rng.standard_normal((5, 7, 3)).astype(np.float32) * 1e3
    img[0, 0] = [np.inf, -np.inf, 0.0]
    img[1, 1] = [1e-40, -0.0, 3.4e38]  # a subnormal, negative zero, near max
    p = tmp_path / "a.exr"
    opal.write_exr(p, img)
    back = opal.read_exr(p)
    assert back.shape == (5, 7, 3) and back.dtype == np.float32
    assert np.array_equal(back.view(np.uint32), img.view(np.uint32))
    back[0, 0, 0] = 1.0  # writable


def test_nan_survives(tmp_path):
    img = np.zeros((2, 2, 3), np.float32)
    img[1, 0, 2] = np.nan
    opal.write_exr(tmp_path / "n.exr", img)
    assert np.isnan(opal.read_exr(tmp_path / "n.exr")[1, 0, 2])


def test_grey_and_float64_and_non_contiguous(tmp_path):
    grey = np.arange(12, dtype=np.float64).reshape(3, 4)
    opal.write_exr(tmp_path / "g.exr", grey)
    back = opal.read_exr(tmp_path / "g.exr")
    assert np.array_equal(back, np.repeat(grey[:, :, None], 3, axis=2).astype(np.float32))
    rgb = np.random.default_rng(2).random((6, 8, 3)).astype(np.float32)[::2, ::2]
    opal.write_exr(tmp_path / "s.exr", rgb)
    assert np.array_equal(opal.read_exr(tmp_path / "s.exr"), rgb)


def test_bad_shapes(tmp_path):
    for shape in [(4,), (2, 2, 4), (2, 2, 1), (0, 3, 3), (1, 2, 3, 3)]:
        with pytest.raises(ValueError):
            opal.write_exr(tmp_path / "x.exr", np.zeros(shape, np.float32))
    assert not (tmp_path / "x.exr").exists()


def test_bad_files(tmp_path):
    with pytest.raises(opal.OpalError, match="no such file"):
        opal.read_exr(tmp_path / "missing.exr")
    junk = tmp_path / "junk.exr"
    junk.write_bytes(b"not an exr file at all")
    with pytest.raises(opal.OpalError):
        opal.read_exr(junk)
    with pytest.raises(opal.OpalError):
        opal.read_exr(tmp_path / "x.txt")
    d = tmp_path / "adir"
    d.mkdir()
    with pytest.raises(opal.OpalError):
        opal.write_exr(d, np.zeros((2, 2, 3), np.float32))

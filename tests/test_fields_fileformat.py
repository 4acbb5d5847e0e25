"""The AO-field file (aobake.methods.fields.fileformat): reproducible round trips, and
one-line errors for every kind of broken file."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest

from aobake.errors import InputError
from aobake.methods.fields import field_ao, load_field, save_field
from aobake.testing.field_scenes import ball_fields as fit_ball_fields
from aobake.testing.field_scenes import plane_receivers


@pytest.fixture(scope="module")
def ball_fields():
    return fit_ball_fields(("raster", "table"))


# --------------------------------------------------------------------------- files


def test_round_trip_and_reproducible_bytes(ball_fields, tmp_path):
    for kind in ("raster", "table"):
        f = ball_fields[kind]
        a, b = tmp_path / f"{kind}_a.npz", tmp_path / f"{kind}_b.npz"
        save_field(f, a)
        save_field(f, b)
        assert a.read_bytes() == b.read_bytes()
        g = load_field(a)
        np.testing.assert_array_equal(g.texels, f.texels)
        if f.table is not None:
            np.testing.assert_array_equal(g.table, f.table)
        assert g.model == f.model and g.params == f.params and g.occluder_hash == f.occluder_hash
        p, n = plane_receivers(1.1)
        np.testing.assert_array_equal(field_ao(g, p, n), field_ao(f, p, n))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["raster_a.npz", "raster_b.npz", "table_a.npz", "table_b.npz"]


def _rewrite(src, dst, **changes):
    with np.load(src) as z:
        data = {k: z[k] for k in z.files}
    for k, v in changes.items():
        if v is None:
            data.pop(k)
        else:
            data[k] = v
    np.savez(dst, **data)


def _expect_error(path, text):
    with pytest.raises(InputError) as info:
        load_field(path)
    msg = str(info.value)
    assert msg.startswith(f"{path.name}: ") and "\n" not in msg and text in msg, msg


def test_bad_files_fail_with_one_line(ball_fields, tmp_path):
    good = tmp_path / "good.npz"
    save_field(ball_fields["raster"], good)
    data = good.read_bytes()

    (tmp_path / "text.npz").write_text("not a zip\n")
    _expect_error(tmp_path / "text.npz", "not a readable field file")
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    _expect_error(tmp_path / "cut.npz", "not a readable field file")
    (tmp_path / "empty.npz").write_bytes(b"")
    _expect_error(tmp_path / "empty.npz", "not a readable field file")
    _expect_error(tmp_path / "missing_file.npz", "file not found")

    cases = {
        "nokey": ({"texels": None}, "missing texels"),
        "version": ({"format_version": np.array(99)}, "version 99"),
        "shape": ({"texels": np.zeros((6, 3, 3, 7), np.float32)}, "texels have shape"),
        "nan": ({"centre": np.array([0.0, np.nan, 0.0])}, "NaN"),
        "dtype": ({"texels": np.zeros((6, 8, 8, 7), np.int32)}, "floating point"),
        "radii": ({"r_far": np.array(0.5)}, "inconsistent radii"),
        "params": ({"params": np.array("[1, 2")}, "JSON"),
        "model": ({"model": np.array("spline")}, "model"),
    }
    for name, (change, text) in cases.items():
        path = tmp_path / f"{name}.npz"
        _rewrite(good, path, **change)
        _expect_error(path, text)

    # a corrupted member inside an intact zip directory
    bad = tmp_path / "crc.npz"
    with zipfile.ZipFile(good) as zin, zipfile.ZipFile(bad, "w") as zout:
        for item in zin.infolist():
            payload = zin.read(item)
            if item.filename == "texels.npy":
                payload = payload[:-40]
            zout.writestr(item, payload)
    _expect_error(bad, "not a readable field file")

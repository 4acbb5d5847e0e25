"""AO-field evaluation (aobake.methods.fields.evaluate): the cap integral, lookups at
receivers, rigid placements, several fields."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from aobake.methods.fields import (
    AOField,
    cap_integral,
    field_ao,
    fields_ao,
    fit_field,
    rigid_transform,
)
from aobake.testing import scenes
from aobake.testing.field_scenes import ball_fields as fit_ball_fields
from aobake.testing.field_scenes import plane_receivers

# --------------------------------------------------------------------------- cap integral


def cap_numeric(omega: float, ct: float, n: int = 800) -> float:
    """1/pi int_cap max(0, n.w) dw by midpoint quadrature in the cap's own frame."""
    cs = 1.0 - omega / (2.0 * math.pi)
    st_ = math.sqrt(max(0.0, 1.0 - ct * ct))
    # polar angle t about the cap axis a = (st, 0, ct), azimuth p
    sigma = math.acos(max(-1.0, min(1.0, cs)))
    t = (np.arange(n) + 0.5) / n * sigma
    p = (np.arange(2 * n) + 0.5) / (2 * n) * 2.0 * math.pi
    tt, pp = np.meshgrid(t, p, indexing="ij")
    # w = cos t a + sin t (cos p e1 + sin p e2) with e1 = (ct, 0, -st), e2 = (0, 1, 0)
    wz = np.cos(tt) * ct - np.sin(tt) * np.cos(pp) * st_
    d_area = np.sin(tt) * (sigma / n) * (math.pi / n)
    return float((np.maximum(wz, 0.0) * d_area).sum() / math.pi)


def test_cap_reference_values():
    np.testing.assert_allclose(cap_integral(math.pi, [1.0, 0.0, -1.0]), [0.75, 0.1955011, 0.0], atol=1e-6)
    np.testing.assert_allclose(cap_integral(2.0 * math.pi, [1.0, 0.0, -1.0]), [1.0, 0.5, 0.0], atol=1e-12)
    np.testing.assert_allclose(cap_integral(4.0 * math.pi, [1.0, 0.3, -1.0]), 1.0, atol=1e-12)
    np.testing.assert_allclose(cap_integral(0.0, [1.0, 0.0, -1.0]), 0.0, atol=0)


@pytest.mark.parametrize("omega", [0.05, 1.0, math.pi, 5.0, 2.0 * math.pi - 1e-3, 8.0, 12.0])
@pytest.mark.parametrize("ct", [1.0, 0.9, 0.3, 0.0, -0.4, -0.95, -1.0])
def test_cap_matches_numerical_integration(omega, ct):
    np.testing.assert_allclose(cap_integral(omega, ct), cap_numeric(omega, ct), atol=2e-4)


@settings(max_examples=200)
@given(st.floats(0.0, 4.0 * math.pi), st.floats(-1.0, 1.0))
def test_cap_complement_and_range(omega, ct):
    a = float(cap_integral(omega, ct))
    assert 0.0 <= a <= 1.0
    # the rest of the sphere is the opposite cap: C(4pi - Omega, -ct) = 1 - C(Omega, ct)
    np.testing.assert_allclose(cap_integral(4.0 * math.pi - omega, -ct), 1.0 - a, atol=1e-9)


def test_cap_is_finite_at_the_guards():
    om = np.array([2.0 * math.pi, 2.0 * math.pi, np.nextafter(2.0 * math.pi, 0), np.nan, -1.0, 1e-300, 20.0])
    ct = np.array([1.0, -1.0, 1.0, 0.5, 0.5, 0.0, np.nan])
    out = cap_integral(om, ct)
    assert np.isfinite(out[:6]).all()
    np.testing.assert_allclose(out[:3], [1.0, 0.0, 1.0], atol=1e-6)


@pytest.fixture(scope="module")
def ball_fields():
    return fit_ball_fields(("raster", "embree", "table"))


# --------------------------------------------------------------------------- evaluation


def test_receivers_at_centre_hull_inside_and_far(ball_fields):
    f = ball_fields["raster"]
    c = f.centre
    r0 = float(f.texels[..., 3].mean())
    p = np.array(
        [c, c + [0, 0, r0], c + [0.3, 0.2, 0.1], c + [0, 0, f.r_far], c + [f.r_far * 2, 0, 0], c + [0, 0, f.r_near]]
    )
    for normals in (np.tile([0.0, 0.0, 1.0], (len(p), 1)), np.zeros((len(p), 3))):
        res = fields_ao([f], p, normals)
        assert np.isfinite(res.ao).all() and (res.ao >= 0).all() and (res.ao <= 1).all()
        assert res.skipped == (2,)
        np.testing.assert_array_equal(res.ao[3:5], 1.0)
        assert res.ao[0] == pytest.approx(1.0 - f.a0)  # the centre reads A0


def test_transform_invariance(ball_fields):
    f = ball_fields["table"]
    p, n = plane_receivers(1.2, n=7)
    p += [0.0123, 0.0456, 0.0]  # off the cube map's face seams, where rounding may pick either face
    base = field_ao(f, p, n)
    m = rigid_transform((3.0, -20.0, 7.5), (30.0, -45.0, 110.0))
    moved = field_ao(f, p @ m[:3, :3].T + m[:3, 3], n @ m[:3, :3].T, transform=m)
    np.testing.assert_allclose(moved, base, atol=1e-9)


def test_rigid_transform_conventions():
    m = rigid_transform((1.0, 2.0, 3.0), (90.0, 0.0, 0.0))
    np.testing.assert_allclose(m[:3, :3] @ [0, 1, 0], [0, 0, 1], atol=1e-15)
    m = rigid_transform(rotation_degrees=(90.0, 90.0, 0.0))  # x first, then y
    np.testing.assert_allclose(m[:3, :3] @ [0, 1, 0], [1, 0, 0], atol=1e-15)
    with pytest.raises(ValueError, match="rigid"):
        field_ao_dummy = np.diag([2.0, 1.0, 1.0, 1.0])
        fields_ao([_tiny_field()], np.zeros((1, 3)), np.zeros((1, 3)), transforms=[field_ao_dummy])


def _tiny_field() -> AOField:
    return fit_field(scenes.box((1.0, 1.0, 1.0)), resolution=1, radial_samples=3, raster_size=8)


def test_several_fields_multiply(ball_fields):
    f1, f2 = ball_fields["raster"], ball_fields["embree"]
    p, n = plane_receivers(1.5, half=6.0)
    t1, t2 = rigid_transform((-1.2, 0, 0)), rigid_transform((1.2, 0, 0), (0, 0, 40))
    both = fields_ao([f1, f2], p, n, transforms=[t1, t2])
    a1 = field_ao(f1, p, n, transform=t1)
    a2 = field_ao(f2, p, n, transform=t2)
    np.testing.assert_array_equal(both.ao, a1 * a2)
    far = [int((np.linalg.norm(p - t[:3, 3] - f.centre, axis=1) >= f.r_far).sum()) for f, t in ((f1, t1), (f2, t2))]
    assert both.skipped == tuple(far) and sum(far) > 0

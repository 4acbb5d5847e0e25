"""Hybrid method (aobake.hybrid): short rays near each vertex, disks beyond."""

from __future__ import annotations

import numpy as np
import pytest

from aobake import bunnell as B
from aobake.hybrid import hybrid_ao
from aobake.mesh import surface_from_arrays
from aobake.raytrace import embree_ao
from aobake.sampling import sample_directions

from naive_bunnell import facing_plates, sphere_on_plane, touching_spheres


def test_near_field_is_the_reference_estimator_with_short_rays():
    """Same directions and origins as embree_ao: with every ray long enough to reach
    everything (reach huge) the near field is embree_ao's estimate, hit for hit."""
    s = sphere_on_plane()
    h = hybrid_ao(s, n_rays=32, reach=1e6, seed=3)
    ref = embree_ao(s, n_rays=32, seed=3)
    np.testing.assert_array_equal(1.0 - h.near, ref.ao)
    assert h.contacts == ref.contacts
    np.testing.assert_array_equal(h.far, 0.0)  # nothing lies beyond the rays


def test_ray_length_is_reach_edge_lengths():
    s = touching_spheres()
    h = hybrid_ao(s, reach=3.0, max_distance=0.25)
    edges = np.zeros(s.n_vertices)
    for k in range(3):
        e = np.linalg.norm(s.positions[s.faces[:, (k + 1) % 3]] - s.positions[s.faces[:, k]], axis=1)
        np.maximum.at(edges, s.faces[:, k], e)
        np.maximum.at(edges, s.faces[:, (k + 1) % 3], e)
    np.testing.assert_allclose(h.reach, np.minimum(3.0 * edges, 0.25))


def test_far_field_is_the_disk_sum_beyond_the_rays():
    """The far field is the exact disk sum over emitters at least D_i away (brute-force
    check of the tree's inner radius), front faces cast."""
    s = facing_plates(cells=10)
    h = hybrid_ao(s, reach=2.0, theta=np.inf)
    e = B.build_elements(s)
    exact = B.occlusion_passes(e, None, near=0.0, sides="front", inner=h.reach)[0]
    np.testing.assert_allclose(h.far, exact, rtol=0, atol=2e-6)
    assert h.far.max() > 0.3
    # far from everything: with rays as long as the scene, nothing is left for disks
    assert hybrid_ao(s, reach=100.0).far.max() == 0.0


@pytest.mark.parametrize("combine", ["product", "sum", "max"])
def test_combinations(combine):
    s = sphere_on_plane()
    h = hybrid_ao(s, combine=combine, reach=2.0)
    n, f = h.near, h.far
    expected = {
        "product": 1 - (1 - n) * (1 - f),
        "sum": np.minimum(n + f, 1),
        "max": np.maximum(n, f),
    }[combine]
    np.testing.assert_allclose(h.ao, 1 - expected, rtol=0, atol=1e-15)


def test_against_the_reference():
    """Near field by rays, far field by disks: close to 1024 rays on a contact scene."""
    s = sphere_on_plane(subdivisions=3, cells=40)
    ref = embree_ao(s, n_rays=1024, seed=0).ao
    h = hybrid_ao(s, n_rays=64, seed=1)
    assert np.sqrt(np.mean((h.ao - ref) ** 2)) < 0.045


def test_directions_are_the_reference_ones():
    """sample_directions gives the rays embree_ao (and so hybrid_ao) cast: unit length,
    in the hemisphere."""
    s = sphere_on_plane()
    d = sample_directions(s.normals, 8, seed=0)
    np.testing.assert_allclose(np.linalg.norm(d, axis=2), 1.0, atol=1e-6)
    assert np.all(np.einsum("vkj,vj->vk", d, s.normals) >= -1e-6)


def test_isolated_vertices_and_bad_meshes():
    p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, 0.5], [3, 3, 3.0]])
    s = surface_from_arrays(p, [[0, 1, 2], [0, 0, 1]])
    h = hybrid_ao(s)
    assert np.all(np.isfinite(h.ao)) and h.ao.min() >= 0 and h.ao.max() <= 1
    assert h.reach[4] == 0.0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(n_rays=0), "n_rays must be an integer >= 1"),
        (dict(reach=0.0), "reach must be finite and > 0"),
        (dict(reach="2"), "reach must be a positive number"),
        (dict(combine="min"), "combine must be one of"),
        (dict(measure="solid"), "measure must be one of"),
        (dict(max_distance=-1.0), "max_distance must be finite and > 0"),
    ],
)
def test_bad_options(kwargs, match):
    with pytest.raises(ValueError, match=match):
        hybrid_ao(touching_spheres(), **kwargs)


def test_deterministic_across_threads():
    s = sphere_on_plane()
    a = hybrid_ao(s, threads=1).ao
    b = hybrid_ao(s, threads=2).ao
    np.testing.assert_array_equal(a, b)


def test_cli_hybrid(tmp_path):
    import trimesh
    from click.testing import CliRunner

    from aobake.cli import main
    from aobake.formats import read_bake

    s = sphere_on_plane()
    src = tmp_path / "scene.ply"
    trimesh.Trimesh(s.positions, s.faces, process=False).export(src)
    out = tmp_path / "out.ply"
    result = CliRunner().invoke(
        main, ["bake", str(src), "-o", str(out), "--method", "hybrid", "--reach", "3", "--seed", "2"]
    )
    assert result.exit_code == 0, result.output
    from aobake.readers import load_mesh

    expected = hybrid_ao(load_mesh(src), reach=3.0, seed=2).ao
    np.testing.assert_allclose(read_bake(out), expected, atol=1e-7)
    assert f"{16 * s.n_vertices / 1e6:.3f} M rays" in result.stderr  # hybrid's own default

"""Triangle-mesh helpers of the SH PRT: the icosphere is a closed, outward, unit mesh; area-weighted normals;
barycentric weights; Mitsuba ray casting returns the hit triangle and weights that rebuild the hit point."""
import pytest
import torch

from neumat import InputError
from neumat.render.mesh import MeshIntersector, barycentrics, icosphere, vertex_normals
from tests.mitsuba_util import mitsuba_or_skip


@pytest.mark.parametrize("s", [0, 1, 3])
def test_icosphere_is_closed_outward_and_unit(s):
    v, f = icosphere(s)
    assert v.shape == (10 * 4 ** s + 2, 3) and f.shape == (20 * 4 ** s, 3)
    torch.testing.assert_close(v.norm(dim=-1), torch.ones(len(v), dtype=torch.float64), rtol=0, atol=1e-12)
    edges = torch.cat([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    directed = {tuple(e) for e in edges.tolist()}
    assert len(directed) == len(edges)  # no directed edge twice: consistently oriented
    assert all((b, a) in directed for a, b in directed)  # each edge has its twin: closed
    assert len(v) - len(directed) // 2 + len(f) == 2  # Euler characteristic of the sphere
    centres = v[f].mean(1)
    normals = torch.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]], dim=-1)
    assert bool(((normals * centres).sum(-1) > 0).all())  # counter-clockwise from outside
    n = vertex_normals(v, f)
    assert (n - v).norm(dim=-1).max() < (0.02 if s == 3 else 0.2)


def test_vertex_normals_weight_faces_by_area():
    v = torch.tensor([[0.0, 0, 0], [2, 0, 0], [0, 2, 0], [0, 0, -1], [0, 0, 0]], dtype=torch.float64)
    f = torch.tensor([[0, 1, 2], [0, 3, 1]])  # areas 2 (normal +z) and 1 (normal -y)
    n = vertex_normals(v[:4], f)
    torch.testing.assert_close(n[0], torch.tensor([0.0, -1, 2], dtype=torch.float64) / 5 ** 0.5)
    torch.testing.assert_close(n[2], torch.tensor([0.0, 0, 1], dtype=torch.float64))
    with pytest.raises(InputError, match="vertex 4"):
        vertex_normals(v, f)


def test_barycentrics_rebuild_points_and_clamp():
    g = torch.Generator().manual_seed(0)
    tri = torch.randn(50, 3, 3, generator=g, dtype=torch.float64)
    w = torch.rand(50, 3, generator=g, dtype=torch.float64)
    w = w / w.sum(-1, keepdim=True)
    p = (w[:, :, None] * tri).sum(1)
    torch.testing.assert_close(barycentrics(tri, p), w)
    normal = torch.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], dim=-1)
    torch.testing.assert_close(barycentrics(tri, p + 0.3 * normal), w)  # projected onto the plane
    outside = barycentrics(tri, tri[:, 0] + 2 * (tri[:, 0] - tri[:, 1]))
    assert bool((outside >= 0).all()) and torch.allclose(outside.sum(-1), torch.ones(50, dtype=torch.float64))


@pytest.mark.mitsuba
def test_mesh_intersector_returns_the_hit_triangle_and_its_weights():
    mitsuba_or_skip()
    v, f = icosphere(2)
    g = torch.Generator().manual_seed(1)
    target = torch.nn.functional.normalize(torch.randn(200, 3, generator=g, dtype=torch.float64), dim=-1) * 0.5
    o = torch.tensor([[0.3, -0.2, 4.0]], dtype=torch.float64).expand(200, 3)
    d = torch.nn.functional.normalize(target - o, dim=-1)
    d = torch.cat([d, torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)])  # away from the sphere: a miss
    hit, face, bary = MeshIntersector(v, f).intersect(torch.cat([o, o[:1]]), d)
    assert bool(hit[:200].all()) and not bool(hit[200])
    p = (bary[:, :, None] * v[f[face]]).sum(1)
    # the point lies on the ray, and on the face Mitsuba reports
    t = ((p - o) * d[:200]).sum(-1, keepdim=True)
    assert (o + t * d[:200] - p).norm(dim=-1).max() < 1e-5
    assert bool((bary >= 0).all()) and bool((t > 0).all())
    with pytest.raises(InputError, match="faces"):
        MeshIntersector(v, f + len(v))


@pytest.mark.mitsuba
def test_object_mesh_drops_vertices_on_no_triangle(tmp_path):
    mitsuba_or_skip()
    from neumat.reflectance.translucent import TranslucentConfig, TranslucentObject
    from neumat.render.mesh import object_mesh
    lines = ["ply", "format ascii 1.0", "element vertex 5", "property float x", "property float y",
             "property float z", "element face 4", "property list uchar int vertex_indices", "end_header",
             "0 0 0", "5 5 5", "1 0 0", "0 1 0", "0 0 1", "3 0 3 2", "3 0 2 4", "3 0 4 3", "3 2 3 4"]
    (tmp_path / "t.ply").write_text("\n".join(lines) + "\n")  # vertex 1 (5, 5, 5) is on no face
    v, f = object_mesh(TranslucentObject(TranslucentConfig(shape=str(tmp_path / "t.ply")), spp=1))
    assert v.shape == (4, 3) and f.shape == (4, 3)
    assert sorted(map(tuple, v.tolist())) == [(0, 0, 0), (0, 0, 1), (0, 1, 0), (1, 0, 0)]
    assert bool(((vertex_normals(v, f) * (v - 0.25)).sum(-1) > 0).all())  # the faces still point outwards

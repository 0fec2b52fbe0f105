"""Triangle meshes for per-vertex precomputation (SH PRT): an icosphere, area-weighted vertex normals, the mesh of
a translucent object, and ray casting against a mesh (hit triangle and barycentric coordinates, Mitsuba 3).

Meshes are (vertices (V, 3) float64, faces (F, 3) long) pairs, counter-clockwise seen from outside.
"""
from __future__ import annotations

import math

import numpy as np
import torch

from ..core.checks import check_int, check_shape
from ..core.errors import InputError
from ..core.mitsuba import import_mitsuba
from ..reflectance.translucent import TranslucentObject


def icosphere(subdivisions: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Unit icosphere: the icosahedron with each triangle split into 4 `subdivisions` times, new vertices pushed
    onto the sphere; 10 4^s + 2 vertices and 20 4^s faces."""
    check_int(subdivisions, "icosphere subdivisions", 0)
    t = (1 + math.sqrt(5)) / 2
    verts = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
             (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
             (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11),
             (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    v = [np.array(p, dtype=np.float64) / np.linalg.norm(p) for p in verts]
    for _ in range(subdivisions):
        midpoint: dict[tuple[int, int], int] = {}

        def mid(a: int, b: int) -> int:
            key = (min(a, b), max(a, b))
            if key not in midpoint:
                m = v[a] + v[b]
                v.append(m / np.linalg.norm(m))
                midpoint[key] = len(v) - 1
            return midpoint[key]

        faces = [f for a, b, c in faces
                 for f in ((a, mid(a, b), mid(c, a)), (b, mid(b, c), mid(a, b)), (c, mid(c, a), mid(b, c)),
                           (mid(a, b), mid(b, c), mid(c, a)))]
    return torch.from_numpy(np.stack(v)), torch.tensor(faces, dtype=torch.long)


def vertex_normals(vertices: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """(V, 3) unit vertex normals: the sum of the adjacent faces' normals weighted by their areas (the cross
    products of counter-clockwise triangles). Raises InputError for a vertex on no triangle of non-zero area."""
    check_shape(vertices, "vertices", (-1, 3))
    check_shape(faces, "faces", (-1, 3))
    v = vertices.double()
    f = faces.long()
    cross = torch.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]], dim=-1)  # 2 area x unit normal
    n = torch.zeros_like(v).index_add_(0, f.reshape(-1), cross.repeat_interleave(3, 0))
    length = n.norm(dim=-1, keepdim=True)
    if bool((length <= 0).any()):
        bad = int((length[:, 0] <= 0).nonzero()[0])
        raise InputError(f"mesh vertex {bad} lies on no triangle of non-zero area: it has no normal")
    return n / length


def object_mesh(obj: TranslucentObject, subdivisions: int = 4) -> tuple[torch.Tensor, torch.Tensor]:
    """(vertices, faces) of a translucent object's surface: the triangles Mitsuba loaded from its PLY (quads
    split; vertices on no triangle dropped, as scanned meshes like the Stanford bunny have some), or for the
    analytic unit sphere an icosphere with `subdivisions`."""
    if obj.config.shape == "sphere":
        return icosphere(subdivisions)
    mi = obj.mi
    shape = next(s for s in obj.scenes["black"].shapes() if s.is_mesh())
    params = mi.traverse(shape)
    v = np.array(params["vertex_positions"], dtype=np.float64).reshape(-1, 3)
    f = np.array(params["faces"], dtype=np.int64).reshape(-1, 3)
    used, f = np.unique(f, return_inverse=True)
    return torch.from_numpy(v[used]), torch.from_numpy(f.reshape(-1, 3))


class MeshIntersector:
    """Ray casting against a triangle mesh (vertices (V, 3), faces (F, 3)) with Mitsuba 3."""

    def __init__(self, vertices: torch.Tensor, faces: torch.Tensor) -> None:
        check_shape(vertices, "vertices", (-1, 3))
        check_shape(faces, "faces", (-1, 3))
        if faces.numel() == 0 or int(faces.min()) < 0 or int(faces.max()) >= vertices.shape[0]:
            raise InputError(f"faces: expected at least one triangle with vertex indices in [0, {vertices.shape[0]})")
        self.vertices, self.faces = vertices.double().cpu(), faces.long().cpu()
        self.mi = mi = import_mitsuba()
        mesh = mi.Mesh("mesh", self.vertices.shape[0], self.faces.shape[0])
        params = mi.traverse(mesh)
        params["vertex_positions"] = mi.Float(self.vertices.numpy().astype(np.float32).ravel())
        params["faces"] = mi.UInt32(self.faces.numpy().astype(np.uint32).ravel())
        params.update()
        self.scene = mi.load_dict({"type": "scene", "mesh": mesh})

    def intersect(self, o: torch.Tensor, d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """For rays o + t d (N, 3): (hit (N,) bool, face (M,) long, bary (M, 3) float64) of the M rays that hit:
        the first triangle hit and the barycentric weights of its three vertices at the hit point (computed
        from the hit point and the triangle's vertices, clamped to the triangle)."""
        mi = self.mi
        o32 = np.ascontiguousarray(o.detach().double().cpu().numpy().astype(np.float32).T)
        d32 = np.ascontiguousarray(d.detach().double().cpu().numpy().astype(np.float32).T)
        si = self.scene.ray_intersect(mi.Ray3f(mi.Point3f(o32), mi.Vector3f(d32)))
        hit = torch.from_numpy(np.array(si.is_valid(), dtype=bool))
        face = torch.from_numpy(np.array(si.prim_index, dtype=np.int64))[hit]
        p = torch.from_numpy(np.array(si.p, dtype=np.float64).T.copy())[hit]
        return hit, face, barycentrics(self.vertices[self.faces[face]], p)


def barycentrics(triangles: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """(N, 3) barycentric weights of points p (N, 3) in triangles (N, 3 vertices, 3): those of p's projection
    onto the triangle's plane, clamped to the triangle (weights >= 0, summing to 1)."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    e1, e2, r = b - a, c - a, p - a
    d11, d12, d22 = (e1 * e1).sum(-1), (e1 * e2).sum(-1), (e2 * e2).sum(-1)
    r1, r2 = (r * e1).sum(-1), (r * e2).sum(-1)
    det = (d11 * d22 - d12 * d12).clamp(min=1e-300)
    w1, w2 = (d22 * r1 - d12 * r2) / det, (d11 * r2 - d12 * r1) / det
    w = torch.stack([1 - w1 - w2, w1, w2], -1).clamp(min=0)
    return w / w.sum(-1, keepdim=True).clamp(min=1e-300)

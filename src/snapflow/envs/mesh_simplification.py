"""A triangle mesh simplified for drawing, in NumPy: welded, cut along its texture's seams, edges collapsed down to a
number of triangles (PyPI's ``fast-simplification``), its normals and texture coordinates made again for the new
surface, and how far it strays from the original (:func:`deviation`). :mod:`snapflow.envs.libero_lod` puts such
meshes into a LIBERO camera's render context; the reasons and measurements are in its docstring."""

from __future__ import annotations

import numpy as np

CREASE = 30.0  # degrees between two faces beyond which a vertex's normal is not smoothed across them
NEIGHBOURS = 16  # original faces (nearest centroids) searched for a new corner's nearest point
SAMPLES = 20000  # original points whose distance to a simplified mesh measures its deviation

Simplified = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]  # simplify_mesh's result


def simplify_mesh(
    vertices: np.ndarray, faces: np.ndarray, texcoords: np.ndarray | None, target: int, textured: bool = False
) -> Simplified:
    """A triangle mesh simplified to about ``target`` triangles (fewer when degenerate triangles drop out; more where
    collapses would fold the surface or its borders stop them). ``vertices``: n x 3; ``faces``: m x 3 indices into
    them; ``texcoords``: per face corner (m x 3 x 2), or None; ``textured``: whether a texture is drawn on it, so that
    its seams (corners of one position and different texture coordinates) must stay where they are: the mesh is cut
    along them, its borders kept whole. Returns the new vertices (float32, inside the box of ``vertices``), faces
    (int32, indices into them), normals per corner (k x 3 x 3: the new surface's, :func:`smooth_normals`), texture
    coordinates per corner (k x 3 x 2, the original surface's near the new corner, :func:`_transfer`; None without
    ``texcoords``), and for each new face the original face it was (for the original's values where the new do not
    fit)."""
    import fast_simplification  # the libero extra's: only this module needs it

    vertices, faces = np.asarray(vertices), np.asarray(faces)
    seams = textured and texcoords is not None
    # a vertex per position, or per position and texture coordinates where the texture's seams are to be kept
    keys = np.concatenate([vertices[faces], texcoords], axis=2) if seams else vertices[faces]
    welded, inverse = unique_rows(keys.reshape(len(faces) * 3, -1))
    welded, corners = welded[:, :3], inverse.reshape(len(faces), 3)
    proper = np.flatnonzero(_distinct(corners))  # a degenerate face draws nothing, and would keep its vertices
    corners = corners[proper]
    points, _, collapses = fast_simplification.simplify(
        welded.astype(np.float64),
        corners.astype(np.int32),
        target_count=min(target, len(corners)),
        return_collapses=True,
        preserve_border=seams,
    )
    # collapses[i] = (kept, removed), in order: each welded vertex's final vertex is the end of its chain of removals
    final = np.arange(len(welded))
    if len(collapses):
        final[collapses[:, 1]] = collapses[:, 0]
    while not np.array_equal(following := final[final], final):
        final = following
    moved = final[corners]
    kept = np.flatnonzero(_distinct(moved))
    # the simplifier keeps the vertices still used, in index order: its points, in that order
    used = np.unique(moved[kept])
    if len(used) != len(points):  # not the library's documented behaviour: refuse rather than draw garbage
        raise RuntimeError(f"fast_simplification returned {len(points)} vertices for {len(used)} collapsed ones")
    index = np.full(len(welded), -1, dtype=np.int64)
    index[used] = np.arange(len(used))
    points = np.clip(points, vertices.min(axis=0), vertices.max(axis=0)).astype(np.float32)
    new_faces = index[moved[kept]].astype(np.int32)
    source = proper[kept]
    new_texcoords = None
    if texcoords is not None:
        triangles = vertices[faces[proper]]
        new_texcoords = _transfer(triangles, texcoords[proper], points[new_faces], kept).astype(np.float32)
    return points, new_faces, smooth_normals(points, new_faces), new_texcoords, source


def _distinct(corners: np.ndarray) -> np.ndarray:
    """Whether each face's three corners (m x 3 vertex ids) are three vertices."""
    return (corners[:, 0] != corners[:, 1]) & (corners[:, 1] != corners[:, 2]) & (corners[:, 0] != corners[:, 2])


def smooth_normals(points: np.ndarray, faces: np.ndarray, crease: float = CREASE) -> np.ndarray:
    """Per corner of ``faces`` (into ``points``), the area-weighted mean of the normals of the faces around its vertex
    that lie within ``crease`` degrees of its own face (k x 3 x 3, unit; a face's own normal where that is
    degenerate). Why the new surface's own and not the original's: MuJoCo lights a mesh per vertex, so a large new
    face interpolates its corners' normals across it, and a corner given the normal of an original face across a crease
    (a table's edge) shades the whole face wrong."""
    triangles = points[faces].astype(np.float64)
    cross = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    area = np.linalg.norm(cross, axis=1)  # twice the area
    unit = cross / np.maximum(area, 1e-30)[:, None]
    vertex, face = faces.reshape(-1), np.repeat(np.arange(len(faces)), 3)
    order = np.argsort(vertex, kind="stable")
    vertex, face = vertex[order], face[order]
    rank = np.arange(len(vertex)) - np.searchsorted(vertex, vertex)
    around = np.full((len(points), rank.max() + 1), -1)  # the faces around each vertex, padded with -1
    around[vertex, rank] = face
    normals = np.empty((len(faces), 3, 3), dtype=np.float32)
    for first in range(0, len(faces), 4096):  # in parts: a vertex kept on a seam may have a hundred faces around it
        part = slice(first, first + 4096)
        neighbours = around[faces[part]]  # faces x 3 x the most faces around a vertex
        valid = neighbours >= 0
        neighbours = np.where(valid, neighbours, 0)
        similar = valid & (np.einsum("fc,fknc->fkn", unit[part], unit[neighbours]) >= np.cos(np.deg2rad(crease)))
        summed = np.einsum("fkn,fknc->fkc", np.where(similar, area[neighbours], 0.0), unit[neighbours])
        length = np.linalg.norm(summed, axis=2, keepdims=True)
        normals[part] = np.where(length > 1e-30, summed / np.maximum(length, 1e-30), unit[part, None, :])
    return normals


def _transfer(triangles: np.ndarray, texcoords: np.ndarray, corners: np.ndarray, source: np.ndarray) -> np.ndarray:
    """Texture coordinates (k x 3 x 2) for new corners (``corners``, k x 3 x 3, of new faces that were original faces
    ``source``): the original's (``texcoords``, m x 3 x 2, of the original ``triangles``, m x 3 x 3), interpolated at
    the nearest point to the new corner among the original faces that face its way in the source face's chart (faces
    joined across edges whose two ends agree in position and texture coordinates); on a tie the source face's own.
    Why: a collapse moves a vertex along the surface, and a corner that kept its own face's texture coordinates would
    drag the texture along (visible at close range, in the wrist camera)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    count = len(triangles)
    wedges = unique_rows(np.concatenate([triangles, texcoords], axis=2).reshape(count * 3, -1))[1].reshape(count, 3)
    edges = np.sort(np.stack([wedges, np.roll(wedges, -1, axis=1)], axis=2), axis=2).reshape(-1, 2)
    edge = unique_rows(edges)[1]
    nodes = count + edge.max() + 1  # the faces, then the edges: a face is joined to its three edges
    links = coo_matrix((np.ones(len(edge)), (np.repeat(np.arange(count), 3), count + edge)), shape=(nodes, nodes))
    chart = connected_components(links, directed=False)[1][:count]
    # the chart as a far-apart 4th coordinate: a search near a corner stays in its source face's chart
    spread = 10 * (np.ptp(triangles.reshape(-1, 3), axis=0).max() + 1.0)
    tree = cKDTree(np.column_stack([triangles.mean(axis=1), chart * spread]))
    queries = np.column_stack([corners.reshape(-1, 3), np.repeat(chart[source], 3) * spread])
    near = tree.query(queries, k=min(NEIGHBOURS, count))[1].reshape(len(queries), -1)
    near = np.column_stack([np.repeat(source, 3), near])  # the source face first, to win a tie
    points = np.repeat(corners.reshape(-1, 1, 3), near.shape[1], axis=1)
    weights = _barycentric(points, triangles[near])
    distance = np.linalg.norm(np.einsum("qnk,qnkc->qnc", weights, triangles[near]) - points, axis=2)
    # in the chart, and facing the same way (a shell's two sides share positions and may share texture coordinates)
    facing = np.einsum("qc,qnc->qn", np.repeat(_normals(corners), 3, axis=0), _normals(triangles)[near])
    valid = (chart[near] == chart[near[:, :1]]) & (facing > 0) & np.isfinite(distance)
    distance = np.where(valid, distance, np.inf)
    best = np.argmax(distance <= distance.min(axis=1, keepdims=True) * (1 + 1e-6), axis=1)
    rows = np.arange(len(queries))
    result = np.einsum("qk,qkd->qd", np.nan_to_num(weights[rows, best]), texcoords[near[rows, best]])
    lost = np.isinf(distance[rows, best])  # no face near that faces its way: the source face's own corner
    result[lost] = texcoords[source].reshape(len(queries), -1)[lost]
    return result.reshape(len(corners), 3, -1)


def _normals(triangles: np.ndarray) -> np.ndarray:
    """The unit normals of ``triangles`` (m x 3 x 3, counter-clockwise), zero for a degenerate one."""
    cross = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    return cross / np.maximum(np.linalg.norm(cross, axis=1, keepdims=True), 1e-30)


def _barycentric(p: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The barycentric weights (..., 3) of the point of each triangle (``triangles``: ..., 3, 3) nearest to ``p``
    (..., 3): Ericson's Real-Time Collision Detection, 5.1.5, vectorised (a degenerate triangle: NaN weights)."""
    a, b, c = triangles[..., 0, :], triangles[..., 1, :], triangles[..., 2, :]
    ab, ac, ap, bp, cp = b - a, c - a, p - a, p - b, p - c

    def dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.einsum("...i,...i->...", x, y)

    def stack(*weights: np.ndarray | float) -> np.ndarray:
        return np.stack(np.broadcast_arrays(*weights), axis=-1)

    d1, d2, d3, d4, d5, d6 = dot(ab, ap), dot(ac, ap), dot(ab, bp), dot(ac, bp), dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        v, w = vb / (va + vb + vc), vc / (va + vb + vc)
        on_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        on_ac, on_ab = d2 / (d2 - d6), d1 / (d1 - d3)
        regions = [  # Ericson's tests in reverse order, so that the first that holds is written last
            ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), stack(0.0, 1 - on_bc, on_bc)),  # on edge bc
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0), stack(1 - on_ac, 0.0, on_ac)),  # on edge ac
            ((d6 >= 0) & (d5 <= d6), stack(0.0, 0.0, np.ones_like(d1))),  # vertex c
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0), stack(1 - on_ab, on_ab, 0.0)),  # on edge ab
            ((d3 >= 0) & (d4 <= d3), stack(0.0, np.ones_like(d1), 0.0)),  # vertex b
            ((d1 <= 0) & (d2 <= 0), stack(np.ones_like(d1), 0.0, 0.0)),  # vertex a
        ]
        weights = stack(1 - v - w, v, w)  # inside the face
        for region, values in regions:
            weights = np.where(region[..., None], values, weights)
    return weights


def unique_rows(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(rows, axis=0, return_inverse=True)`` (the distinct rows, sorted, and each row's index among them),
    by a lexicographic sort of the columns: several times faster than NumPy's sort of rows as opaque bytes."""
    order = np.lexsort(rows.T[::-1])
    ordered = rows[order]
    starts = np.concatenate([[True], np.any(ordered[1:] != ordered[:-1], axis=1)])
    inverse = np.empty(len(rows), dtype=np.int64)
    inverse[order] = np.cumsum(starts) - 1
    return ordered[starts], inverse


def deviation(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, new_faces: np.ndarray) -> np.ndarray:
    """How far the original mesh (``vertices``, ``faces``) lies from its simplification (``points``, ``new_faces``):
    the distance (in the mesh's units, metres) of the original vertices used and faces' centroids (at most
    :data:`SAMPLES` of them, evenly strided) to the nearest of the new faces sampled (corners, edges' midpoints,
    centroid) nearest to them: at least the distance to the new surface, and at most a little more (a long sliver's
    nearest point may lie between its samples)."""
    from scipy.spatial import cKDTree

    queries = np.concatenate([vertices[np.unique(faces)], vertices[faces].mean(axis=1)]).astype(np.float64)
    queries = queries[:: -(-len(queries) // SAMPLES)]  # evenly strided: a percentile needs no more
    triangles = points[new_faces].astype(np.float64)
    samples = np.concatenate(
        [triangles, (triangles + np.roll(triangles, -1, axis=1)) / 2, triangles.mean(axis=1, keepdims=True)], axis=1
    )  # faces x 7 x 3
    owner = np.repeat(np.arange(len(triangles)), samples.shape[1])
    near = cKDTree(samples.reshape(-1, 3)).query(queries, k=min(3 * NEIGHBOURS, len(owner)))[1]
    near = owner[near.reshape(len(queries), -1)]
    distances = np.full(len(queries), np.inf)
    for first in range(0, len(queries), 4096):  # in parts: 48 candidates of 3 x 3 doubles each
        part = slice(first, first + 4096)
        candidates = triangles[near[part]]
        repeated = np.repeat(queries[part, None, :], near.shape[1], axis=1)
        nearest = np.einsum("qnk,qnkc->qnc", _barycentric(repeated, candidates), candidates)
        distances[part] = np.nanmin(np.linalg.norm(nearest - repeated, axis=2), axis=1)
    return distances


__all__ = [
    "CREASE",
    "NEIGHBOURS",
    "SAMPLES",
    "Simplified",
    "simplify_mesh",
    "smooth_normals",
    "deviation",
    "unique_rows",
]

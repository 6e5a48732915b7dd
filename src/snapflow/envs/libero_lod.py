"""Fewer triangles for a LIBERO camera to draw: the render context's copies of the large visual-only meshes replaced
by simplified ones, the model itself (and so the physics) left as it was, bit for bit.

Why: under software OpenGL (Mesa's llvmpipe, as LIBERO is rendered here) a 64-pixel frame costs the vertex processing
of every mesh triangle drawn (~293k a LIBERO-Spatial frame: a bowl 42k, the robot's pedestal 33k, a Panda link
12-15k), nearly all of them far below a pixel at that size. At the defaults (:data:`CAP` triangles a mesh, within
:data:`MAX_DEVIATION` of the original) both 64-px cameras render in 42-57% less time (measured on the first task of
each suite, frustum culling on), their frames within 0.04-1.2 (of 255) mean absolute error of the full meshes' over a
whole expert episode, where storing them as AV1 (crf 30) costs 2.6-3.4.

Which meshes: those only drawn, never collided with: every geom that uses the mesh has ``contype == 0`` and
``conaffinity == 0`` (robosuite's and LIBERO's ``*_vis`` geoms), and the mesh has no convex hull (``mesh_graphadr``
-1: the hull's display list indexes the mesh's vertices, which the upload below rewrites for a moment). A mesh shared
with a colliding geom is left whole.

How: MuJoCo's renderer compiles each mesh into a display list when the render context is made (``mjr_makeContext``)
or a mesh is uploaded again (``mjr_uploadMesh``), reading ``mesh_vert``, ``mesh_face``, ``mesh_facenormal``,
``mesh_facetexcoord``, ``mesh_normal``, ``mesh_texcoord`` and the mesh's ``*adr`` and ``facenum`` fields, and never
after. So each simplified mesh is written into its own slices of those arrays (counts reduced, within the slices),
uploaded with ``mjr_uploadMesh``, and the model's arrays are put back as they were. Nothing that reads the model at
run time sees a change: collisions (visual-only meshes never reach them anyway), ray casts (``mj_ray`` reads the faces
and their BVH, ``mesh_bvhadr``, which simplified faces would have left stale), the boxes ``geom_aabb``/``geom_rbound``
(computed by the compiler from the full mesh, never at run time), inertia (compiled). What changes is only what the
render context draws.

The simplification (:func:`simplify_mesh`): the mesh's vertices welded (MuJoCo keeps a textured mesh as a triangle
soup, a vertex per face corner), cut along its texture's seams where a texture is drawn on it, then quadric edge
collapses (Fast-Quadric-Mesh-Simplification: PyPI's ``fast-simplification``, ~0.8 MB) down to the cap, the seams kept
where they are. The new vertices are clamped to the mesh's original box (so the frustum culling of
:mod:`snapflow.envs.libero_render`, which tests a mesh's ``geom_aabb``, stays exact); the normals are the new surface's
own, smoothed between faces less than :data:`CREASE` degrees apart; the texture coordinates are the original surface's
at the nearest point of the new corner's chart. A mesh that strays further than the bound from its original
(:func:`deviation`) is simplified less, or not at all: LIBERO's wicker basket (its strands are geometry) and its large
table (lit per vertex) lose their look at any cap that saves much. A scene's first simplification takes 7-21 s, so the
results are cached on disk (6-21 MB a scene), keyed by the mesh's content, the cap, the library's version and
:data:`VERSION`: 0.1-0.2 s a scene after that.

What undoes it: anything that builds the render context again from the model (robosuite's ``update_offscreen_size``
on a render at another size, a hard reset that reloads the model) uploads the full meshes: the frames are then exact
again, only slower. Call :func:`simplify_visual_meshes` again after such a rebuild.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from snapflow.envs.mesh_simplification import Simplified, deviation, simplify_mesh, unique_rows

MESH = 7  # mjGEOM_MESH
VERSION = 1  # of the simplification below: part of the cache key, to be raised whenever its output changes
CAP = 5000  # triangles a mesh is simplified to by default (see the module's docstring for the measurements)
MAX_DEVIATION = 1e-3  # metres: the 99th percentile of how far a simplified mesh may lie from its original, by default


@dataclasses.dataclass(frozen=True)
class SimplifiedMeshes:
    """What :func:`simplify_visual_meshes` did to a render context: the meshes it simplified, the triangles each mesh
    of the model is drawn with now (``faces``, indexed by mesh id; ``mesh_facenum`` for the others), the visual-only
    meshes' triangles before and after, its wall time, and how many simplifications (tries included) the disk cache
    held."""

    meshes: tuple[int, ...]
    faces: np.ndarray
    triangles_before: int
    triangles_after: int
    seconds: float
    cached: int


def visual_meshes(model: Any) -> np.ndarray:
    """The ids of the meshes of MuJoCo ``model`` that are drawn and never collided with: used by at least one mesh geom
    and only by geoms with ``contype == 0`` and ``conaffinity == 0``, and without a convex hull."""
    geoms = np.flatnonzero(model.geom_type == MESH)
    meshes = model.geom_dataid[geoms]
    colliding = (model.geom_contype[geoms] != 0) | (model.geom_conaffinity[geoms] != 0)
    visual = np.setdiff1d(np.unique(meshes), meshes[colliding])
    return visual[model.mesh_graphadr[visual] < 0]


def textured_meshes(model: Any) -> np.ndarray:
    """Per mesh of ``model``, whether a geom draws it with a texture (its material has one): only then do its texture
    coordinates show, and must its texture's seams stay put."""
    geoms = np.flatnonzero((model.geom_type == MESH) & (model.geom_matid >= 0))
    textured = np.zeros(model.nmesh, dtype=bool)
    textured[model.geom_dataid[geoms[np.any(model.mat_texid[model.geom_matid[geoms]] >= 0, axis=1)]]] = True
    return textured


def default_cache() -> Path:
    """``$SNAPFLOW_MESH_CACHE``, else ``$XDG_CACHE_HOME/snapflow/meshes`` (``~/.cache`` without it)."""
    if os.environ.get("SNAPFLOW_MESH_CACHE"):
        return Path(os.environ["SNAPFLOW_MESH_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "snapflow" / "meshes"


def _simplified(
    model: Any, mesh: int, target: int, textured: bool, cache: Path | None
) -> tuple[Simplified, float, bool]:
    """:func:`simplify_mesh`'s result for mesh ``mesh`` of ``model`` and its :func:`deviation` (the 99th percentile),
    read from ``cache`` when it holds them (and the flag True), else computed and written there (atomically: several
    collecting processes may write the same file)."""
    vertex, face = model.mesh_vertadr[mesh], model.mesh_faceadr[mesh]
    vertices = model.mesh_vert[vertex : vertex + model.mesh_vertnum[mesh]]
    faces = model.mesh_face[face : face + model.mesh_facenum[mesh]]
    texcoords = None
    if model.mesh_texcoordadr[mesh] >= 0:
        texcoords = model.mesh_texcoord[
            model.mesh_texcoordadr[mesh] + model.mesh_facetexcoord[face : face + len(faces)]
        ]
    path = None
    if cache is not None:
        from fast_simplification import __version__ as library  # its output may change with its version

        key = hashlib.sha256(f"{library} {target} {textured} {VERSION}".encode())
        for part in (vertices, faces, texcoords if texcoords is not None else np.empty(0)):
            key.update(np.ascontiguousarray(part).tobytes())
        path = cache / f"{key.hexdigest()[:40]}.npz"
        try:
            with np.load(path) as stored:
                found = stored["texcoords"] if stored["texcoords"].size else None
                result = (stored["points"], stored["faces"], stored["normals"], found, stored["source"])
                return result, float(stored["deviation"]), True
        except (OSError, KeyError, ValueError):
            pass
    result = simplify_mesh(vertices, faces, texcoords, target, textured)
    error = float(np.percentile(deviation(vertices, faces, result[0], result[1]), 99))
    if path is not None:
        points, new_faces, normals, new_texcoords, source = result
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            partial = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npz")
            empty = np.empty(0, np.float32)
            np.savez(
                partial,
                points=points,
                faces=new_faces,
                normals=normals,
                texcoords=empty if new_texcoords is None else new_texcoords,
                source=source,
                deviation=error,
            )
            os.replace(partial, path)
        except OSError:
            pass  # a read-only or full disk: simplified again next time
    return result, error, False


def _write(model: Any, mesh: int, simplified: Simplified, saved: list[tuple[np.ndarray, slice, np.ndarray]]) -> None:
    """Writes ``simplified`` into mesh ``mesh``'s own slices of ``model``'s arrays, as ``mjr_uploadMesh`` reads them
    (the counts reduced, within the slices), appending to ``saved`` what each write overwrites, (array, slice, old
    values), before it writes, to be put back. Per-corner normals or texture coordinates are deduplicated; where they
    are still more than the mesh's slice holds (a welded mesh has a normal per vertex), each new face takes its
    original face's."""
    points, faces, normals, texcoords, source = simplified
    face = model.mesh_faceadr[mesh]
    writes: list[tuple[np.ndarray, int, Any]] = [
        (model.mesh_vert, model.mesh_vertadr[mesh], points),
        (model.mesh_face, face, faces),
        (model.mesh_vertnum, mesh, [len(points)]),
        (model.mesh_facenum, mesh, [len(faces)]),
    ]
    attributes = [(normals, model.mesh_normal, model.mesh_normaladr, model.mesh_normalnum, model.mesh_facenormal)]
    if texcoords is not None:
        attributes.append(
            (texcoords, model.mesh_texcoord, model.mesh_texcoordadr, model.mesh_texcoordnum, model.mesh_facetexcoord)
        )
    for values, array, addresses, counts, indices in attributes:
        rows, corners = unique_rows(values.reshape(len(faces) * 3, -1))
        if len(rows) <= counts[mesh]:
            writes += [(array, addresses[mesh], rows), (indices, face, corners.reshape(-1, 3))]
            writes += [(counts, mesh, [len(rows)])]
        else:  # the original faces' own, read before any write
            writes.append((indices, face, indices[face + source].copy()))
    for array, start, values in writes:
        part = slice(start, start + len(values))
        saved.append((array, part, array[part].copy()))
        array[part] = values


def simplify_visual_meshes(
    sim: Any,
    max_triangles: int = CAP,
    cache: str | Path | None = "default",
    max_deviation: float | None = MAX_DEVIATION,
) -> SimplifiedMeshes:
    """Makes robosuite ``MjSim`` ``sim``'s off-screen render context draw each visual-only mesh
    (:func:`visual_meshes`) of more than ``max_triangles`` triangles simplified to about ``max_triangles``, leaving the
    model's arrays as they were. With ``max_deviation`` (metres; None: no bound), a mesh whose simplification lies
    further than that from the original (the 99th percentile of :func:`deviation`) is simplified again to twice the
    triangles, and so on, and left whole when even half its triangles do not fit: a few meshes lose their look at any
    cap (LIBERO's wicker basket, whose strands are geometry; its large flat table, lit per vertex). ``cache``: a folder
    for the simplified meshes (``"default"``: :func:`default_cache`; ``None``: none). Call it after the render context
    is made (and again after anything rebuilds it)."""
    import mujoco  # LIBERO's own dependency: snapflow's core does not need it

    if max_triangles < 4:
        raise ValueError(f"max_triangles must be at least 4, got {max_triangles}")
    start = time.perf_counter()
    folder = default_cache() if cache == "default" else None if cache is None else Path(cache)
    model, context = sim.model._model, sim._render_context_offscreen
    faces = model.mesh_facenum.copy()
    visual = visual_meshes(model)
    textured = textured_meshes(model)
    context.gl_ctx.make_current()
    simplified_meshes, cached = [], 0
    for mesh in visual[faces[visual] > max_triangles]:
        target = max_triangles
        while True:
            simplified, error, hit = _simplified(model, mesh, target, bool(textured[mesh]), folder)
            cached += hit
            if max_deviation is None or error <= max_deviation or 2 * target > model.mesh_facenum[mesh] / 2:
                break
            target *= 2
        if max_deviation is not None and error > max_deviation:
            continue  # left whole
        saved: list[tuple[np.ndarray, slice, np.ndarray]] = []
        try:
            _write(model, mesh, simplified, saved)
            mujoco.mjr_uploadMesh(model, context.con, mesh)
        finally:
            for array, part, values in reversed(saved):
                array[part] = values
        faces[mesh] = len(simplified[1])
        simplified_meshes.append(int(mesh))
    return SimplifiedMeshes(
        tuple(simplified_meshes),
        faces,
        int(model.mesh_facenum[visual].sum()),
        int(faces[visual].sum()),
        time.perf_counter() - start,
        cached,
    )


__all__ = [
    "SimplifiedMeshes",
    "simplify_visual_meshes",
    "visual_meshes",
    "textured_meshes",
    "default_cache",
    "VERSION",
    "CAP",
    "MAX_DEVIATION",
]

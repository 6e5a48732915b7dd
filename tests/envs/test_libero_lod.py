"""Simplified visual meshes for LIBERO's cameras (``snapflow.envs.libero_lod``): the physics bit for bit as without,
the model's arrays untouched, far fewer triangles drawn, frames close to the full meshes' (within a stated bound), the
disk cache read back to the same frames; and the simplification itself on a small mesh, without the simulator.

Making a LIBERO environment takes 5-10 s, so the test that steps one is marked slow, as in ``test_libero.py``.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("fast_simplification")  # the libero extra's

from snapflow.envs import libero_lod  # noqa: E402
from snapflow.envs.mesh_simplification import _barycentric, deviation, simplify_mesh, smooth_normals  # noqa: E402

SIZE = 64  # the collections' image size
CAP, MAX_DEVIATION = 5000, 1e-3  # the level the test runs at: the recommended one
# bounds on the frames' mean absolute error (of 255) against the full meshes' at that level, each frame's and the run's
# mean: measured over whole expert episodes of four tasks (one a suite), at most 2.3 a frame (the wrist camera close
# over a textured bowl) and 0.04-1.2 an episode; AV1 at crf 30, as the frames are stored, costs 2.6-3.4 an episode
MAX_FRAME_ERROR, MAX_MEAN_ERROR = 4.0, 1.5


def _sphere(rings: int = 40, segments: int = 80) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A unit UV sphere as MuJoCo keeps a textured mesh: a triangle soup (a vertex per face corner), with a
    longitude/latitude texture map whose seam runs along one meridian."""
    theta = np.linspace(0, np.pi, rings + 1)
    phi = np.linspace(0, 2 * np.pi, segments + 1)  # the last column repeats the first's positions: the seam
    grid = np.stack(np.meshgrid(theta, phi, indexing="ij"), axis=-1)
    uv = np.stack([grid[..., 1] / (2 * np.pi), grid[..., 0] / np.pi], axis=-1)
    t, p = grid[..., 0], grid[..., 1]
    xyz = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)
    xyz[0], xyz[-1] = (0, 0, 1), (0, 0, -1)  # the poles: one position each
    xyz = np.round(xyz, 6)  # so that the seam's two columns weld exactly
    quads = []
    for i in range(rings):
        for j in range(segments):
            a, b, c, d = (i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)
            quads += [(a, b, c), (a, c, d)]
    corners = np.array(quads)  # faces x 3 corners x (ring, segment)
    positions = xyz[corners[..., 0], corners[..., 1]]
    keep = np.linalg.norm(np.cross(positions[:, 1] - positions[:, 0], positions[:, 2] - positions[:, 0]), axis=1) > 0
    positions = positions[keep]
    texcoords = uv[corners[keep][..., 0], corners[keep][..., 1]]
    vertices = positions.reshape(-1, 3).astype(np.float32)
    faces = np.arange(len(vertices)).reshape(-1, 3)
    return vertices, faces, texcoords.astype(np.float32)


def test_the_modules_mujoco_constant_is_mujocos():
    mujoco = pytest.importorskip("mujoco")
    assert libero_lod.MESH == mujoco.mjtGeom.mjGEOM_MESH


def test_barycentric_gives_each_triangles_nearest_point():
    rng = np.random.default_rng(0)
    triangles, points = rng.normal(size=(300, 3, 3)), 2 * rng.normal(size=(300, 3))
    weights = _barycentric(points, triangles)
    nearest = np.einsum("nk,nkc->nc", weights, triangles)
    samples = rng.dirichlet([1, 1, 1], size=5000)  # points spread over each triangle
    sampled = np.array(
        [
            np.linalg.norm(samples @ triangle - point, axis=1).min()
            for triangle, point in zip(triangles, points, strict=True)
        ]
    )
    assert np.all(weights >= -1e-12) and np.allclose(weights.sum(axis=1), 1)
    assert np.all(np.linalg.norm(nearest - points, axis=1) <= sampled + 1e-12)


def test_a_textured_sphere_is_simplified_within_its_box_its_seam_kept():
    """~6k triangles to ~1k: within the original box, unit normals that still point outwards, texture coordinates
    that match the sphere's own map at the new corners (none interpolated across the seam), and no corner's position
    off the sphere by more than its new triangles' size allows. Without ``textured`` the seam is not kept."""
    vertices, faces, texcoords = _sphere()
    points, new_faces, new_normals, new_texcoords, source = simplify_mesh(vertices, faces, texcoords, 1000, True)
    assert 900 <= len(new_faces) <= 1100 < len(faces)
    assert new_faces.min() >= 0 and new_faces.max() < len(points) and points.dtype == np.float32
    assert source.shape == (len(new_faces),) and len(np.unique(source)) == len(source) and source.max() < len(faces)
    assert np.all(points >= vertices.min(axis=0)) and np.all(points <= vertices.max(axis=0))
    assert np.allclose(np.linalg.norm(new_normals, axis=2), 1, atol=1e-5)
    corners = points[new_faces]
    assert np.all(
        np.einsum("fkc,fkc->fk", new_normals, corners / np.linalg.norm(corners, axis=2, keepdims=True)) > 0.99
    )
    assert np.abs(np.linalg.norm(points, axis=1) - 1).max() < 0.02
    # the longitude of a corner off the poles is its u; on the seam (u 0 or 1) its face tells which
    longitude = np.mod(np.arctan2(corners[..., 1], corners[..., 0]), 2 * np.pi) / (2 * np.pi)
    off_poles = np.abs(corners[..., 2]) < 0.99
    error = np.abs(longitude - new_texcoords[..., 0])
    error = np.minimum(error, np.abs(1 - error))  # the seam: 0 and 1 are one longitude
    assert error[off_poles].max() < 0.01
    spans = np.ptp(new_texcoords[..., 0], axis=1)  # no face's u spans the whole map (interpolated across the seam)
    assert spans.max() < 0.25
    _, _, _, across, _ = simplify_mesh(vertices, faces, texcoords, 1000, False)
    assert np.ptp(across[..., 0], axis=1).max() > 0.5  # the seam welded shut: faces across it span the map


def test_deviation_is_zero_on_the_mesh_itself_and_the_chords_sag_on_a_coarse_sphere():
    """A mesh lies on itself; a sphere of ~1k triangles lies within its faces' sag of the fine one (a ~6k-triangle
    sphere's points are on the unit sphere; a face of circumradius r sags inwards by 1 - sqrt(1 - r^2) at most, r at
    most the longest edge over sqrt(3) for a face with no angle over 90 degrees)."""
    vertices, faces, texcoords = _sphere()
    assert deviation(vertices, faces, vertices, faces).max() < 1e-6
    points, new_faces, _, _, _ = simplify_mesh(vertices, faces, texcoords, 1000, True)
    distances = deviation(vertices, faces, points, new_faces)
    edges = np.linalg.norm(points[new_faces] - points[np.roll(new_faces, 1, axis=1)], axis=2)
    assert 0 < np.percentile(distances, 99) < 1 - np.sqrt(1 - edges.max() ** 2 / 3)


def test_smooth_normals_keep_a_cubes_edges_and_round_a_sphere():
    """A cube's faces meet at 90 degrees, beyond the crease: each corner takes its own face's normal; on a fine
    sphere each corner's normal is (nearly) the radial direction."""
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]  # outward windings
    cube = np.array([(a, b, c) for a, b, c, d in quads] + [(a, c, d) for a, b, c, d in quads])
    normals = smooth_normals(corners, cube)
    faces = np.cross(corners[cube[:, 1]] - corners[cube[:, 0]], corners[cube[:, 2]] - corners[cube[:, 0]])
    np.testing.assert_allclose(normals, np.repeat(faces[:, None, :], 3, axis=1), atol=1e-6)
    vertices, soup, _ = _sphere()
    points, welded = np.unique(vertices, axis=0, return_inverse=True)
    sphere = smooth_normals(points, welded.reshape(-1)[soup].astype(np.int32))
    radial = points[welded.reshape(-1)[soup]]
    assert np.einsum("fkc,fkc->fk", sphere, radial).min() > 0.999


@pytest.mark.slow
def test_simplified_meshes_leave_the_physics_bit_for_bit_and_the_frames_close(tmp_path):
    """60 steps of the same actions from the same reset, with full meshes, then with visual meshes simplified (CAP,
    MAX_DEVIATION):
    the same simulator state at every step and the same model arrays (what changed is only what the render context
    draws), far fewer triangles, frames within the bounds of the full meshes' (and not identical: the meshes drawn
    did change), frustum culling (:mod:`snapflow.envs.libero_render`) still exact on them, and the disk cache read back
    to the very same frames."""
    import mujoco

    from snapflow.envs.libero import CAMERAS, LiberoEnv
    from snapflow.envs.libero_lod import simplify_visual_meshes, visual_meshes
    from snapflow.envs.libero_render import render

    env = LiberoEnv("libero_spatial_0", "train", image_size=SIZE)
    try:
        sim = env._env.env.sim
        model = sim.model._model
        arrays = {name: getattr(model, name).copy() for name in dir(model) if name.startswith(("mesh_", "geom_"))}
        actions = [
            np.array([0.6 * np.sin(phase), 0.6 * np.cos(phase), 0.3 * np.sin(2 * phase), 0, 0.3, 0.6, -1])
            for phase in np.linspace(0, 2 * np.pi, 60)
        ]

        def run(culled: bool = False) -> tuple[list[np.ndarray], dict[str, list[np.ndarray]]]:
            env.reset(0, render=False)
            states, frames = [], {camera: [] for camera in CAMERAS}
            for step, action in enumerate(actions):
                observation, _, _ = env.step(action, render=step % 10 == 9)
                states.append(sim.get_state().flatten())
                if step % 10 == 9:
                    frames["image"].append(observation.image)
                    frames["image2"].append(observation.extra_images["image2"])
                    for camera in CAMERAS.values() if culled else ():  # frustum culling still exact (the boxes hold)
                        expected = sim.render(camera_name=camera, width=SIZE, height=SIZE)
                        np.testing.assert_array_equal(render(sim, camera, SIZE, SIZE), expected, err_msg=camera)
            return states, frames

        full_states, full_frames = run()
        stats = simplify_visual_meshes(sim, CAP, cache=tmp_path, max_deviation=MAX_DEVIATION)
        states, frames = run(culled=True)

        for step, (full, state) in enumerate(zip(full_states, states, strict=True)):
            np.testing.assert_array_equal(state, full, err_msg=f"step {step}")
        for name, values in arrays.items():
            np.testing.assert_array_equal(getattr(model, name), values, err_msg=name)

        visual = visual_meshes(model)
        meshes = model.geom_type == mujoco.mjtGeom.mjGEOM_MESH
        colliding = np.flatnonzero(meshes & ((model.geom_contype != 0) | (model.geom_conaffinity != 0)))
        assert not set(visual) & set(model.geom_dataid[colliding]), "a mesh of a colliding geom"
        # the two bowls are one mesh's content: the second is read from the cache the first wrote
        assert stats.meshes and set(stats.meshes) <= set(visual) and stats.cached < len(stats.meshes)
        assert stats.triangles_after < stats.triangles_before / 2
        assert np.all(stats.faces[list(stats.meshes)] < model.mesh_facenum[list(stats.meshes)])

        for camera in CAMERAS:
            full, mine = (np.stack(found[camera]).astype(np.int16) for found in (full_frames, frames))
            error = np.abs(full - mine).mean(axis=(1, 2, 3))
            assert error.max() < MAX_FRAME_ERROR and error.mean() < MAX_MEAN_ERROR, f"{camera}: {error}"
            assert error.max() > 0, f"{camera}: no pixel changed"

        again = simplify_visual_meshes(sim, CAP, cache=tmp_path, max_deviation=MAX_DEVIATION)  # from the cache
        assert again.cached >= len(again.meshes) == len(stats.meshes) and again.seconds < stats.seconds
        np.testing.assert_array_equal(again.faces, stats.faces)
        _, cached_frames = run()
        for camera in CAMERAS:
            np.testing.assert_array_equal(np.stack(cached_frames[camera]), np.stack(frames[camera]))
    finally:
        env.close()


@pytest.mark.slow
def test_the_libero_lod_benchmark_renders_simplified_meshes_over_the_same_scenes(tmp_path, monkeypatch):
    """``--env libero-lod``: LIBERO's tasks, scenes and physics, its cameras drawing the simplified meshes; what a
    sweep's collection and its evaluations both build, so that a policy is evaluated on the frames it trained on."""
    from snapflow.envs.factory import make_benchmark

    monkeypatch.setenv("SNAPFLOW_MESH_CACHE", str(tmp_path))
    lod = make_benchmark("libero-lod")
    assert (lod.name, lod.mesh_triangles, lod.tasks) == ("libero-lod", CAP, make_benchmark("libero").tasks)
    observations = []
    for benchmark in (make_benchmark("libero"), lod):
        env = benchmark.make_env("libero_spatial_4", "train", SIZE)
        try:
            observations.append(env.reset(7))
        finally:
            env.close()
    full, simplified = observations
    np.testing.assert_array_equal(simplified.state, full.state)
    for camera in ("image", "image2"):
        frames = [o.image if camera == "image" else o.extra_images[camera] for o in observations]
        error = np.abs(frames[0].astype(np.int16) - frames[1]).mean()
        assert 0 < error < MAX_FRAME_ERROR, f"{camera}: {error}"

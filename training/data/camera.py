"""Parts as a depth camera sees a body: the surface visible from a virtual camera, by ray casting.

A handheld scanner orbits a person: what one frame sees is the front-facing, unoccluded surface
inside the camera's field of view. Consecutive frames overlap heavily, a frame taken closer sees
a patch inside a farther one, and a frame taken again from nearly the same place sees nearly the
same region: the overlaps real scanning sessions are made of, which random regions never give.
A view is a template vertex mask (bodies share the template's topology), cleaned by the same
rules as every other part, so its spectrum is computed like any other region's.

The body is z-up (anny's and the synthetic body's convention); the camera orbits the vertical
axis through the body's centre. Ray casting uses Embree through trimesh when it is installed
(the ``train`` extra) and trimesh's own ray-triangle code otherwise (slower, same answers).
"""

from dataclasses import dataclass

import numpy as np
import trimesh

from training.data.regions import RegionSampler

HALF_FIELD_OF_VIEW = np.radians(30.0)  # a depth camera's ~60° cone
OCCLUSION_TOLERANCE = 0.005  # m: a ray reaching this close to its vertex saw it
VIEWS_PER_ORBIT = 5  # the orbit views a session chains, 3…5 of them
ORBIT_STEP_DEGREES = (15.0, 60.0)  # azimuth step between consecutive orbit views
RESCAN_DEGREES = (2.0, 6.0)  # "the camera moved a little"
DISTANCE = (1.2, 2.5)  # m from the body's vertical axis, for orbit views
CLOSE_UP_DISTANCE = (0.35, 0.6)  # m from the surface point a close-up looks at


@dataclass(frozen=True)
class Camera:
    """A pinhole cone: where the camera is and the point it looks at (both in metres)."""

    position: np.ndarray
    target: np.ndarray


def visible_vertices(mesh: trimesh.Trimesh, camera: Camera) -> np.ndarray:
    """(n,) whether each vertex is in the view cone, faces the camera and is not occluded."""
    vertices = np.asarray(mesh.vertices)
    rays = vertices - camera.position
    distance = np.linalg.norm(rays, axis=1)
    directions = rays / np.maximum(distance, 1e-12)[:, None]
    axis = camera.target - camera.position
    axis = axis / np.linalg.norm(axis)
    candidates = (directions @ axis >= np.cos(HALF_FIELD_OF_VIEW)) & (
        np.einsum("ij,ij->i", np.asarray(mesh.vertex_normals), directions) < 0
    )
    seen = np.zeros(len(vertices), bool)
    index = np.flatnonzero(candidates)
    if not len(index):
        return seen
    origins = np.repeat(camera.position[None], len(index), axis=0)
    locations, ray_ids, _ = mesh.ray.intersects_location(origins, directions[index], multiple_hits=False)
    first_hit = np.full(len(index), np.inf)
    first_hit[ray_ids] = np.linalg.norm(locations - camera.position, axis=1)
    seen[index] = first_hit >= distance[index] - OCCLUSION_TOLERANCE
    return seen


def body_mesh(vertices: np.ndarray, faces: np.ndarray) -> trimesh.Trimesh:
    return trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), faces, process=False)


def view_mask(sampler: RegionSampler, mesh: trimesh.Trimesh, camera: Camera) -> np.ndarray | None:
    """The admissible region a camera sees (largest component, pin-holes closed), or None."""
    return sampler.clean(visible_vertices(mesh, camera))


def orbit_camera(mesh: trimesh.Trimesh, azimuth: float, distance: float, height: float, aim: float) -> Camera:
    """A camera on the orbit: ``azimuth`` (rad) around the vertical axis, ``distance`` from it,
    ``height`` and ``aim`` (the looked-at height) as fractions of the body's height."""
    low, high = mesh.bounds
    centre = (low + high) / 2
    span = high[2] - low[2]
    direction = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
    position = centre + distance * direction
    position[2] = low[2] + height * span
    target = np.array([centre[0], centre[1], low[2] + aim * span])
    return Camera(position, target)


def close_up_camera(mesh: trimesh.Trimesh, far: Camera, distance: float) -> Camera:
    """A camera closer along the far camera's line of sight, ``distance`` from the surface it
    looks at: it sees a patch of what the far camera sees."""
    axis = far.target - far.position
    axis = axis / np.linalg.norm(axis)
    hits, _, _ = mesh.ray.intersects_location(far.position[None], axis[None], multiple_hits=False)
    surface = hits[0] if len(hits) else far.target
    return Camera(surface - distance * axis, surface)


@dataclass(frozen=True)
class Session:
    """One scanning session of one body: orbit views, a re-scan of the first and a close-up in it."""

    orbit: list[np.ndarray]  # VIEWS_PER_ORBIT consecutive views, in orbit order
    rescan: np.ndarray  # the first view again, the camera moved a little
    close_up: np.ndarray  # a closer view along the first view's line of sight
    step_degrees: float


def scan_session(
    sampler: RegionSampler, vertices: np.ndarray, rng: np.random.Generator, attempts: int = 20
) -> Session | None:
    """A random session around one posed body, or None if no admissible one was found."""
    mesh = body_mesh(vertices, sampler.template.faces)
    for _ in range(attempts):
        start = rng.uniform(0, 2 * np.pi)
        step = np.radians(rng.uniform(*ORBIT_STEP_DEGREES))
        distance, height, aim = rng.uniform(*DISTANCE), rng.uniform(0.2, 1.1), rng.uniform(0.3, 0.8)
        cameras = [orbit_camera(mesh, start + j * step, distance, height, aim) for j in range(VIEWS_PER_ORBIT)]
        orbit = [view_mask(sampler, mesh, camera) for camera in cameras]
        moved = np.radians(rng.uniform(*RESCAN_DEGREES)) * rng.choice([-1, 1])
        rescan = view_mask(
            sampler, mesh, orbit_camera(mesh, start + moved, distance + rng.uniform(-0.05, 0.05), height, aim)
        )
        close_up = view_mask(sampler, mesh, close_up_camera(mesh, cameras[0], rng.uniform(*CLOSE_UP_DISTANCE)))
        if all(m is not None for m in orbit) and rescan is not None and close_up is not None:
            return Session(orbit, rescan, close_up, float(np.degrees(step)))  # type: ignore[arg-type]
    return None

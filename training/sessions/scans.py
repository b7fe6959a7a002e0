"""Scanning sessions of anny people with exact truth, as a front-end scans a person.

Each person is posed once and scanned by a depth camera walking around: at 8 azimuths a far
view, a close-up and a re-scan (24 views in scanning order), then 8 views alternately from above
and below (up to 32: a view that sees no admissible region is left out). Every view is a region
of the body's mesh, so the truth of any session is exact: the spectrum of the union of its
views' template masks, solved by the service's own pipeline (pin-holes capped).
"""

from dataclasses import dataclass

import numpy as np
import trimesh

from app.geometry import Mesh, Solved, SpectrumOptions, mesh_spectrum, solve_bytes
from training.data.camera import body_mesh, close_up_camera, orbit_camera, view_mask
from training.data.regions import RegionSampler
from training.data.spectra import region_mesh, remeshed

K = 20
VARIANTS = ("mesh", "remeshed")  # views as cut from the body, or re-meshed (30 % of vertices collapsed)
SESSION_STREAM = 7  # a Test C person's session pose and cameras: a random stream the build does not use


@dataclass(frozen=True)
class Person:
    body: np.ndarray  # (n, 3) posed vertices, template topology
    masks: list[np.ndarray]  # the session's views as template vertex masks, in scanning order
    rest: np.ndarray  # (n, 3) the same body in the rest pose: the truth a fitted body is scored against
    label: str  # who it is: the seed database's label for Test C's people (stored there in other poses)


def session_masks(sampler: RegionSampler, body: np.ndarray, rng: np.random.Generator) -> list[np.ndarray]:
    """Up to 32 views of one body in scanning order: far, close-up and re-scan at 8 azimuths,
    then 8 views alternately from above and below."""
    mesh = body_mesh(body, sampler.template.faces)
    start = rng.uniform(0, 2 * np.pi)
    cameras = []
    for step in range(8):
        azimuth = start + step * np.pi / 4
        distance, height, aim = rng.uniform(2.0, 2.5), rng.uniform(0.45, 0.75), rng.uniform(0.45, 0.55)
        far = orbit_camera(mesh, azimuth, distance, height, aim)
        moved = np.radians(rng.uniform(2, 6)) * rng.choice([-1, 1])
        cameras += [
            far,
            close_up_camera(mesh, far, rng.uniform(0.35, 0.6)),
            orbit_camera(mesh, azimuth + moved, distance + rng.uniform(-0.05, 0.05), height, aim),
        ]
    for step in range(8):
        high = step % 2 == 0
        azimuth = start + (step + 0.5) * np.pi / 4
        cameras.append(orbit_camera(mesh, azimuth, rng.uniform(1.5, 2.0), 1.3 if high else 0.05, 0.6 if high else 0.35))
    masks = [view_mask(sampler, mesh, camera) for camera in cameras]
    return [mask for mask in masks if mask is not None]


ADULTS = ("man", "woman")
EVERYONE = ("man", "woman", "child")  # as Test C's people are drawn: men, women and children


def people(count: int, seed: int, kinds: tuple[str, ...] = ADULTS) -> tuple[RegionSampler, list[Person]]:
    """``count`` anny people outside the training identities (as many of each of ``kinds`` as
    the count allows, the first kinds taking the remainder), each in one random pose, and their
    sessions."""
    from training.data.bodies import AnnySource

    source = AnnySource()
    sampler = RegionSampler(source.template())
    found = []
    for number, label in enumerate(kinds):
        share = count // len(kinds) + (1 if number < count % len(kinds) else 0)
        if share == 0:  # anny draws no empty batch
            continue
        group = label if label == "child" else f"unknown_{label}"
        identities = source.body.sample_identities(seed * 100 + number, label, group, share)
        for index, identity in enumerate(identities):
            rng = np.random.default_rng([seed, number, index])
            found.append(_scanned(source, sampler, identity, rng, f"calibration_{label}-{seed}-{index:03d}"))
    return sampler, found


def build_identities(source, seed: int = 0) -> list[tuple[int, int, object, str, str]]:
    """Every identity of the standard build, drawn from ``source`` (an AnnySource) as the build
    draws them: (group number, index in the group, anny identity, seed database label, group
    name), group after group."""
    from training.data.presets import PRESETS, groups_of

    drawn, first = [], 0  # the build numbers identities across its groups, in order
    for number, group in enumerate(groups_of(PRESETS["standard"])):
        if group.count > 0:
            label = group.name.split("_")[-1]
            identities = source.body.sample_identities(seed * 100 + number, label, group.name, group.count)
            drawn += [
                (number, index, identity, f"{group.name}-{first + index:03d}", group.name)
                for index, identity in enumerate(identities)
            ]
        first += group.count
    return drawn


def test_c_people(count: int, seed: int = 0) -> tuple[RegionSampler, list[Person]]:
    """The first ``count`` people of the standard build's held-out groups (Test C's people:
    unknown men, unknown women, children, drawn as the build draws them, taken in turn), each in
    a pose of its own (not one of the build's), and their sessions."""
    from training.data.bodies import AnnySource
    from training.data.presets import TRAINING_GROUPS

    source = AnnySource()
    sampler = RegionSampler(source.template())
    held_out = [row for row in build_identities(source, seed) if row[4] not in TRAINING_GROUPS]
    groups = sorted({row[0] for row in held_out})
    by_group = [[row for row in held_out if row[0] == number] for number in groups]
    in_turn = [person for row in zip(*by_group, strict=False) for person in row][:count]  # a man, a woman, a child, …
    found = []
    for number, index, identity, seed_label, _ in in_turn:
        rng = np.random.default_rng([seed, number, index, SESSION_STREAM])
        found.append(_scanned(source, sampler, identity, rng, seed_label))
    return sampler, found


def rest_body(source, identity) -> np.ndarray:
    """(n, 3) an anny identity's body in the rest pose (``source``: an AnnySource)."""
    body = source.body
    return np.asarray(body.pose(identity, np.tile(np.eye(4), (1, len(body.bones), 1, 1)))[0], np.float64)


def _scanned(source, sampler: RegionSampler, identity, rng: np.random.Generator, label: str) -> Person:
    """One person posed at random and scanned, and the same person at rest."""
    body = source.body.pose(identity, source.body.valid_poses(identity, rng, 1, rest_first=False))[0]
    masks = session_masks(sampler, body, rng)
    return Person(np.asarray(body, np.float64), masks, rest_body(source, identity), label)


def view_meshes(person: Person, faces: np.ndarray, variant: str) -> list[Mesh]:
    """The person's views as meshes in the body's frame (``variant``: as cut, or re-meshed)."""
    meshes = [region_mesh(person.body, faces, mask) for mask in person.masks]
    return [remeshed(mesh) for mesh in meshes] if variant == "remeshed" else meshes


def solved_view(mesh: Mesh) -> Solved:
    """A view as the service solves an upload: spectrum, footprint and part."""
    data = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(file_type="ply")
    return solve_bytes(data, "ply", SpectrumOptions(k=K), vectors=False, footprint=True, descriptors=True)


def union_spectrum(body: np.ndarray, faces: np.ndarray, masks: list[np.ndarray]) -> np.ndarray:
    """The truth: the spectrum of the union of the views' template masks, as the service solves it."""
    union = region_mesh(body, faces, np.logical_or.reduce(masks))
    return np.asarray(mesh_spectrum(union, SpectrumOptions(k=K)).eigenvalues)


def relative_error(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Mean relative error over the eigenvalues."""
    return float(np.mean(np.abs(estimate - truth) / truth))

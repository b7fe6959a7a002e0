"""The data set build on a synthetic body (no anny needed): determinism, masks, rules, splits."""

import dataclasses
import shutil

import numpy as np
import pytest

from app.geometry.pipeline import SpectrumOptions, mesh_spectrum
from app.geometry.shapes import Mesh
from tests.training.data.synthetic import SyntheticSource, synthetic_template
from training.data.build import build_dataset
from training.data.overlaps import CAMERA, IDENTICAL, NESTED, RESCAN, TEST_C_GROUPS
from training.data.pairs import AREA_TIE, MIN_GAIN, containment, symmetric_iou
from training.data.presets import PRESETS
from training.data.regions import MAX_AREA_FRACTION, MIN_AREA_FRACTION, RegionSampler
from training.data.spectra import region_mesh
from training.data.splits import TEST_B_MAX_IOU

PRESET = PRESETS["tiny"]


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny")
    build_dataset(SyntheticSource(), PRESET, out, seed=0, workers=2)
    return out


@pytest.fixture(scope="module")
def data(built):
    return dict(np.load(built / "dataset.npz"))


@pytest.fixture(scope="module")
def sampler():
    return RegionSampler(synthetic_template())


def unpack(data, index):
    return np.unpackbits(data["masks"][index], count=len(synthetic_template().vertices)).astype(bool)


def test_same_seed_same_data(built, data, tmp_path):
    build_dataset(SyntheticSource(), PRESET, tmp_path, seed=0, workers=1)
    again = np.load(tmp_path / "dataset.npz")
    assert set(again.files) == set(data)
    for key in data:
        np.testing.assert_array_equal(again[key], data[key], err_msg=key)


def test_no_spectrum_failed(data):
    assert not np.isnan(data["spectra"]).any()


def test_every_part_is_one_component_with_a_boundary(data, sampler):
    # Mask 0, the whole closed body, is a part only of nested rows: (A, whole body) → whole body.
    assert set(data["scenario"][data["mask_b"] == 0]) <= {NESTED}
    parts = np.unique(np.concatenate([data["mask_a"], data["mask_b"]]))
    for index in parts[parts > 0]:
        mask = unpack(data, index)
        assert sampler.is_connected(mask)
        assert MIN_AREA_FRACTION <= sampler.area_fraction(mask) <= MAX_AREA_FRACTION


def test_union_is_the_or_of_its_parts(data):
    for a, b, union, scenario in zip(data["mask_a"], data["mask_b"], data["mask_union"], data["scenario"], strict=True):
        both = unpack(data, a) | unpack(data, b)
        if scenario == "full":
            assert union == 0 and both.all()
        else:
            np.testing.assert_array_equal(unpack(data, union), both)


def test_neither_part_of_a_random_pair_contains_the_other(data, sampler):
    random_pairs = np.isin(data["scenario"], ["full", "partial"])
    for a, b, union in zip(*(data[c][random_pairs] for c in ("mask_a", "mask_b", "mask_union")), strict=True):
        gain = sampler.area_fraction(unpack(data, union)) - max(
            sampler.area_fraction(unpack(data, a)), sampler.area_fraction(unpack(data, b))
        )
        assert gain >= MIN_GAIN - 1e-9


def test_minimum_union_area_rule(data, sampler):
    """Every pair but a camera session's, whose union is what the scanner saw."""
    mirror = sampler.template.mirror
    ruled = ~np.char.startswith(data["scenario"].astype(str), "camera")
    for a, b in zip(data["mask_a"][ruled], data["mask_b"][ruled], strict=True):
        a, b = unpack(data, a), unpack(data, b)
        assert sampler.area_fraction(a | b) <= sampler.area_fraction(a | b[mirror]) + AREA_TIE


def test_splits_keep_held_out_identities_and_poses_out_of_training(data, built):
    import json

    identities = json.loads((built / "work" / "identities.json").read_text())
    group_of_shape = np.repeat([m["group"] for m in identities], PRESET.poses)
    train = data["split"] == "train"
    for column in ("shape_a", "shape_b"):
        assert set(group_of_shape[data[column][train]]) <= {"known_man", "known_woman"}
        assert np.all(data[column][train] % PRESET.poses < PRESET.poses - PRESET.test_poses)
        known_test = (data["split"] != "train") & np.char.startswith(data["group"].astype(str), "known")
        assert np.all(data[column][known_test] % PRESET.poses >= PRESET.poses - PRESET.test_poses)


def test_test_b_unions_were_never_seen_in_training(data, sampler):
    n = len(sampler.template.vertices)
    train = (data["split"] == "train") & (data["scenario"] == "partial")
    seen_masks = np.concatenate([data["mask_union"][train], data["triples"][:, 5:].ravel()])
    seen = np.array([unpack(data, i) for i in seen_masks]).reshape(-1, n)
    test_b = np.array([unpack(data, i) for i in data["mask_union"][data["split"] == "test_b"]])
    assert len(test_b) > 0
    assert np.all(symmetric_iou(test_b, seen, sampler.vertex_area, sampler.template.mirror) < TEST_B_MAX_IOU)


def test_every_test_group_gets_its_test_b_rows(data):
    test_b = (data["split"] == "test_b") & (data["variant"] == "mesh")
    groups, counts = np.unique(data["group"][test_b], return_counts=True)
    assert set(groups) == {"known_man", "known_woman", "unknown_man", "unknown_woman", "child"}
    assert np.all(counts == PRESET.test_pairs)


def test_a_union_has_no_larger_eigenvalue_than_its_parts(data):
    same_shape = (data["shape_a"] == data["shape_b"]) & (data["variant"] == "mesh")
    assert same_shape.any()
    spectra = data["spectra"]
    for row in np.flatnonzero(same_shape):
        union = spectra[data["spec_union"][row]]
        parts = np.minimum(spectra[data["spec_a"][row]], spectra[data["spec_b"][row]])
        assert np.all(union <= parts * 1.01 + 1e-9), row


def test_spectrum_of_the_extracted_submesh_equals_the_region_of_the_full_mesh(sampler):
    template = sampler.template
    mask = sampler.sample(np.random.default_rng(3)).mask
    inside = template.faces[mask[template.faces].all(axis=1)]
    as_region = mesh_spectrum(Mesh(template.vertices, inside), SpectrumOptions(k=10)).eigenvalues
    as_submesh = mesh_spectrum(region_mesh(template.vertices, template.faces, mask), SpectrumOptions(k=10)).eigenvalues
    np.testing.assert_allclose(as_submesh, as_region, rtol=1e-10)


def test_a_killed_build_resumes_without_recomputing_finished_chunks(built, data, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(built, copy)
    chunks = sorted((copy / "work").glob("spectra-*.npz"))
    chunks[-1].unlink()
    (copy / "dataset.npz").unlink()
    finished = {path: path.stat().st_mtime_ns for path in chunks[:-1]}
    build_dataset(SyntheticSource(), PRESET, copy, seed=0, workers=1)
    assert all(path.stat().st_mtime_ns == mtime for path, mtime in finished.items())
    np.testing.assert_array_equal(np.load(copy / "dataset.npz")["spectra"], data["spectra"])


def test_a_build_resumed_over_a_larger_preset_equals_a_fresh_one(built, data, tmp_path):
    """Mask chunks of a preset that drew more (here retrieval pairs) hold this preset's draws first."""
    larger = dataclasses.replace(PRESET, retrieval_pairs=PRESET.retrieval_pairs + 3)
    build_dataset(SyntheticSource(), larger, tmp_path, seed=0, workers=1)
    assert (np.load(tmp_path / "dataset.npz")["split"] == "retrieval").sum() == larger.retrieval_pairs
    (tmp_path / "dataset.npz").unlink()
    build_dataset(SyntheticSource(), PRESET, tmp_path, seed=0, workers=1)
    resumed = np.load(tmp_path / "dataset.npz")
    for key in ("split", "shape_a", "shape_b", "spectra"):
        np.testing.assert_array_equal(resumed[key], data[key], err_msg=key)
    np.testing.assert_array_equal(resumed["masks"][resumed["mask_a"]], data["masks"][data["mask_a"]])


def test_dask_cluster_builds_the_same_data(data, tmp_path):
    import distributed

    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        build_dataset(SyntheticSource(), PRESET, tmp_path, seed=0, scheduler=cluster.scheduler_address)
    np.testing.assert_array_equal(np.load(tmp_path / "dataset.npz")["spectra"], data["spectra"])


def test_sample_files_reproduce_their_stored_spectra_through_the_service_code(built):
    import json

    from app.geometry.pipeline import spectrum_from_bytes

    index = json.loads((built / "samples" / "samples.json").read_text())
    checked = [entry for entry in index if entry["eigenvalues"] is not None]
    assert {entry["variant"] for entry in checked} >= {"mesh", "remeshed"}
    for entry in checked:
        data = (built / "samples" / entry["file"]).read_bytes()
        report = spectrum_from_bytes(data, "ply", SpectrumOptions(k=PRESET.k))
        np.testing.assert_allclose(report.eigenvalues, entry["eigenvalues"], rtol=1e-8, err_msg=entry["file"])


def test_overlap_rows_span_every_overlap_in_training(data, sampler):
    train = data["split"] == "train"
    shares = [
        containment(sampler, unpack(data, a), unpack(data, b))
        for a, b in zip(data["mask_a"][train], data["mask_b"][train], strict=True)
    ]
    counts = np.histogram(shares, bins=[0, 0.25, 0.75, 0.999, 1.001])[0]
    assert np.all(counts > 0), counts


def test_identical_rescan_and_nested_rows_read_existing_parts(data):
    poses = PRESET.poses
    for kind in (IDENTICAL, RESCAN, NESTED):
        rows = np.flatnonzero(data["scenario"] == kind)
        assert len(rows) and {"train", "test_a"} <= set(data["split"][rows])
        for row in rows:
            a, b, union = data["mask_a"][row], data["mask_b"][row], data["mask_union"][row]
            same_identity = data["shape_a"][row] // poses == data["shape_b"][row] // poses
            assert same_identity and (union == b if kind == NESTED else a == b == union)
    identical = data["scenario"] == IDENTICAL
    np.testing.assert_array_equal(data["spec_a"][identical], data["spec_b"][identical])  # literally one spectrum


def test_camera_rows_and_test_c_chains_are_unions_of_views(data, built):
    import json

    identities = json.loads((built / "work" / "identities.json").read_text())
    group_of_shape = np.repeat([m["group"] for m in identities], PRESET.poses)
    camera = np.isin(data["scenario"], CAMERA)
    test_c = data["split"] == "test_c"
    assert camera[test_c].all() and set(data["scenario"][camera & (data["split"] == "train")]) == set(CAMERA)
    assert set(group_of_shape[data["shape_a"][test_c]]) <= set(TEST_C_GROUPS)
    assert len(data["chains"]) > 0
    for chain in data["chains"]:
        views = [unpack(data, m) for m in chain[1:6]]
        for length, union in enumerate(chain[6:], start=2):
            np.testing.assert_array_equal(unpack(data, union), np.any(views[:length], axis=0))


def test_remeshed_training_rows_repeat_mesh_training_rows_with_re_meshed_parts(data):
    remeshed = np.flatnonzero((data["split"] == "train") & (data["variant"] == "remeshed"))
    assert len(remeshed) == PRESET.remeshed_train
    mesh = np.flatnonzero((data["split"] == "train") & (data["variant"] == "mesh"))
    columns = ("group", "scenario", "shape_a", "shape_b", "mask_a", "mask_b", "mask_union")
    originals = {tuple(data[c][row] for c in columns): row for row in mesh}
    spectra = data["spectra"]
    for row in remeshed:
        original = originals[tuple(data[c][row] for c in columns)]  # the same pair, on the same bodies
        assert data["spec_union"][row] == data["spec_union"][original]  # the union stays the mesh's
        a, b = spectra[data["spec_a"][row]], spectra[data["spec_a"][original]]
        assert data["spec_a"][row] != data["spec_a"][original]
        assert 0 < np.max(np.abs(a - b) / b) < 0.5  # another meshing of the same surface

"""Uploads built to hurt: each is refused with its documented problem, and the next request is served.

How fast the refusals come is measured by ``benchmarks/faults.py`` and the overload benchmark
(docs/reliability.md), not asserted here.

The cheap cases (a corrupt file, a mesh with NaNs, an archive, an over-cap body) live in
``test_spectrum_api.py``; these are the ones aimed at the server itself.
"""

import errno
import io
import zipfile
from importlib.metadata import version

import pytest
import starlette.formparsers

from harness.builders import mesh_bytes
from tests.api.test_spectrum_api import assert_problem, post
from tests.conftest import bumpy_patch

# Advisories against the multipart stack with the release that fixed each; the pins must be at
# or past every one (python-multipart parses, Starlette enforces the limits).
FIXED_IN = {
    "python-multipart": {
        "CVE-2024-24762 Content-Type ReDoS": "0.0.7",
        "CVE-2024-53981 boundary DoS": "0.0.18",
        "GHSA-wp53-j4wj-2cfg file write": "0.0.22",
        "GHSA-mj87-hwqh-73pj preamble/epilogue DoS": "0.0.26",
        "CVE-2026-42561 unbounded part headers": "0.0.27",
        "GHSA-5rvq-cxj2-64vf quadratic querystring": "0.0.30",
        "GHSA-v9pg-7xvm-68hf negative Content-Length": "0.0.31",
    },
    "starlette": {
        "CVE-2023-30798 unlimited parts": "0.25.0",
        "CVE-2024-47874 unbounded text fields": "0.40.0",
        "CVE-2025-54121 rollover blocks the loop": "0.47.2",
        "CVE-2025-62727 Range header DoS": "0.49.1",
    },
}


def _release(text: str) -> tuple[int, ...]:
    return tuple(int(part) for part in text.split(".")[:3])


@pytest.mark.parametrize("package", sorted(FIXED_IN))
def test_the_multipart_stack_is_past_every_known_dos_fix(package):
    installed = _release(version(package))
    missing = [advisory for advisory, fixed in FIXED_IN[package].items() if installed < _release(fixed)]
    assert not missing, f"{package} {version(package)} lacks the fixes for {missing}"


def test_more_files_than_any_route_takes_is_a_400(client):
    files = [("files", (f"p{i}.ply", b"ply\n")) for i in range(40)]
    response = client.post("/v1/union", files=files)
    assert "files" in assert_problem(response, 400, "invalid-form")["detail"]


@pytest.mark.parametrize("content", ["multipart", "urlencoded"])
def test_a_flood_of_form_fields_is_a_400(client, content):
    fields = {f"f{i}": "x" for i in range(5000)}
    if content == "multipart":
        response = client.post("/v1/union", data=fields, files={"files": ("a.ply", b"x")})
        assert_problem(response, 400, "invalid-form")
    else:  # no route takes a urlencoded body: it is refused without being parsed into 5 000 fields
        response = client.post("/v1/union", data=fields)
        assert response.status_code in (400, 422) and response.headers["content-type"] == "application/problem+json"


def test_a_text_field_over_a_mebibyte_is_a_400(client):
    spectra = "[[" + ",".join(["1.0"] * 300_000) + "]]"
    response = client.post("/v1/union", data={"spectra": spectra}, files={"files": ("a.ply", b"x")})
    assert_problem(response, 400, "invalid-form")


def _zip_bomb(inflated_bytes: int = 200 * 1024 * 1024) -> bytes:
    """~200 KB on the wire that would inflate to 200 MB of zeros."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=9) as archive:
        with archive.open("scan.ply", "w") as member:
            chunk = b"\0" * (1024 * 1024)
            for _ in range(inflated_bytes // len(chunk)):
                member.write(chunk)
    return buffer.getvalue()


@pytest.mark.parametrize(
    ("name", "status", "slug"), [("bomb.zip", 415, "unsupported-file-type"), ("bomb.ply", 422, "unreadable-file")]
)
def test_a_zip_bomb_is_never_inflated(client, name, status, slug):
    bomb = _zip_bomb()
    assert len(bomb) < 1_000_000
    assert_problem(post(client, name, bomb), status, slug)


def test_a_ply_header_declaring_a_billion_vertices_is_refused_before_parsing(client):
    header = b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000\nproperty float x\n"
    header += b"property float y\nproperty float z\nend_header\n"
    response = post(client, "huge.ply", header + b"\0" * 1200)
    assert_problem(response, 422, "too-many-vertices")


def test_a_full_upload_spool_is_a_retryable_503_not_a_bad_request(client, monkeypatch):
    class FullDisk(starlette.formparsers.SpooledTemporaryFile):
        def rollover(self) -> None:
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(starlette.formparsers, "SpooledTemporaryFile", FullDisk)
    big = mesh_bytes(bumpy_patch(seed=3, n=50_000), "ply")
    assert len(big) > 1024 * 1024  # past Starlette's in-memory spool, so it must go to disk
    response = post(client, "big.ply", big)
    assert_problem(response, 503, "upload-storage-full")
    assert response.headers["retry-after"]


def test_the_service_still_answers_after_the_hostile_requests(client):
    response = post(client, "fine.ply", mesh_bytes(bumpy_patch(seed=5, n=400), "ply"))
    assert response.status_code == 200 and len(response.json()["eigenvalues"]) == 20

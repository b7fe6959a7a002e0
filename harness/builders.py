"""Bytes of every accepted format, and of hostile files, built in code."""

import io
import json
import struct
import zipfile

import numpy as np
import trimesh

from app.geometry.shapes import Mesh


def mesh_bytes(mesh: Mesh, file_type: str, **kwargs) -> bytes:
    """Export with trimesh (ply takes ``encoding='ascii'|'binary'``)."""
    exported = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(file_type=file_type, **kwargs)
    return exported.encode() if isinstance(exported, str) else exported


def ascii_ply(vertices: np.ndarray, faces: np.ndarray | None = None, boundary=None) -> bytes:
    """A hand-written ASCII PLY, so broken values (NaN, bad indices) go in verbatim."""
    lines = [
        "ply",
        "format ascii 1.0",
        f"element vertex {len(vertices)}",
        "property double x",
        "property double y",
        "property double z",
    ]
    if boundary is not None:
        lines.append("property uchar boundary")
    if faces is not None:
        lines += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
    lines.append("end_header")
    for i, v in enumerate(vertices):
        extra = f" {int(boundary[i])}" if boundary is not None else ""
        lines.append(" ".join(repr(float(c)) for c in v) + extra)
    for f in faces if faces is not None else []:
        lines.append("3 " + " ".join(str(int(i)) for i in f))
    return ("\n".join(lines) + "\n").encode()


def glb_with_external_buffer(uri: str, mesh: Mesh) -> bytes:
    """A GLB whose geometry lives in an external buffer file named by ``uri``."""
    gltf = _gltf(mesh, nodes=1)
    gltf["buffers"][0]["uri"] = uri
    return _glb(gltf)


def glb_of(mesh: Mesh, **position) -> bytes:
    """A one-mesh GLB; ``position`` updates its POSITION accessor (to make it sparse, quantized)."""
    gltf = _gltf(mesh, nodes=1)
    gltf["accessors"][0].update(position)
    return _glb(gltf, external_buffer(mesh))


def instanced_glb(mesh: Mesh, nodes: int) -> bytes:
    """A GLB whose ``nodes`` scene nodes each place the one mesh it holds: small on the wire,
    ``nodes`` times the mesh once flattened."""
    return _glb(_gltf(mesh, nodes), external_buffer(mesh))


def _gltf(mesh: Mesh, nodes: int) -> dict:
    positions = len(mesh.vertices) * 12
    return {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": positions + mesh.faces.size * 4}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": positions},
            {"buffer": 0, "byteOffset": positions, "byteLength": mesh.faces.size * 4},
        ],
        "accessors": [
            {
                "bufferView": 0,
                "componentType": 5126,
                "count": len(mesh.vertices),
                "type": "VEC3",
                "min": mesh.vertices.min(axis=0).tolist(),
                "max": mesh.vertices.max(axis=0).tolist(),
            },
            {"bufferView": 1, "componentType": 5125, "count": mesh.faces.size, "type": "SCALAR"},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "nodes": [{"mesh": 0, "translation": [3.0 * i, 0, 0]} for i in range(nodes)],
        "scenes": [{"nodes": list(range(nodes))}],
        "scene": 0,
    }


def _glb(gltf: dict, binary: bytes = b"") -> bytes:
    """Pack a glTF document (and its binary buffer, if embedded) as GLB chunks."""
    chunk = json.dumps(gltf, separators=(",", ":")).encode()
    chunk += b" " * (-len(chunk) % 4)
    body = struct.pack("<II", len(chunk), 0x4E4F534A) + chunk
    if binary:
        binary += b"\0" * (-len(binary) % 4)
        body += struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def external_buffer(mesh: Mesh) -> bytes:
    """The buffer that :func:`glb_with_external_buffer` points at: valid geometry."""
    return mesh.vertices.astype(np.float32).tobytes() + mesh.faces.astype(np.uint32).tobytes()


def npy_bytes(points: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, points)
    return buffer.getvalue()


def zip_of(name: str, data: bytes) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr(name, data)
    return buffer.getvalue()

"""What placing one uploaded part on the template costs, stage by stage, beside LaPy's eigenbasis.

Run: ``python -m benchmarks.bench_correspondence`` (needs ``pip install -e '.[train,dev]'`` for
LaPy and cholespy, and ``models/correspondence.onnx``). Prints, as a Markdown table, the median
milliseconds (stages taking turns within every repeat) on the README's two sample parts (~9 k
and ~11 k vertices) and a ~10 k-point cloud of the second: the Laplacian, the part's spectrum
(k = 20, Dirichlet: what every upload already costs), the correspondence inputs (the k = 64
free-boundary eigenbasis, the heat signature, outward winding and gradient stencil, with the
Laplacian they need) of the whole part and, as the service places a mesh above its vertex budget,
through its simplified copy (app.geometry.placing), the ONNX graph on what the service reads, and
the region, each of ours on one BLAS thread and the graph on one thread, as a solver worker runs
them (the pool runs a worker per core); beside LaPy with CHOLMOD on its default threads solving
the part's own 64 eigenpairs (its strongest configuration), as the peer of the eigenbasis stage.
"""

import argparse
from collections.abc import Callable

import lapy
import numpy as np
from threadpoolctl import ThreadpoolController

from app.contract import CORRESPONDENCE_BASIS, CORRESPONDENCE_FILE
from app.core.config import Settings
from app.geometry.descriptors import mesh_inputs
from app.geometry.laplacian import mesh_operators, point_cloud_operators
from app.geometry.pipeline import SpectrumOptions, mesh_spectrum
from app.geometry.placing import cloud_part, mesh_part
from app.geometry.shapes import Mesh
from app.inference.correspondence import CorrespondenceModel
from app.inference.models import SpectralModels
from app.samples import PARTS, template_part_mesh
from training.common.timing import interleaved_ms

CONTROLLER = ThreadpoolController()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=9)
    args = parser.parse_args()
    directory = Settings().models_dir
    models = SpectralModels(directory)
    model = CorrespondenceModel(directory / CORRESPONDENCE_FILE, models.template_regions)
    print(
        "| part | vertices | placed on | Laplacian | spectrum k = 20 | inputs of the whole part | inputs through "
        "the copy | graph | region | LaPy-CHOLMOD 64 eigenpairs |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, removed in PARTS.items():
        part = template_part_mesh(models.template, removed)
        vertices, faces = part.vertices, part.faces
        _row(name, vertices, faces, model, args.repeats)
    _row("point cloud of " + name, vertices, None, model, args.repeats)


def _row(name: str, vertices: np.ndarray, faces: np.ndarray | None, model, repeats: int) -> None:
    if faces is None:
        part = cloud_part(vertices, None, point_cloud_operators(vertices))
        runs = {"whole": lambda: cloud_part(vertices, None, point_cloud_operators(vertices))}
    else:
        part = mesh_part(vertices, faces, mesh_operators(vertices, faces))
        solver = lapy.Solver(lapy.TriaMesh(vertices, faces), use_cholmod=True)
        runs = {
            "laplacian": lambda: mesh_operators(vertices, faces),
            "spectrum": lambda: mesh_spectrum(Mesh(vertices, faces), SpectrumOptions(k=20)),
            "whole": lambda: mesh_inputs(vertices, faces),
            "copy": lambda: mesh_part(vertices, faces, mesh_operators(vertices, faces)),
        }
    placement = model.place(part)
    runs |= {"graph": lambda: model.place(part), "region": lambda: model.cover(placement)}
    ours = {stage: _one_thread(run) for stage, run in runs.items()}
    peer = {} if faces is None else {"lapy": lambda: solver.eigs(k=CORRESPONDENCE_BASIS)}
    ms = interleaved_ms(ours | peer, repeats)
    cell = lambda key: f"{ms[key]:.0f}" if key in ms else "—"  # noqa: E731
    print(
        f"| {name} | {len(vertices)} | {part.inputs.vertices} | {cell('laplacian')} | {cell('spectrum')} | "
        f"{cell('whole')} | {cell('copy')} | {cell('graph')} | {cell('region')} | {cell('lapy')} |"
    )


def _one_thread(run: Callable[[], object]) -> Callable[[], object]:
    """``run`` on one BLAS thread, as a solver worker runs it."""

    def limited() -> object:
        with CONTROLLER.limit(limits=1):
            return run()

    return limited


if __name__ == "__main__":
    main()

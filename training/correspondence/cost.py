"""What placing one uploaded part costs, measured by the evaluation on the machine that runs it.

The part is the README's larger sample (the template less its left forearm and hand, ~10 k
vertices), computed as a solver worker computes it: one BLAS thread and the graph on one thread
(the service's pool runs a worker per core, so a 2-core machine places two parts at once), and
through its copy of about 6 000 vertices as the service places it (app.geometry.placing). The
stages are disjoint and take turns within every repeat: the part's Laplacian, the copy with the
graph's inputs of it (the 64-function eigenbasis, heat signature, curvature, winding and
stencil), the graph with each place's nearest template vertex, and the region with its shares.
Its own k = 20 spectrum, which every upload costs anyway, is not counted. ``benchmarks/bench_correspondence.py``
times the same stages beside LaPy-CHOLMOD's eigenbasis.
"""

from pathlib import Path

from threadpoolctl import threadpool_limits

from app.geometry import mesh_operators, mesh_part
from app.inference import CorrespondenceModel, SpectralModels
from app.samples import PARTS, template_part_mesh
from training.common.timing import interleaved_ms

COST_PART = "no_left_forearm_hand.ply"
COST_THREADS = 1  # BLAS's and the graph's, as in a solver worker (app.api.solver)
COST_REPEATS = 7


def part_cost(graph: Path, models: Path, repeats: int = COST_REPEATS) -> dict:
    """Median milliseconds of each stage of placing :data:`COST_PART` with ``graph``, and their
    total (``total_ms``)."""
    served = SpectralModels(models)
    model = CorrespondenceModel(graph, served.template_regions, COST_THREADS)
    part = template_part_mesh(served.template, PARTS[COST_PART])
    vertices, faces = part.vertices, part.faces
    operators = mesh_operators(vertices, faces)
    placing = mesh_part(vertices, faces, operators)
    placement = model.place(placing)
    with threadpool_limits(limits=COST_THREADS):
        ms = interleaved_ms(
            {
                "laplacian": lambda: mesh_operators(vertices, faces),
                "inputs": lambda: mesh_part(vertices, faces, operators),
                "graph": lambda: model.place(placing),
                "region": lambda: model.cover(placement),
            },
            repeats,
        )
    stages = {f"{stage}_ms": round(value, 1) for stage, value in ms.items()}
    return {
        "part": COST_PART,
        "vertices": len(vertices),
        "placed_vertices": placing.inputs.vertices,
        "threads": COST_THREADS,
        **stages,
        "total_ms": round(sum(ms.values()), 1),
    }

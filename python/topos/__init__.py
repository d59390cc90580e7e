"""topos from Python: topological domains, their operators and liftings, schedules, HOPNet.

The C++ library topos (header-only, on LibTorch) through its extension ``topos._C``. Tensors
cross without copies (torch's own pybind11 casters); operators come back as torch sparse COO
tensors by default (``format="csr"``, ``"dense"`` or ``"scipy"`` for the others). Names and
conventions are TopoNetX's: ``sc.incidence_matrix(rank, signed=True)``,
``sc.hodge_laplacian_matrix(rank)``, ``cc.adjacency_matrix(rank, via_rank)``, ...
``topos.nn`` builds operator schedules and runs them as torch modules; ``topos.topobench`` trains
any backbone in TopoBench's pipeline. See docs/python.md.
"""

import torch  # noqa: F401  (first: the extension's tensors are torch's)

from ._C import (  # noqa: F401
    CellComplex,
    CombinatorialComplex,
    ComplexError,
    DataError,
    ScheduleError,
    Hypergraph,
    SimplicialComplex,
    __version__,
    clique_complex,
    clique_lifting,
    cycle_basis,
    cycle_lifting,
    khop_lifting,
    neighborhood_hypergraph,
    to_cell_complex,
    to_combinatorial_complex,
    to_hypergraph,
)
from . import hopnet, nn, normalization, topobench  # noqa: F401,E402

"""TopoNetX's ``toponetx.utils.normalization`` functions, on sparse operators.

Each takes torch sparse tensors (COO or CSR) or scipy.sparse matrices and returns the result in
the ``format`` asked (torch sparse COO by default), like the operators of the domains.
"""

from ._C.normalization import (  # noqa: F401
    compute_bunch_normalized_matrices,
    compute_kipf_adjacency_normalized_matrix,
    compute_laplacian_normalized_matrix,
    compute_x_laplacian_normalized_matrix,
    compute_xu_asymmetric_normalized_matrix,
)

"""topos's drop-in for ``topomodelx.utils.sparse``."""

import numpy as np
import torch

__all__ = ["from_sparse"]


def from_sparse(data):
    """A scipy.sparse matrix as a coalesced torch sparse COO tensor of float32 (TopoModelX's
    ``from_sparse``: the same values, dtype and layout)."""
    if not (hasattr(data, "tocoo") and hasattr(data, "nnz")):
        raise TypeError(
            f"from_sparse(data): expected a scipy.sparse matrix, got {type(data).__name__}"
        )
    coo = data.tocoo()
    values = torch.as_tensor(np.asarray(coo.data), dtype=torch.float32)
    indices = torch.as_tensor(np.vstack((coo.row, coo.col)), dtype=torch.long)
    return torch.sparse_coo_tensor(indices, values, coo.shape).coalesce()

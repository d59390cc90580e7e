"""topos's drop-in for ``topomodelx.nn``."""

from . import cell, combinatorial, hypergraph, simplicial  # noqa: F401

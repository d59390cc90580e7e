"""topos's drop-in for ``topomodelx.nn.hypergraph``."""

from .allset import AllSet
from .allset_transformer import AllSetTransformer
from .dhgcn import DHGCN
from .hmpnn import HMPNN
from .hnhn import HNHN
from .hypergat import HyperGAT
from .hypersage import HyperSAGE
from .unigcn import UniGCN
from .unigcnii import UniGCNII
from .unigin import UniGIN
from .unisage import UniSAGE

__all__ = [
    "AllSet",
    "AllSetTransformer",
    "DHGCN",
    "HMPNN",
    "HNHN",
    "HyperGAT",
    "HyperSAGE",
    "UniGCN",
    "UniGCNII",
    "UniGIN",
    "UniSAGE",
]

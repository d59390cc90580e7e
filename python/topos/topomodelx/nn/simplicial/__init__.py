"""topos's drop-in for ``topomodelx.nn.simplicial``."""

from .dist2cycle import Dist2Cycle
from .hsn import HSN
from .san import SAN
from .sca_cmps import SCACMPS
from .sccn import SCCN
from .sccnn import SCCNN
from .scconv import SCConv
from .scn2 import SCN2
from .scnn import SCNN
from .scone import SCoNe

__all__ = [
    "Dist2Cycle",
    "HSN",
    "SAN",
    "SCACMPS",
    "SCCN",
    "SCCNN",
    "SCConv",
    "SCN2",
    "SCNN",
    "SCoNe",
]

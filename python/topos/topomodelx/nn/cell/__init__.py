"""topos's drop-in for ``topomodelx.nn.cell``."""

from .can import CAN
from .ccxn import CCXN
from .cwn import CWN

__all__ = ["CAN", "CCXN", "CWN"]

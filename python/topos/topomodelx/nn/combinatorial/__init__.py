"""topos's drop-in for ``topomodelx.nn.combinatorial``."""

from .hmc import HMC

__all__ = ["HMC"]

"""topos's drop-in for ``topomodelx.nn.simplicial.dist2cycle``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["Dist2Cycle"]


class Dist2Cycle(ZooModule):
    """High Skip Network Implementation for binary node classification (TopoModelX's
    ``nn.simplicial.dist2cycle.Dist2Cycle``, run by topos's C++ zoo)."""

    _operators = ("Linv", "adjacency")
    _returns = "single"

    def __init__(self, channels, n_layers=2, *, topomodelx_compatible=True):
        super().__init__("Dist2Cycle", Dist2Cycle.__init__, locals())

    def forward(self, x_1e, Linv, adjacency):
        return self._forward((x_1e, Linv, adjacency))

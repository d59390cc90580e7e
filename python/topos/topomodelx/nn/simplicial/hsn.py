"""topos's drop-in for ``topomodelx.nn.simplicial.hsn``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["HSN"]


class HSN(ZooModule):
    """High Skip Network Implementation for binary node classification (TopoModelX's
    ``nn.simplicial.hsn.HSN``, run by topos's C++ zoo)."""

    _operators = ("incidence_1", "adjacency_0")
    _returns = "single"

    def __init__(self, channels, n_layers=2, *, topomodelx_compatible=True):
        super().__init__("HSN", HSN.__init__, locals())

    def forward(self, x_0, incidence_1, adjacency_0):
        return self._forward((x_0, incidence_1, adjacency_0))

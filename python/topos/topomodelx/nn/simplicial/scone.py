"""topos's drop-in for ``topomodelx.nn.simplicial.scone``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["SCoNe"]


class SCoNe(ZooModule):
    """Neural network implementation of classification using SCoNe (TopoModelX's
    ``nn.simplicial.scone.SCoNe``, run by topos's C++ zoo)."""

    _operators = ("incidence_1", "incidence_2")
    _returns = "single"

    def __init__(self, in_channels, hidden_channels, n_layers, *, topomodelx_compatible=True):
        super().__init__("SCoNe", SCoNe.__init__, locals())

    def forward(self, x, incidence_1, incidence_2):
        return self._forward((x, incidence_1, incidence_2))

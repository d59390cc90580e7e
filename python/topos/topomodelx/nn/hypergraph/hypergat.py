"""topos's drop-in for ``topomodelx.nn.hypergraph.hypergat``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["HyperGAT"]


class HyperGAT(ZooModule):
    """Neural network implementation of Template for hypergraph classification [1]_
    (TopoModelX's ``nn.hypergraph.hypergat.HyperGAT``, run by topos's C++ zoo)."""

    _operators = ("incidence_1",)
    _returns = "tuple"

    def __init__(
        self,
        in_channels,
        hidden_channels,
        n_layers=2,
        layer_drop=0.2,
        *,
        topomodelx_compatible=True,
        **kwargs,
    ):
        super().__init__("HyperGAT", HyperGAT.__init__, locals())

    def forward(self, x_0, incidence_1):
        return self._forward((x_0, incidence_1))

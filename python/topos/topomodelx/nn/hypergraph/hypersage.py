"""topos's drop-in for ``topomodelx.nn.hypergraph.hypersage``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["HyperSAGE"]


class HyperSAGE(ZooModule):
    """Neural network implementation of HyperSAGE [1]_ for hypergraph classification
    (TopoModelX's ``nn.hypergraph.hypersage.HyperSAGE``, run by topos's C++ zoo)."""

    _operators = ("incidence_1",)
    _returns = "single"

    def __init__(
        self,
        in_channels,
        hidden_channels,
        n_layers=2,
        alpha=-1,
        *,
        topomodelx_compatible=True,
        **kwargs,
    ):
        super().__init__("HyperSAGE", HyperSAGE.__init__, locals())

    def forward(self, x_0, incidence_1):
        return self._forward((x_0, incidence_1))

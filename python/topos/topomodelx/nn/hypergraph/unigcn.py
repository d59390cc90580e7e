"""topos's drop-in for ``topomodelx.nn.hypergraph.unigcn``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["UniGCN"]


class UniGCN(ZooModule):
    """Neural network implementation of UniGCN [1]_ for hypergraph classification (TopoModelX's
    ``nn.hypergraph.unigcn.UniGCN``, run by topos's C++ zoo)."""

    _operators = ("incidence_1",)
    _returns = "tuple"

    def __init__(
        self,
        in_channels,
        hidden_channels,
        n_layers=2,
        *,
        topomodelx_compatible=True,
        **kwargs,
    ):
        super().__init__("UniGCN", UniGCN.__init__, locals())

    def forward(self, x_0, incidence_1):
        return self._forward((x_0, incidence_1))

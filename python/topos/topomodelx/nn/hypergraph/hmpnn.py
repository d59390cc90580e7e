"""topos's drop-in for ``topomodelx.nn.hypergraph.hmpnn``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["HMPNN"]


class HMPNN(ZooModule):
    """Neural network implementation of HMPNN [1]_ (TopoModelX's ``nn.hypergraph.hmpnn.HMPNN``,
    run by topos's C++ zoo)."""

    _operators = ("incidence_1",)
    _returns = "tuple"

    def __init__(
        self,
        in_channels,
        hidden_channels,
        n_layers=2,
        adjacency_dropout_rate=0.7,
        regular_dropout_rate=0.5,
        *,
        topomodelx_compatible=True,
        **kwargs,
    ):
        super().__init__("HMPNN", HMPNN.__init__, locals())

    def forward(self, x_0, x_1, incidence_1):
        return self._forward((x_0, x_1, incidence_1))

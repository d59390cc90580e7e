"""topos's drop-in for ``topomodelx.nn.hypergraph.unigin``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["UniGIN"]


class UniGIN(ZooModule):
    """Neural network implementation of UniGIN [1]_ for hypergraph classification (TopoModelX's
    ``nn.hypergraph.unigin.UniGIN``, run by topos's C++ zoo)."""

    _operators = ("incidence_1",)
    _returns = "tuple"

    def __init__(
        self,
        in_channels,
        hidden_channels,
        n_layers=2,
        input_drop=0.2,
        layer_drop=0.2,
        eps=0,
        train_eps=False,
        use_norm=False,
        *,
        topomodelx_compatible=True,
        **kwargs,
    ):
        super().__init__("UniGIN", UniGIN.__init__, locals())

    def forward(self, x_0, incidence_1):
        return self._forward((x_0, incidence_1))

"""topos's drop-in for ``topomodelx.nn.hypergraph.allset_transformer``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["AllSetTransformer"]


class AllSetTransformer(ZooModule):
    """AllSet Neural Network Module (TopoModelX's
    ``nn.hypergraph.allset_transformer.AllSetTransformer``, run by topos's C++ zoo)."""

    _operators = ("incidence_1",)
    _returns = "tuple"

    def __init__(
        self,
        in_channels,
        hidden_channels,
        n_layers=1,
        heads=4,
        dropout=0.2,
        mlp_num_layers=2,
        mlp_dropout=0.2,
        *,
        topomodelx_compatible=True,
        **kwargs,
    ):
        super().__init__("AllSetTransformer", AllSetTransformer.__init__, locals())

    def forward(self, x_0, incidence_1):
        return self._forward((x_0, incidence_1))

"""topos's drop-in for ``topomodelx.nn.hypergraph.allset``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["AllSet"]


class AllSet(ZooModule):
    """AllSet Neural Network Module (TopoModelX's ``nn.hypergraph.allset.AllSet``, run by
    topos's C++ zoo)."""

    _operators = ("incidence_1",)
    _returns = "tuple"

    def __init__(
        self,
        in_channels,
        hidden_channels,
        n_layers=2,
        layer_dropout=0.2,
        mlp_num_layers=2,
        mlp_activation=None,
        mlp_dropout=0.0,
        mlp_norm=None,
        *,
        topomodelx_compatible=True,
        **kwargs,
    ):
        super().__init__("AllSet", AllSet.__init__, locals())

    def forward(self, x_0, incidence_1):
        return self._forward((x_0, incidence_1))

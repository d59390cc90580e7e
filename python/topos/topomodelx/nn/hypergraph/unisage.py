"""topos's drop-in for ``topomodelx.nn.hypergraph.unisage``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["UniSAGE"]


class UniSAGE(ZooModule):
    """Neural network implementation of UniSAGE [1]_ for hypergraph classification
    (TopoModelX's ``nn.hypergraph.unisage.UniSAGE``, run by topos's C++ zoo)."""

    _operators = ("incidence_1",)
    _returns = "tuple"

    def __init__(
        self,
        in_channels,
        hidden_channels,
        input_drop=0.2,
        layer_drop=0.2,
        n_layers=2,
        e_aggr='sum',
        v_aggr='mean',
        use_norm=False,
        *,
        topomodelx_compatible=True,
        **kwargs,
    ):
        super().__init__("UniSAGE", UniSAGE.__init__, locals())

    def forward(self, x_0, incidence_1):
        return self._forward((x_0, incidence_1))

"""topos's drop-in for ``topomodelx.nn.hypergraph.unigcnii``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["UniGCNII"]


class UniGCNII(ZooModule):
    """Hypergraph neural network utilizing the UniGCNII layer [1]_ for node-level
    classification (TopoModelX's ``nn.hypergraph.unigcnii.UniGCNII``, run by topos's C++
    zoo)."""

    _operators = ("incidence_1",)
    _returns = "tuple"

    def __init__(
        self,
        in_channels,
        hidden_channels,
        n_layers=2,
        alpha=0.5,
        beta=0.5,
        input_drop=0.2,
        layer_drop=0.2,
        use_norm=False,
        *,
        topomodelx_compatible=True,
        **kwargs,
    ):
        super().__init__("UniGCNII", UniGCNII.__init__, locals())

    def forward(self, x_0, incidence_1):
        return self._forward((x_0, incidence_1))

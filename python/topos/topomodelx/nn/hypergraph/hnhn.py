"""topos's drop-in for ``topomodelx.nn.hypergraph.hnhn``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["HNHN"]


class HNHN(ZooModule):
    """Hypergraph Networks with Hyperedge Neurons [1]_. Implementation for multiclass node
    classification (TopoModelX's ``nn.hypergraph.hnhn.HNHN``, run by topos's C++ zoo)."""

    _operators = ("incidence_1",)
    _returns = "tuple"

    def __init__(
        self,
        in_channels,
        hidden_channels,
        incidence_1,
        n_layers=2,
        layer_drop=0.2,
        *,
        topomodelx_compatible=True,
        **kwargs,
    ):
        super().__init__("HNHN", HNHN.__init__, locals())

    def forward(self, x_0, incidence_1=None):
        return self._forward((x_0, incidence_1))

"""topos's drop-in for ``topomodelx.nn.simplicial.scnn``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["SCNN"]


class SCNN(ZooModule):
    """Simplicial convolutional neural network implementation for complex classification
    (TopoModelX's ``nn.simplicial.scnn.SCNN``, run by topos's C++ zoo)."""

    _operators = ("laplacian_down", "laplacian_up")
    _returns = "single"

    def __init__(
        self,
        in_channels,
        hidden_channels,
        conv_order_down,
        conv_order_up,
        aggr_norm=False,
        update_func=None,
        n_layers=2,
        *,
        topomodelx_compatible=True,
    ):
        super().__init__("SCNN", SCNN.__init__, locals())

    def forward(self, x, laplacian_down, laplacian_up):
        return self._forward((x, laplacian_down, laplacian_up))

"""topos's drop-in for ``topomodelx.nn.cell.can``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["CAN"]


class CAN(ZooModule):
    """CAN (Cell Attention Network) [1]_ module for graph classification (TopoModelX's
    ``nn.cell.can.CAN``, run by topos's C++ zoo)."""

    _operators = ("adjacency_0", "down_laplacian_1", "up_laplacian_1")
    _returns = "single"

    def __init__(
        self,
        in_channels_0,
        in_channels_1,
        out_channels,
        dropout=0.5,
        heads=2,
        concat=True,
        skip_connection=True,
        att_activation=None,
        n_layers=2,
        att_lift=True,
        pooling=False,
        k_pool=0.5,
        *,
        topomodelx_compatible=True,
        **kwargs,
    ):
        super().__init__("CAN", CAN.__init__, locals())

    def forward(self, x_0, x_1, adjacency_0, down_laplacian_1, up_laplacian_1):
        return self._forward((x_0, x_1, adjacency_0, down_laplacian_1, up_laplacian_1))

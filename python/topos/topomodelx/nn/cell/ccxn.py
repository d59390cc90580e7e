"""topos's drop-in for ``topomodelx.nn.cell.ccxn``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["CCXN"]


class CCXN(ZooModule):
    """CCXN [1]_ (TopoModelX's ``nn.cell.ccxn.CCXN``, run by topos's C++ zoo)."""

    _operators = ("adjacency_0", "incidence_2_t")
    _returns = "tuple"

    def __init__(
        self,
        in_channels_0,
        in_channels_1,
        in_channels_2,
        n_layers=2,
        att=False,
        *,
        topomodelx_compatible=True,
        **kwargs,
    ):
        super().__init__("CCXN", CCXN.__init__, locals())

    def forward(self, x_0, x_1, adjacency_0, incidence_2_t):
        return self._forward((x_0, x_1, adjacency_0, incidence_2_t))

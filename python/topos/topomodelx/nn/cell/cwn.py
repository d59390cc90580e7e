"""topos's drop-in for ``topomodelx.nn.cell.cwn``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["CWN"]


class CWN(ZooModule):
    """Implementation of a specific version of CW network [1]_ (TopoModelX's
    ``nn.cell.cwn.CWN``, run by topos's C++ zoo)."""

    _operators = ("adjacency_0", "incidence_2", "incidence_1_t")
    _returns = "tuple"

    def __init__(
        self,
        in_channels_0,
        in_channels_1,
        in_channels_2,
        hid_channels,
        n_layers,
        *,
        topomodelx_compatible=True,
        **kwargs,
    ):
        super().__init__("CWN", CWN.__init__, locals())

    def forward(self, x_0, x_1, x_2, adjacency_0, incidence_2, incidence_1_t):
        return self._forward((x_0, x_1, x_2, adjacency_0, incidence_2, incidence_1_t))

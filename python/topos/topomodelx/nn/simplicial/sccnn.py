"""topos's drop-in for ``topomodelx.nn.simplicial.sccnn``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["SCCNN"]


class SCCNN(ZooModule):
    """SCCNN implementation for complex classification (TopoModelX's
    ``nn.simplicial.sccnn.SCCNN``, run by topos's C++ zoo)."""

    _operators = ("laplacian_all", "incidence_all")
    _returns = "tuple"

    def __init__(
        self,
        in_channels_all,
        hidden_channels_all,
        conv_order,
        sc_order,
        aggr_norm=False,
        update_func=None,
        n_layers=2,
        *,
        topomodelx_compatible=True,
    ):
        super().__init__("SCCNN", SCCNN.__init__, locals())

    def forward(self, x_all, laplacian_all, incidence_all):
        return self._forward((x_all, laplacian_all, incidence_all))

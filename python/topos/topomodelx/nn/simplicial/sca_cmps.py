"""topos's drop-in for ``topomodelx.nn.simplicial.sca_cmps``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["SCACMPS"]


class SCACMPS(ZooModule):
    """SCA with CMPS (TopoModelX's ``nn.simplicial.sca_cmps.SCACMPS``, run by topos's C++ zoo)."""

    _operators = ("laplacian_down_list", "incidence_t_list")
    _returns = "list_inplace"

    def __init__(
        self,
        in_channels_all,
        complex_dim,
        n_layers=2,
        att=False,
        *,
        topomodelx_compatible=True,
    ):
        super().__init__("SCACMPS", SCACMPS.__init__, locals())

    def forward(self, x, laplacian_down_list, incidence_t_list):
        return self._forward((x, laplacian_down_list, incidence_t_list))

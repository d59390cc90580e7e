"""topos's drop-in for ``topomodelx.nn.simplicial.scn2``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["SCN2"]


class SCN2(ZooModule):
    """Simplex Convolutional Network Implementation for binary node classification
    (TopoModelX's ``nn.simplicial.scn2.SCN2``, run by topos's C++ zoo)."""

    _operators = ("laplacian_0", "laplacian_1", "laplacian_2")
    _returns = "tuple"

    def __init__(
        self,
        in_channels_0,
        in_channels_1,
        in_channels_2,
        n_layers=2,
        *,
        topomodelx_compatible=True,
    ):
        super().__init__("SCN2", SCN2.__init__, locals())

    def forward(self, x_0, x_1, x_2, laplacian_0, laplacian_1, laplacian_2):
        return self._forward((x_0, x_1, x_2, laplacian_0, laplacian_1, laplacian_2))

"""topos's drop-in for ``topomodelx.nn.simplicial.san``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["SAN"]


class SAN(ZooModule):
    """Simplicial Attention Network (SAN) implementation for binary edge classification
    (TopoModelX's ``nn.simplicial.san.SAN``, run by topos's C++ zoo)."""

    _operators = ("laplacian_up", "laplacian_down")
    _returns = "single"

    def __init__(
        self,
        in_channels,
        hidden_channels,
        out_channels=None,
        n_filters=2,
        order_harmonic=5,
        epsilon_harmonic=0.1,
        n_layers=2,
        *,
        topomodelx_compatible=True,
    ):
        super().__init__("SAN", SAN.__init__, locals())

    def forward(self, x, laplacian_up, laplacian_down):
        return self._forward((x, laplacian_up, laplacian_down))

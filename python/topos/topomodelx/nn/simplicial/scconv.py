"""topos's drop-in for ``topomodelx.nn.simplicial.scconv``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["SCConv"]


class SCConv(ZooModule):
    """Simplicial 2-Complex Convolutional Network Implementation for binary node classification
    (TopoModelX's ``nn.simplicial.scconv.SCConv``, run by topos's C++ zoo)."""

    _operators = (
        "incidence_1",
        "incidence_1_norm",
        "incidence_2",
        "incidence_2_norm",
        "adjacency_up_0_norm",
        "adjacency_up_1_norm",
        "adjacency_down_1_norm",
        "adjacency_down_2_norm",
    )
    _returns = "tuple"

    def __init__(
        self,
        node_channels,
        edge_channels=None,
        face_channels=None,
        n_layers=2,
        *,
        topomodelx_compatible=True,
    ):
        super().__init__("SCConv", SCConv.__init__, locals())

    def forward(
        self,
        x_0,
        x_1,
        x_2,
        incidence_1,
        incidence_1_norm,
        incidence_2,
        incidence_2_norm,
        adjacency_up_0_norm,
        adjacency_up_1_norm,
        adjacency_down_1_norm,
        adjacency_down_2_norm,
    ):
        return self._forward(
            (
                x_0,
                x_1,
                x_2,
                incidence_1,
                incidence_1_norm,
                incidence_2,
                incidence_2_norm,
                adjacency_up_0_norm,
                adjacency_up_1_norm,
                adjacency_down_1_norm,
                adjacency_down_2_norm,
            )
        )

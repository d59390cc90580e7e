"""topos's drop-in for ``topomodelx.nn.combinatorial.hmc``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["HMC"]


class HMC(ZooModule):
    """Higher Order Attention Network for Mesh Classification (TopoModelX's
    ``nn.combinatorial.hmc.HMC``, run by topos's C++ zoo)."""

    _operators = (
        "neighborhood_0_to_0",
        "neighborhood_1_to_1",
        "neighborhood_2_to_2",
        "neighborhood_0_to_1",
        "neighborhood_1_to_2",
    )
    _returns = "tuple"

    def __init__(
        self,
        channels_per_layer,
        negative_slope=0.2,
        update_func_attention='relu',
        update_func_aggregation='relu',
        *,
        topomodelx_compatible=True,
    ):
        super().__init__("HMC", HMC.__init__, locals())

    def forward(
        self,
        x_0,
        x_1,
        x_2,
        neighborhood_0_to_0,
        neighborhood_1_to_1,
        neighborhood_2_to_2,
        neighborhood_0_to_1,
        neighborhood_1_to_2,
    ):
        return self._forward(
            (
                x_0,
                x_1,
                x_2,
                neighborhood_0_to_0,
                neighborhood_1_to_1,
                neighborhood_2_to_2,
                neighborhood_0_to_1,
                neighborhood_1_to_2,
            )
        )

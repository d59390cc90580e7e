"""topos's drop-in for ``topomodelx.nn.simplicial.sccn``."""

from topos.topomodelx._zoo import ZooModule

__all__ = ["SCCN"]


class SCCN(ZooModule):
    """Simplicial Complex Convolutional Network Implementation for binary node classification
    (TopoModelX's ``nn.simplicial.sccn.SCCN``, run by topos's C++ zoo)."""

    _operators = ("incidences", "adjacencies")
    _returns = "dict"

    def __init__(
        self,
        channels,
        max_rank,
        n_layers=2,
        update_func='sigmoid',
        *,
        topomodelx_compatible=True,
    ):
        super().__init__("SCCN", SCCN.__init__, locals())

    def forward(self, features, incidences, adjacencies):
        return self._forward((features, incidences, adjacencies))

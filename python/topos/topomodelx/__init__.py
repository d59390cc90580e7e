"""A drop-in for TopoModelX: its 25 models at its module paths, run by topos's C++ model zoo.

    from topos.topomodelx.nn.simplicial.scn2 import SCN2   # was: from topomodelx.nn...

Every model takes TopoModelX's constructor and forward arguments, returns its outputs, has its
``state_dict`` names and, under the same ``torch.manual_seed``, its initial parameters; a
training script runs unchanged but for the import. Where TopoModelX's numbers differ from the
model's paper (docs/models.md lists where), the drop-in gives TopoModelX's;
``topomodelx_compatible=False`` gives the paper's. DHGCN, whose hypergraph is rebuilt from the
features at every forward, is written in torch. See docs/python.md, "TopoModelX drop-in".
"""

from . import nn, utils  # noqa: F401
from ._zoo import ZooError  # noqa: F401

__all__ = ["ZooError", "nn", "utils"]

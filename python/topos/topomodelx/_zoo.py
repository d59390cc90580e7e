"""The base of topos.topomodelx's models: a TopoModelX model run by topos's C++ zoo.

A model is built by the C++ zoo from its TopoModelX constructor arguments (those given, as JSON;
TopoModelX's defaults are the zoo's), its parameters and buffers are the C++ module's own
tensors at TopoModelX's ``state_dict`` names, and it is then initialised as TopoModelX
initialises it, draw for draw from torch's default generator (``_init.py``), so the same
``torch.manual_seed`` gives the same initial parameters.
"""

import inspect
import json

import torch

from topos._C.zoo import ZooError, _ZooModel
from topos.nn import _SharedTensors

from . import _init

__all__ = ["ZooError", "ZooModule"]


def _config_value(name, v, model):
    """A constructor argument as the zoo's JSON reads it."""
    if isinstance(v, type) and issubclass(v, torch.nn.Module):
        return f"torch.nn.{v.__name__}"  # AllSet's mlp_activation / mlp_norm
    if isinstance(v, (bool, int, float, str)) or v is None:
        return v
    if isinstance(v, (list, tuple)):
        return [_config_value(name, x, model) for x in v]
    raise ZooError(
        f"{model}({name}=...): a {type(v).__name__} is not supported here (numbers, strings, "
        f"lists and torch.nn classes are)"
    )


def _same(a, b):
    try:
        return type(a) is type(b) and bool(a == b)
    except Exception:  # e.g. a tensor against None
        return False


class ZooModule(_SharedTensors):
    """A TopoModelX model (its class name ``_model``), its forward run by the C++ zoo.

    Subclasses set ``_operators`` (the forward arguments that are operators: a dense tensor
    there is passed as ``x.to_sparse()``, as TopoModelX's ``torch.mm`` would use it) and
    ``_returns`` (``single``, ``tuple``, ``dict`` or ``list_inplace``: TopoModelX's return form).
    ``topomodelx_compatible=False`` gives the model as its paper defines it where TopoModelX
    differs (docs/models.md lists where).
    """

    _error = ZooError
    _operators = ()
    _returns = "tuple"

    def __init__(self, model, init, arguments):
        super().__init__()
        arguments = dict(arguments)
        for k in ("self", "__class__"):
            arguments.pop(k, None)
        compatible = bool(arguments.pop("topomodelx_compatible"))
        arguments.update(arguments.pop("kwargs", {}))
        params = inspect.signature(init).parameters
        config = {}
        for k, v in arguments.items():
            p = params.get(k)
            if p is not None and p.default is not inspect.Parameter.empty and _same(v, p.default):
                continue  # TopoModelX's default is the zoo's
            config[k] = v
        self._incidence_1 = None
        if model == "HNHN" and isinstance(config.get("incidence_1"), torch.Tensor):
            # HNHN takes its incidence in the constructor or in forward; the zoo in forward.
            self._incidence_1 = config["incidence_1"]
        if "incidence_1" in config and model == "HNHN":
            config["incidence_1"] = None
        config = {k: _config_value(k, v, model) for k, v in config.items()}
        self._model = model
        self._config = config
        # The C++ constructor's own initialisation draws from the same generator: undo its draws,
        # so that the replay below starts where TopoModelX's constructor would.
        rng = torch.get_rng_state()
        self._zoo = _ZooModel(model, json.dumps(config), compatible)
        torch.set_rng_state(rng)
        tensors = {path: (t, is_buffer) for path, t, is_buffer in self._zoo.tensors()}
        order = _init.reset({k: t for k, (t, _) in tensors.items()}, model, arguments)
        self._share([(k, *tensors[k]) for k in order])

    def _forward(self, args):
        self._check_shared()
        names = list(inspect.signature(self.forward).parameters)
        args = list(args)
        for i, name in enumerate(names):
            if name in self._operators:
                args[i] = _sparse(args[i])
        if self._model == "HNHN" and args[1] is None:
            if self._incidence_1 is None:
                raise ZooError(
                    "HNHN.forward: no incidence_1 (pass it to forward or to the constructor)"
                )
            args[1] = _sparse(self._incidence_1)
        out = self._zoo.forward(args, self.training)
        if self._returns == "single":
            return out[0]
        if self._returns == "dict":  # SCCN: features by "rank_<k>"
            return {f"rank_{k}": y for k, y in enumerate(out)}
        if self._returns == "list_inplace":
            # SCA-CMPS writes its results into the list it was given and returns that list.
            x = args[0]
            if isinstance(x, list):
                x[:] = out
                return x
            return list(out)
        return tuple(out)

    def extra_repr(self):
        return f"{self._model}({json.dumps(self.__dict__.get('_config', {}))[1:-1]})"


def _sparse(a):
    """An operator argument: a dense tensor as its nonzero entries (recursively in lists, tuples
    and dicts); sparse tensors, scipy matrices and None as they are."""
    if isinstance(a, torch.Tensor) and a.layout == torch.strided:
        return a.to_sparse()
    if isinstance(a, (list, tuple)):
        return type(a)(_sparse(x) for x in a)
    if isinstance(a, dict):
        return {k: _sparse(x) for k, x in a.items()}
    return a

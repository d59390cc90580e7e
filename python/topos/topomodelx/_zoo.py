"""The base of topos.topomodelx's models: a TopoModelX model run by topos's C++ zoo.

A model is built by the C++ zoo from its TopoModelX constructor arguments (those given, as JSON;
TopoModelX's defaults are the zoo's), its parameters and buffers are the C++ module's own
tensors at TopoModelX's ``state_dict`` names, and it is then initialised as TopoModelX
initialises it, draw for draw from torch's default generator (``_init.py``), so the same
``torch.manual_seed`` gives the same initial parameters.
"""

import inspect
import json
import weakref

import torch

from topos._C.zoo import ZooError, _ZooModel
from topos.nn import SparseOperator, _SharedTensors

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
        cls = type(self)
        if "_operator_positions" not in cls.__dict__:
            names = list(inspect.signature(cls.forward).parameters)[1:]
            cls._operator_positions = [i for i, n in enumerate(names) if n in cls._operators]
        args = list(args)
        cache = self.__dict__.setdefault("_operator_cache", _OperatorCache())
        dtype = self._shared[0][3].dtype if self._shared else torch.get_default_dtype()
        for i in cls._operator_positions:
            args[i] = cache.convert(args[i], dtype)
        if self._model == "HNHN" and args[1] is None:
            if self._incidence_1 is None:
                raise ZooError(
                    "HNHN.forward: no incidence_1 (pass it to forward or to the constructor)"
                )
            args[1] = cache.convert(self._incidence_1, dtype)
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

    def __deepcopy__(self, memo):
        # A copy of the C++ module (its clone), its tensors registered as here; the generator is
        # left as it was and the operator cache starts empty.
        other = type(self).__new__(type(self))
        _SharedTensors.__init__(other)
        for k in ("_model", "_config", "_incidence_1"):
            setattr(other, k, getattr(self, k))
        rng = torch.get_rng_state()  # the C++ clone builds its modules anew, drawing
        other._zoo = self._zoo.clone()
        torch.set_rng_state(rng)
        tensors = {path: (t, is_buffer) for path, t, is_buffer in other._zoo.tensors()}
        other._share([(path, *tensors[path]) for path, *_ in self._shared])
        for (_, _, _, t, _), (_, _, _, u, _) in zip(self._shared, other._shared):
            u.requires_grad_(t.requires_grad)
        other.train(self.training)
        memo[id(self)] = other
        return other

    def extra_repr(self):
        return f"{self._model}({json.dumps(self.__dict__.get('_config', {}))[1:-1]})"


class _OperatorCache:
    """Operators converted once: a TopoModelX script passes the same operator tensors at every
    forward, and converting them (CSR and its transpose) costs as much as a layer. A tensor is
    looked up by identity, alive (weakly referenced) and unchanged (its version counter): a
    sparse one keeps its values tensor in the converted operator, so a change to its values is
    seen; a dense one (used by its nonzero entries, ``x.to_sparse()``) is converted again after
    an in-place change. Lists, tuples and dicts are converted item by item; other arguments
    (scipy matrices, None, SparseOperator) pass as they are."""

    def __init__(self):
        self._entries = {}

    def convert(self, a, dtype):
        if isinstance(a, (list, tuple)):
            return type(a)(self.convert(x, dtype) for x in a)
        if isinstance(a, dict):
            return {k: self.convert(x, dtype) for k, x in a.items()}
        if not isinstance(a, torch.Tensor):
            return a
        key = id(a)
        entry = self._entries.get(key)
        if entry is not None and entry[0]() is a and entry[1] == (a._version, dtype):
            return entry[2]
        s = a.to_sparse() if a.layout == torch.strided else a
        if s.dtype != dtype or a.requires_grad or (s.layout == torch.sparse_coo and not s.is_coalesced()):
            return s  # converted (a copy) at each call, as the zoo does
        op = SparseOperator(s)
        entries = self._entries
        ref = weakref.ref(a, lambda _, k=key: entries.pop(k, None))
        entries[key] = (ref, (a._version, dtype), op)
        return op

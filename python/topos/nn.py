"""The operator schedule from Python: build a schedule with C++'s vocabulary, run it as a module.

    from topos.nn import OperatorSchedule, OperatorNetwork, into, from_, Activation

    s = OperatorSchedule()
    s.input("x_0", 0, 4).input("x_1", 1, 3).operator_input("incidence_1", 1, 0)
    s.step(into(0).sum(from_(1).conv("conv", 8).via("incidence_1").act(Activation.relu),
                       from_(0).linear("self", 8)))
    s.output("x_0", 0)
    net = OperatorNetwork(s)                   # a torch.nn.Module; checked here
    y = net({"x_0": x0, "x_1": x1}, {"incidence_1": B1})["x_0"]

``from_`` is C++'s ``from`` (a Python keyword). The network is built once and run by the C++
engine with the GIL released; its parameters are the C++ network's own tensors, registered as
``torch.nn.Parameter`` at the schedule's dotted paths, so ``state_dict``, ``.to()``, optimizers,
``train()`` / ``eval()`` and autograd work as for any module. An operation written in Python
(``Operation``: ``infer`` and ``forward``) is applied with ``.apply(op)`` like a built-in one.
See docs/python.md, "Schedules and operations in Python".
"""

import collections.abc

import torch

from ._C import ScheduleError  # noqa: F401
from ._C.nn import (  # noqa: F401
    Activation,
    Aggr,
    AttentionNorm,
    BuildContext,
    MlpOptions,
    OperationTraits,
    OperatorSchedule,
    OperatorStep,
    ParameterInit,
    RunContext,
    SparseOperator,
    Term,
    TermShape,
    Update,  # deprecated: Activation's earlier name
    _Network,
    bfloat16_kernels,
    cached_cpu_bytes,
    from_,
    get_cpu_gemm,
    get_float32_matmul_precision,
    into,
    release_cached_cpu_memory,
    set_cpu_gemm,
    set_float32_matmul_precision,
    use_caching_cpu_allocator,
)

__all__ = [
    "Activation",
    "Aggr",
    "AttentionNorm",
    "BuildContext",
    "MlpOptions",
    "Operation",
    "OperationTraits",
    "OperatorNetwork",
    "OperatorSchedule",
    "OperatorStep",
    "ParameterInit",
    "Plan",
    "RunContext",
    "ScheduleError",
    "SparseOperator",
    "Term",
    "TermShape",
    "bfloat16_kernels",
    "cached_cpu_bytes",
    "from_",
    "get_cpu_gemm",
    "get_float32_matmul_precision",
    "into",
    "release_cached_cpu_memory",
    "set_cpu_gemm",
    "set_float32_matmul_precision",
    "use_caching_cpu_allocator",
]


class Operation:
    """An operation written in Python, applied in a term or a step with ``.apply(op)``.

    Subclass it (or write any object with the same methods):

    - ``infer(ctx, x)``: once, when the network is built. ``x`` is the operand's ``TermShape``
      (``rank``, ``channels``); create parameters with ``ctx.parameter(path, shape, init)``,
      check with ``ctx.fail(why)`` (a ``ScheduleError`` naming the step), and return the
      ``TermShape`` produced (``x`` when both are kept).
    - ``forward(ctx, x)``: at every forward, in torch (autograd flows through it). ``x`` is
      cells × channels; ``ctx.parameter(path)`` is the module's own Parameter, ``ctx.op(name)``
      an operator as a torch sparse COO tensor, ``ctx.cochain(key)`` a cochain before the step,
      ``ctx.is_training()``. The result is checked against ``infer``'s.
    - ``str(x)`` (optional): its printed form applied to ``x``.
    - ``traits()`` (optional): an ``OperationTraits`` for the network's fast paths; the default
      promises nothing.

    The context is valid during the call only. The C++ engine takes the GIL to call these.
    """

    def str(self, x):
        return f"{type(self).__name__}({x})"

    def infer(self, ctx, x):
        raise NotImplementedError(f"{type(self).__name__}.infer(ctx, x) is not written")

    def forward(self, ctx, x):
        raise NotImplementedError(f"{type(self).__name__}.forward(ctx, x) is not written")

    def traits(self):
        return None


def _owner(root, path):
    """The submodule that holds `path`'s last part, made (as an empty Module) where missing."""
    *parents, leaf = path.split(".")
    m = root
    for p in parents:
        child = m._modules.get(p)
        if child is None:
            child = torch.nn.Module()
            try:
                m.add_module(p, child)
            except KeyError as e:
                raise ScheduleError(f"path '{path}': '{p}' cannot name a submodule ({e})") from None
        m = child
    return m, leaf


class _SharedTensors(torch.nn.Module):
    """A module whose parameters and buffers are a C++ module's own tensors, registered (not
    copied) at their dotted paths: OperatorNetwork and topos.topomodelx's models."""

    _error = ScheduleError  # what a bad path or a replaced tensor raises

    def _share(self, tensors):
        """Registers (path, tensor, is_buffer) triples: the C++ module's own tensors."""
        self._shared = []  # (path, module, name, the C++ module's tensor, is_buffer)
        for path, t, is_buffer in tensors:
            owner, leaf = _owner(self, path)
            if leaf in owner.__dict__ or hasattr(type(owner), leaf):
                raise self._error(f"path '{path}': '{leaf}' is an attribute of torch.nn.Module")
            if is_buffer:
                owner.register_buffer(leaf, t)
            else:
                # The very tensor the C++ engine reads, now of class Parameter (not a copy):
                # gradients, .to() and load_state_dict reach both sides.
                t.__class__ = torch.nn.Parameter
                owner.register_parameter(leaf, t)
            self._shared.append((path, owner, leaf, t, is_buffer))

    def _check_shared(self):
        for path, owner, leaf, t, is_buffer in self._shared:
            current = (owner._buffers if is_buffer else owner._parameters).get(leaf)
            if current is not t:
                what = "buffer" if is_buffer else "parameter"
                raise self._error(
                    f"{what} '{path}' of the {type(self).__name__} was replaced by another tensor, "
                    f"which the C++ module does not see: copy into it instead (with torch.no_grad(): "
                    f"p.copy_(value)), or use load_state_dict"
                )

    def _apply(self, fn):
        # torch.nn.Module._apply converts a parameter in place (param.data = ...) but replaces a
        # buffer (and a parameter, with torch.__future__'s overwrite flag) by a new tensor: put the
        # converted value into the network's own tensor and register that one again.
        super()._apply(fn)
        for _, owner, leaf, t, is_buffer in self._shared:
            table = owner._buffers if is_buffer else owner._parameters
            new = table.get(leaf)
            if new is not None and new is not t:
                with torch.no_grad():
                    t.data = new.data if not is_buffer else new
                table[leaf] = t
        return self


class Plan:
    """What an :class:`OperatorNetwork`'s forward runs (C++ ``topos::nn::Plan``).

    ``steps``: one dict per step an output needs (``name``, ``target``, ``group``, ``route``:
    ``"chain"``, ``"filter taps"``, ``"split first layer"``, ``"general"`` or ``"keep"``,
    ``terms``: the sources of the terms it runs, ``compact_readers``, ``lines``: the listing's
    lines as dicts, ``depth`` 0 a term's header and 1 an operation, ``what``, ``flops`` (-1: not
    counted), ``fused_with_next``, how many of the next operations run in its autograd node, and
    the buffer it writes, ``rows`` × ``channels`` (-1: none), ``terms`` of them where it fans out);
    ``total_flops``: the FLOPs of one forward in the plain order; ``total_values``: the values its
    operations write, each output once (``total_bytes`` at the inputs' dtype); ``fast_paths``:
    those on; ``str(plan)``: the listing.
    """

    def __init__(self, d):
        self.steps = list(d["steps"])
        self.total_flops = int(d["total_flops"])
        self.total_values = int(d["total_values"])
        self.total_bytes = self.total_values * int(d["value_bytes"])
        self.fast_paths = d["fast_paths"]
        self._text = d["text"]

    def __str__(self):
        return self._text

    def __repr__(self):
        return f"<topos.nn.Plan: {len(self.steps)} steps, {self.total_flops:,} FLOPs>"


class OperatorNetwork(_SharedTensors):
    """Runs an ``OperatorSchedule``: ``net(inputs, operators)`` -> outputs by name.

    ``inputs``: name -> tensor (cells × channels, optionally with leading batch dimensions);
    ``operators``: name -> torch sparse COO or CSR tensor, scipy.sparse matrix, or a
    ``SparseOperator`` (converted once: reuse it across forwards). Parameters and buffers sit at
    the schedule's dotted paths, as in C++ (TopoModelX's ``state_dict`` names).
    """

    def __init__(self, schedule):
        super().__init__()
        if not isinstance(schedule, OperatorSchedule):
            raise TypeError(
                f"OperatorNetwork(schedule): expected a topos.nn.OperatorSchedule, got {type(schedule).__name__}"
            )
        net = _Network(schedule)  # checks every step; a ScheduleError names the faulty one
        self._network = net
        self._share(net.tensors())

    @property
    def schedule(self):
        return self._network.schedule

    def set_fast_paths(self, on=None, **named):
        """All fast paths on or off (off: every operation runs on every row, each on its own; the
        same numbers up to float rounding, for checking traits), then each named one:
        ``net.set_fast_paths(fuse_products=False)``. The names are :attr:`fast_paths`' keys; an
        unknown one is a ValueError listing them."""
        if on is not None:
            self._network.set_fast_paths(bool(on))
        for name, value in named.items():
            self._network.set_fast_path(name, bool(value))

    @property
    def fast_paths(self):
        """Each fast path's name and whether it is on (C++ ``topos::nn::FastPaths``)."""
        return self._network.fast_paths()

    @property
    def step_threads(self):
        """Threads that the steps of one parallel group share in a forward outside training (1,
        the default: the calling thread alone). With 2 or more, helper threads take some of a
        group's independent steps (Python operations among them, each under the GIL); the outputs
        are the same bit for bit, gradients equal up to the order of their sums. For small
        complexes on spare cores; keep ``torch.set_num_threads(1)`` beside it. Below 1 is a
        ValueError."""
        return self._network.step_threads

    @step_threads.setter
    def step_threads(self, n):
        self._network.step_threads = int(n)

    @property
    def split_groups(self):
        """How many parallel groups this network's forwards have run on more than one thread
        since it was made: 0 means ``step_threads`` never took effect (no group had two
        independent steps to run, or every forward was a training one)."""
        return self._network.split_groups

    @property
    def split_steps(self):
        """How many steps this network's forwards have run with their terms at once (terms that
        aggregate over a batch's neighbourhood after row-wise operations, ``step_threads``)."""
        return self._network.split_steps

    def __deepcopy__(self, memo):
        # A new C++ network from the same schedule (its operations are options, shared), then
        # this one's dtype, state and mode: a snapshot such as early stopping keeps.
        other = type(self)(self.schedule)
        floating = [t for t in self.state_dict().values() if t.is_floating_point()]
        if floating:
            other.to(floating[0].dtype)
        other.load_state_dict(self.state_dict())
        other.train(self.training)
        other.set_fast_paths(**self.fast_paths)
        other.step_threads = self.step_threads
        memo[id(self)] = other
        return other

    def forward(self, inputs, operators=None):
        self._check_shared()
        operators = {} if operators is None else operators
        for name, arg in (("inputs", inputs), ("operators", operators)):
            if not isinstance(arg, collections.abc.Mapping):
                raise TypeError(
                    f"OperatorNetwork: {name} must be a dict of name -> tensor, got {type(arg).__name__}"
                )
        return self._network.forward(dict(inputs), dict(operators), self.training)

    def plan(self, inputs, operators=None):
        """The :class:`Plan` that ``forward(inputs, operators)`` runs with the fast paths on now:
        each step an output needs with its route, and the FLOPs on this complex."""
        self._check_shared()
        operators = {} if operators is None else operators
        return Plan(self._network.plan(dict(inputs), dict(operators)))

    def extra_repr(self):
        net = self.__dict__.get("_network")  # absent while __init__ fails
        return net.schedule.str().rstrip("\n") if net is not None else ""

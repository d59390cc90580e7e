# topos.nn: schedules built in Python and run by the C++ engine, against hand-written torch with
# the very same parameters (outputs and gradients); the module's state (state_dict, .to(),
# train/eval); operations written in Python; bad input as Python exceptions naming the argument
# or the step.
import copy
import sys
import threading

import numpy as np
import pytest
import scipy.sparse
import torch
import torch.nn.functional as F

import topos
from topos.nn import (
    Aggr,
    Operation,
    OperationTraits,
    OperatorNetwork,
    OperatorSchedule,
    ParameterInit,
    ScheduleError,
    SparseOperator,
    TermShape,
    Activation,
    from_,
    into,
)


@pytest.fixture(scope="module")
def complex_():
    sc = topos.SimplicialComplex([[0, 1, 2], [1, 2, 3], [3, 4], [4, 5, 6]])
    return {
        "incidence_1": sc.incidence_matrix(1),  # nodes × edges, signed
        "adjacency_0": sc.adjacency_matrix(0),
        "n0": sc.shape[0],
        "n1": sc.shape[1],
    }


def two_rank_schedule(dropout=0.0):
    """x_0 <- relu(update(relu(B1 (x_1 W10)) + A0 (x_0 W00))), then dropout."""
    s = OperatorSchedule()
    s.input("x_0", 0, 4).input("x_1", 1, 3)
    s.operator_input("incidence_1", 1, 0).operator_input("adjacency_0", 0, 0)
    step = into(0).sum(
        from_(1).conv("conv_1_to_0", 8).via("incidence_1").act(Activation.relu),
        from_(0).conv("conv_0_to_0", 8).via("adjacency_0"),
    )
    step.linear("update", 5).act("relu")
    if dropout:
        step.dropout(dropout)
    s.step(step.named("layer 0"))
    s.output("x_0", 0)
    return s


def two_rank_torch(p, x0, x1, B1, A0):
    m = torch.relu(torch.sparse.mm(B1, x1 @ p["conv_1_to_0.weight"]))
    m = m + torch.sparse.mm(A0, x0 @ p["conv_0_to_0.weight"])
    return torch.relu(F.linear(m, p["update.weight"], p["update.bias"]))


def features(c, dtype=torch.float32, seed=0):
    g = torch.Generator().manual_seed(seed)
    return (
        torch.randn(c["n0"], 4, generator=g, dtype=dtype),
        torch.randn(c["n1"], 3, generator=g, dtype=dtype),
    )


def ops(c):
    return {"incidence_1": c["incidence_1"], "adjacency_0": c["adjacency_0"]}


def test_schedule_matches_torch_outputs_and_gradients(complex_):
    torch.manual_seed(0)
    net = OperatorNetwork(two_rank_schedule())
    assert sorted(net.state_dict()) == [
        "conv_0_to_0.weight",
        "conv_1_to_0.weight",
        "update.bias",
        "update.weight",
    ]
    assert all(isinstance(p, torch.nn.Parameter) for p in net.parameters())
    x0, x1 = features(complex_)
    x1.requires_grad_(True)
    y = net({"x_0": x0, "x_1": x1}, ops(complex_))["x_0"]
    assert y.shape == (complex_["n0"], 5)

    # The same computation in torch, on detached copies of the same parameters.
    p = {k: v.detach().clone().requires_grad_(True) for k, v in net.named_parameters()}
    x1r = x1.detach().clone().requires_grad_(True)
    ref = two_rank_torch(p, x0, x1r, complex_["incidence_1"], complex_["adjacency_0"])
    torch.testing.assert_close(y, ref, rtol=1e-5, atol=1e-6)
    assert (y > 0).any() and (y == 0).any()  # relu's both sides are exercised

    w = torch.randn_like(y)
    (y * w).sum().backward()
    (ref * w).sum().backward()
    for name, param in net.named_parameters():
        assert param.grad is not None, name
        torch.testing.assert_close(param.grad, p[name].grad, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(x1.grad, x1r.grad, rtol=1e-5, atol=1e-6)


@pytest.mark.filterwarnings("ignore:Sparse CSR tensor support is in beta")
def test_operator_formats_agree(complex_):
    net = OperatorNetwork(two_rank_schedule())
    x0, x1 = features(complex_)
    inputs = {"x_0": x0, "x_1": x1}
    coo = net(inputs, ops(complex_))["x_0"]
    B1, A0 = complex_["incidence_1"], complex_["adjacency_0"]
    csr = net(inputs, {"incidence_1": B1.to_sparse_csr(), "adjacency_0": A0.to_sparse_csr()})
    sp = net(
        inputs,
        {
            "incidence_1": scipy.sparse.csr_matrix(B1.to_dense().numpy().astype(np.float64)),
            "adjacency_0": scipy.sparse.coo_matrix(A0.to_dense().numpy()),
        },
    )
    prepared = net(inputs, {"incidence_1": SparseOperator(B1), "adjacency_0": SparseOperator(A0)})
    uncoalesced = torch.sparse_coo_tensor(B1._indices().flip(1), B1._values().flip(0), B1.shape)
    assert not uncoalesced.is_coalesced()
    unc = net(inputs, {"incidence_1": uncoalesced, "adjacency_0": A0})
    # A CSR tensor whose rows hold their columns reversed and one entry split in two halves
    # (torch's unchecked constructor): the same operator once sorted and summed.
    c = B1.to_sparse_csr()
    crow, col, val = c.crow_indices(), c.col_indices().clone(), c.values().clone()
    for i in range(B1.shape[0]):
        a, b = int(crow[i]), int(crow[i + 1])
        col[a:b], val[a:b] = col[a:b].flip(0), val[a:b].flip(0)
    row0 = int(crow[1])
    assert row0 >= 1
    crow2 = torch.cat([crow[:1], crow[1:] + 1])
    col2 = torch.cat([col[:1], col[:row0], col[row0:]])
    val2 = torch.cat([val[:1] / 2, val[:1] / 2, val[1:row0], val[row0:]])
    messy = torch._sparse_csr_tensor_unsafe(crow2, col2, val2, B1.shape)
    head = messy.col_indices()[: row0 + 1]
    assert not torch.equal(head.sort().values, head) or head.unique().numel() < head.numel()
    mess = net(inputs, {"incidence_1": messy, "adjacency_0": A0})
    for other in (csr, sp, prepared, unc, mess):
        torch.testing.assert_close(other["x_0"], coo, rtol=1e-6, atol=1e-6)
    assert SparseOperator(B1).shape == tuple(B1.shape)
    torch.testing.assert_close(SparseOperator(B1).to_torch().to_dense(), B1.to_dense())


def test_state_dict_round_trip_and_to(complex_):
    torch.manual_seed(1)
    a = OperatorNetwork(two_rank_schedule())
    torch.manual_seed(2)
    b = OperatorNetwork(two_rank_schedule())
    x0, x1 = features(complex_)
    inputs, operators = {"x_0": x0, "x_1": x1}, ops(complex_)
    ya, yb = a(inputs, operators)["x_0"], b(inputs, operators)["x_0"]
    assert not torch.allclose(ya, yb)
    b.load_state_dict(a.state_dict())  # copied into the C++ network's own tensors
    torch.testing.assert_close(b(inputs, operators)["x_0"], ya)

    # .double() converts the tensors the C++ engine reads: float64 inputs now, float64 out.
    b.double()
    assert all(p.dtype == torch.float64 for p in b.parameters())
    x0d, x1d = features(complex_, torch.float64)
    yd = b({"x_0": x0d, "x_1": x1d}, operators)["x_0"]
    assert yd.dtype == torch.float64
    ref = two_rank_torch(
        dict(b.named_parameters()), x0d, x1d, complex_["incidence_1"].double(), complex_["adjacency_0"].double()
    )
    torch.testing.assert_close(yd, ref)
    with pytest.raises(ScheduleError, match=r"input 'x_0' is float32, the network's parameters float64"):
        b(inputs, operators)


def test_deepcopy_is_an_independent_network(complex_):
    import copy

    net = OperatorNetwork(two_rank_schedule()).double()
    net.eval()
    twin = copy.deepcopy(net)
    assert not twin.training and all(p.dtype == torch.float64 for p in twin.parameters())
    x0, x1 = features(complex_, torch.float64)
    inputs, operators = {"x_0": x0, "x_1": x1}, ops(complex_)
    torch.testing.assert_close(twin(inputs, operators)["x_0"], net(inputs, operators)["x_0"])
    with torch.no_grad():
        twin.update.bias.add_(1.0)  # the copy's C++ network reads its own tensors
    assert not torch.allclose(twin(inputs, operators)["x_0"], net(inputs, operators)["x_0"])


def test_batch_norm_buffers_follow_the_module(complex_):
    s = OperatorSchedule()
    s.input("x_0", 0, 4)
    s.step(into(0).sum(from_(0).linear("lin", 3)).batch_norm("norm"))
    s.output("y", 0)
    net = OperatorNetwork(s)
    assert "norm.running_mean" in net.state_dict()
    net.double()  # replaces the buffers in Python: the C++ module must see the new ones
    x = torch.randn(complex_["n0"], 4, dtype=torch.float64) + 3
    net.train()
    net({"x_0": x})
    rm = net.state_dict()["norm.running_mean"]
    assert rm.dtype == torch.float64
    h = F.linear(x, net.lin.weight, net.lin.bias)
    torch.testing.assert_close(rm, 0.1 * h.mean(0).detach())  # momentum 0.1 from zeros
    assert net.norm.num_batches_tracked.item() == 1
    net.eval()
    y = net({"x_0": x})["y"]
    ref = (h - rm) / torch.sqrt(net.norm.running_var + 1e-5) * net.norm.weight + net.norm.bias
    torch.testing.assert_close(y, ref.detach())


def test_train_and_eval_dropout(complex_):
    torch.manual_seed(3)
    net = OperatorNetwork(two_rank_schedule(dropout=0.5))
    x0, x1 = features(complex_)
    inputs, operators = {"x_0": x0, "x_1": x1}, ops(complex_)
    ref = two_rank_torch(dict(net.named_parameters()), x0, x1, complex_["incidence_1"], complex_["adjacency_0"])
    net.eval()
    torch.testing.assert_close(net(inputs, operators)["x_0"], ref)
    net.train()
    y = net(inputs, operators)["x_0"]
    kept = y != 0
    torch.testing.assert_close(y[kept], 2 * ref[kept])  # inverted dropout: kept ones scaled by 1/(1-p)
    assert (ref[~kept] != 0).any()  # some nonzero values were dropped


class Gate(Operation):
    """x ⊙ σ(x W), W at `path`."""

    def __init__(self, path):
        self.path = path

    def str(self, x):
        return f"gate[{self.path}]({x})"

    def infer(self, ctx, x):
        ctx.parameter(self.path, [x.channels, x.channels])
        return x

    def forward(self, ctx, x):
        return x * torch.sigmoid(x @ ctx.parameter(self.path))


def gate_schedule(op):
    s = OperatorSchedule()
    s.input("x_0", 0, 4).operator_input("adjacency_0", 0, 0)
    s.step(into(0).sum(from_(0).via("adjacency_0").apply(op)).named("gated"))
    s.output("y", 0)
    return s


def test_python_operation_outputs_gradients_and_training(complex_):
    torch.manual_seed(4)
    net = OperatorNetwork(gate_schedule(Gate("layers.0.gate")))
    assert "gated: (0) = sum[gate[layers.0.gate](adjacency_0·(0))]" in str(net.schedule)
    (name, W), = list(net.named_parameters())
    assert name == "layers.0.gate" and W.shape == (4, 4)
    A0 = complex_["adjacency_0"]
    x = torch.randn(complex_["n0"], 4)
    y = net({"x_0": x}, {"adjacency_0": A0})["y"]
    Wr = W.detach().clone().requires_grad_(True)
    ax = torch.sparse.mm(A0, x)
    ref = ax * torch.sigmoid(ax @ Wr)
    torch.testing.assert_close(y, ref)
    y.square().sum().backward()
    ref.square().sum().backward()
    torch.testing.assert_close(W.grad, Wr.grad)

    before = W.detach().clone()
    opt = torch.optim.SGD(net.parameters(), lr=0.1)
    opt.step()
    torch.testing.assert_close(W.detach(), before - 0.1 * Wr.grad)
    y2 = net({"x_0": x}, {"adjacency_0": A0})["y"]  # the C++ engine reads the updated weight
    torch.testing.assert_close(y2, ax * torch.sigmoid(ax @ W.detach()))


class Project(Operation):
    """x W into `out` channels, reading an operator and a cochain through the context."""

    def __init__(self, out):
        self.out = out

    def infer(self, ctx, x):
        ctx.operator_from("adjacency_0", x.rank)
        assert ctx.cochain_width(0) == 4
        ctx.parameter("proj.weight", [x.channels, self.out], ParameterInit.zeros())
        ctx.buffer("proj.scale", [1], 2.0)
        return TermShape(x.rank, self.out)

    def forward(self, ctx, x):
        A = ctx.op("adjacency_0")
        assert A.layout == torch.sparse_coo and A.is_coalesced()
        w = ctx.parameter("proj.weight") + 1  # zeros + 1
        return torch.sparse.mm(A, x @ w) * ctx.parameter("proj.scale") + ctx.cochain(0).sum()

    def traits(self):
        return OperationTraits(operators=["adjacency_0"])


def test_python_operation_context(complex_):
    s = OperatorSchedule()
    s.input("x_0", 0, 4).operator_input("adjacency_0", 0, 0)
    s.step(into(0, "p").sum(from_(0).apply(Project(2))))
    s.output("y", 0, "p")
    net = OperatorNetwork(s)
    assert [k for k, _ in net.named_parameters()] == ["proj.weight"]
    assert [k for k, _ in net.named_buffers()] == ["proj.scale"]
    A0 = complex_["adjacency_0"]
    x = torch.randn(complex_["n0"], 4)
    y = net({"x_0": x}, {"adjacency_0": A0})["y"]
    torch.testing.assert_close(y, 2 * torch.sparse.mm(A0, x @ torch.ones(4, 2)) + x.sum())


class RightWeight(Operation):
    """x P, declaring P as its right factor: next to a product the engine multiplies by P itself."""

    def __init__(self):
        self.calls = 0
        self.targets = []

    def infer(self, ctx, x):
        ctx.parameter("p", [x.channels, 8])
        return TermShape(x.rank, 8)

    def forward(self, ctx, x):
        self.calls += 1
        self.targets.append(ctx.target)
        return x @ ctx.parameter("p")

    def traits(self):
        return OperationTraits(row_wise=True, reads_cochains=False, right_factor="p")


def test_python_operation_right_factor_is_reordered():
    # B maps 40 cells to 2: (B x) P costs far less than B (x P); the engine runs that order.
    B = torch.zeros(2, 40, dtype=torch.float64)
    B[0, :20], B[1, 20:] = 1.0, 0.5
    x = torch.randn(40, 8, dtype=torch.float64)
    out = {}
    for fast in (True, False):
        op = RightWeight()
        s = OperatorSchedule()
        s.input("x", 0, 8).operator_input("B", 0, 1).output("y", 1)
        s.step(into(1).sum(from_(0).apply(op).via("B")))
        torch.manual_seed(3)
        net = OperatorNetwork(s).double()
        net.set_fast_paths(fast)
        y = net({"x": x}, {"B": B.to_sparse()})["y"]
        torch.testing.assert_close(y, B @ (x @ net.state_dict()["p"]))
        out[fast] = (y, op.calls, op.targets)
    assert out[True][1] == 0 and out[False][1] == 1
    assert out[False][2] == [(1, "")]  # ctx.target: the cochain the step writes
    torch.testing.assert_close(out[True][0], out[False][0])


def test_plan_lists_routes_and_counts_flops_by_hand():
    # x: 6 nodes × 3; B: 4 × 6 with 9 entries. mix: x W (6·3·5), then B· on 5 channels, then
    # relu, as one chain; the dead step does not run.
    B = torch.zeros(4, 6, dtype=torch.float64)
    B[[0, 0, 1, 1, 2, 2, 3, 3, 3], [0, 1, 1, 2, 3, 4, 0, 4, 5]] = 1.0
    s = OperatorSchedule()
    s.input("x", 0, 3).operator_input("B", 0, 1).optional_operator("U", 0, 0).output("y", 1)
    s.step(into(1).sum(from_(0).conv("w", 5).via("B")).act(topos.nn.Activation.relu).named("mix"))
    s.step(into(0, "dead").sum(from_(0).via("U")).named("dead"))
    net = OperatorNetwork(s).double()
    x = torch.randn(6, 3, dtype=torch.float64)
    plan = net.plan({"x": x}, {"B": B.to_sparse()})
    assert plan.total_flops == 2 * 6 * 3 * 5 + 2 * 9 * 5
    assert [(st["name"], st["route"], st["terms"]) for st in plan.steps] == [("mix", "chain", ["(0)"])]
    assert "step mix (into (1), group 0): chain" in str(plan)
    # Its lines: the weight, B· and relu, the first running all three in one node.
    lines = [line for line in plan.steps[0]["lines"] if line["depth"] == 1]
    ops = [(line["what"].split("  ")[0], line["flops"], line["fused_with_next"]) for line in lines]
    assert ops == [("x·w.weight", 2 * 6 * 3 * 5, 2), ("B·x", 2 * 9 * 5, 0), ("relu(x)", -1, 0)]
    # The buffers they write: x W on the 6 nodes, then B· and relu on the 4 edges, 5 channels.
    assert [(line["rows"], line["channels"], line["terms"]) for line in lines] == [(6, 5, 1), (4, 5, 1), (4, 5, 1)]
    assert plan.total_values == 6 * 5 + 2 * 4 * 5
    assert plan.total_bytes == 8 * plan.total_values
    assert str(plan).endswith(f"buffers 70 values ({8 * 70} bytes)\n")
    assert plan.fast_paths.startswith("row_subset")
    net.set_fast_paths(False)
    assert net.plan({"x": x}, {"B": B.to_sparse()}).fast_paths == "none"
    # Each by name: on alone, the same numbers as all off; a copy keeps the switches.
    y_plain = net({"x": x}, {"B": B.to_sparse()})["y"]
    net.set_fast_paths(fuse_products=True)
    assert [k for k, v in net.fast_paths.items() if v] == ["fuse_products"]
    assert net.plan({"x": x}, {"B": B.to_sparse()}).fast_paths == "fuse_products"
    torch.testing.assert_close(net({"x": x}, {"B": B.to_sparse()})["y"], y_plain)
    assert copy.deepcopy(net).fast_paths == net.fast_paths
    net.set_fast_paths(True, reorder_products=False)
    assert not net.fast_paths["reorder_products"] and net.fast_paths["fuse_products"]
    with pytest.raises(ValueError, match="no fast path 'fuse'.*fuse_products"):
        net.set_fast_paths(fuse=True)
    with pytest.raises(topos.nn.ScheduleError, match="input 'x'"):
        net.plan({"x": x[:, :2]}, {"B": B.to_sparse()})


def test_update_is_activations_deprecated_name():
    assert topos.nn.Update is topos.nn.Activation
    s = OperatorSchedule()
    s.input("x", 0, 3).output("y", 0)
    s.step(into(0).sum(from_(0)).act(topos.nn.Update.relu))
    x = torch.randn(4, 3)
    torch.testing.assert_close(OperatorNetwork(s)({"x": x}, {})["y"], torch.relu(x))


def test_schedule_vocabulary():
    s = OperatorSchedule()
    s.input("x_1", 1, 6).operator_input("laplacian_down", 1, 1).operator_input("laplacian_up", 1, 1)
    s.optional_operator("extra", 1, 1)
    s.layer("layer 0")
    s.parallel(
        [
            into(1, "a").mean(from_(1).via("laplacian_down", True), from_(1).pattern("laplacian_up", Aggr.mean)),
            into(1, "b").sum([from_(1).scale(2.0), from_(1).via("extra")]),
        ]
    )
    taps = from_(1).powers([("laplacian_down", 2), ("laplacian_up", 1)])
    s.step(into(1).filter("filter.weight", 4, taps).act(Activation.elu))
    att = from_(1).attend(
        "laplacian_up", "att", Activation.leaky_relu, heads=2, norm=topos.nn.AttentionNorm.softmax, queries=1
    )
    s.step(into(1, "h").sum(att))
    s.output("x", 1)
    text = str(s)
    assert "filter" in text and "layer 0" in text
    assert s.operators == {"laplacian_down": (1, 1), "laplacian_up": (1, 1), "extra": (1, 1)}
    assert s.inputs == {"x_1": (1, "", 6)}
    net = OperatorNetwork(s)
    assert net.state_dict()["filter.weight"].shape == (6, 4, 4)  # in × out × (1 + 2 + 1) terms
    L = torch.eye(5).to_sparse()
    y = net({"x_1": torch.randn(5, 6)}, {"laplacian_down": L, "laplacian_up": L})["x"]  # no "extra"
    assert y.shape == (5, 4)


def test_key_weights_folded_equal_keys_formed(complex_):
    # AllSetTransformer's attention: source-only scores of keys x K_h, formed as a state first or
    # folded into the scores (key_weights); the same output and gradients.
    def attention(keys, key_weights=None):
        return from_(1).head_weights("V", 2, 2).attend(
            "incidence_1", "a", Activation.leaky_relu, norm=topos.nn.AttentionNorm.softmax,
            heads=2, source_only=True, keys=keys, key_weights=key_weights, shape=[2, 1, 3],
        )

    formed, folded = OperatorSchedule(), OperatorSchedule()
    for s in (formed, folded):
        s.input("x_1", 1, 4).operator_input("incidence_1", 1, 0)
    formed.step(into(1, "keys").sum(from_(1).head_weights("K", 2, 3)))
    formed.step(into(0, "y").sum(attention((1, "keys"))))
    folded.step(into(0, "y").sum(attention(1, ("K", 3))))
    for s in (formed, folded):
        s.output("y", 0, "y")
    a, b = OperatorNetwork(formed).double(), OperatorNetwork(folded).double()
    assert b.state_dict()["K"].shape == (2, 4, 3)
    b.load_state_dict(a.state_dict())
    x1 = torch.randn(complex_["n1"], 4, dtype=torch.float64)
    B1 = complex_["incidence_1"].double()
    grads = []
    for net in (a, b):
        x = x1.clone().requires_grad_()
        y = net({"x_1": x}, {"incidence_1": B1})["y"]
        (y * y.cos()).sum().backward()
        grads.append([y.detach(), x.grad] + [p.grad for _, p in sorted(net.named_parameters())])
    for want, got in zip(*grads):
        torch.testing.assert_close(got, want)
    with pytest.raises(TypeError, match=r"attend\(key_weights\): expected \(path, channels per head\)"):
        from_(1).attend("incidence_1", "a", key_weights="K")


# ----- errors ----------------------------------------------------------------------------------


def test_errors_name_the_argument_or_step(complex_):
    net = OperatorNetwork(two_rank_schedule())
    x0, x1 = features(complex_)
    inputs = {"x_0": x0, "x_1": x1}
    B1, A0 = complex_["incidence_1"], complex_["adjacency_0"]
    assert issubclass(ScheduleError, ValueError) and topos.ScheduleError is ScheduleError
    with pytest.raises(ScheduleError, match=r"layer 0.*incidence_1"):
        net(inputs, {"adjacency_0": A0})  # a missing operator
    with pytest.raises(
        ScheduleError,
        match=r"input 'x_1' is float64, the network's parameters float32: write x.to\(torch.float32\), "
        r"or convert the network with net.to\(torch.float64\)",
    ):
        net({"x_0": x0, "x_1": x1.double()}, ops(complex_))
    with pytest.raises(TypeError, match=r"operators\['incidence_1'\]: expected a sparse operator, got a dense"):
        net(inputs, {"incidence_1": B1.to_dense(), "adjacency_0": A0})
    with pytest.raises(TypeError, match=r"inputs\['x_0'\]: expected a torch.Tensor, got a list"):
        net({"x_0": [[1.0]], "x_1": x1}, ops(complex_))
    with pytest.raises(TypeError, match=r"inputs must be a dict of name -> tensor, got list"):
        net([x0, x1], ops(complex_))
    with pytest.raises(ScheduleError, match=r"input 'x_0' must be \(cells × 4"):
        net({"x_0": torch.randn(complex_["n0"], 5), "x_1": x1}, ops(complex_))
    with pytest.raises(ScheduleError, match=r"input 'x_1' was not given"):
        net({"x_0": x0}, ops(complex_))
    with pytest.raises(ScheduleError, match=r"operator 'adjacency_0' is 4 × 4"):
        net(inputs, {"incidence_1": B1, "adjacency_0": torch.eye(4).to_sparse()})

    bad = OperatorSchedule()
    bad.input("x_0", 0, 4).operator_input("incidence_1", 1, 0)
    bad.step(into(0).sum(from_(0).via("incidence_1")).named("wrong rank"))
    bad.output("y", 0)
    with pytest.raises(ScheduleError, match=r"wrong rank.*operator 'incidence_1' applies to rank 1"):
        OperatorNetwork(bad)
    with pytest.raises(TypeError, match=r"sum: term 2 is a int"):
        into(0).sum(from_(0), 3)
    with pytest.raises(ValueError, match="unknown activation 'rleu'"):
        from_(0).act("rleu")


class Shrink(Gate):
    def forward(self, ctx, x):
        return super().forward(ctx, x)[:, :2]  # infer said 4 channels


class Raises(Gate):
    def forward(self, ctx, x):
        raise KeyError("no such thing")


class Keeps(Gate):
    kept = None

    def infer(self, ctx, x):
        Keeps.kept = ctx
        return super().infer(ctx, x)


def test_python_operation_errors(complex_):
    x, A0 = torch.randn(complex_["n0"], 4), complex_["adjacency_0"]
    net = OperatorNetwork(gate_schedule(Shrink("g")))
    with pytest.raises(ScheduleError, match=r"gated.*2 channels.*4"):
        net({"x_0": x}, {"adjacency_0": A0})

    net = OperatorNetwork(gate_schedule(Raises("g")))
    with pytest.raises(ScheduleError, match=r"gated.*python operation Raises.forward raised KeyError") as e:
        net({"x_0": x}, {"adjacency_0": A0})
    assert isinstance(e.value.__cause__, KeyError)

    with pytest.raises(TypeError, match=r"has no method infer"):
        from_(0).apply(object())

    OperatorNetwork(gate_schedule(Keeps("g")))
    with pytest.raises(RuntimeError, match="no longer valid"):
        Keeps.kept.parameter("h", [2, 2])

    class Fails(Gate):
        def infer(self, ctx, x):
            ctx.fail("needs 3 channels")

    with pytest.raises(ScheduleError, match=r"^gated \(into \(0\)\): needs 3 channels$"):
        OperatorNetwork(gate_schedule(Fails("g")))


def test_replaced_parameter_is_an_error(complex_):
    net = OperatorNetwork(gate_schedule(Gate("g")))
    net.g = torch.nn.Parameter(torch.zeros(4, 4))
    with pytest.raises(ScheduleError, match=r"parameter 'g' of the OperatorNetwork was replaced"):
        net({"x_0": torch.randn(complex_["n0"], 4)}, {"adjacency_0": complex_["adjacency_0"]})


def test_python_operation_from_threads(complex_):
    # forward releases the GIL and the Python operation takes it back, from any thread.
    net = OperatorNetwork(gate_schedule(Gate("g")))
    x, A0 = torch.randn(complex_["n0"], 4), SparseOperator(complex_["adjacency_0"])
    want = net({"x_0": x}, {"adjacency_0": A0})["y"].detach()
    want_state = net.state_dict()
    got = []

    def run():
        net = OperatorNetwork(gate_schedule(Gate("g")))  # one network per thread
        net.load_state_dict(want_state)
        for _ in range(20):
            got.append(net({"x_0": x}, {"adjacency_0": A0})["y"].detach())

    threads = [threading.Thread(target=run) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(got) == 60
    for g in got:
        torch.testing.assert_close(g, want)


def test_gradients_reach_operator_values(complex_):
    # A coalesced COO operator's values tensor is the operator's: learned edge weights train.
    A = complex_["adjacency_0"].coalesce()
    vals = A.values().clone().requires_grad_(True)
    s = OperatorSchedule()
    s.input("x_0", 0, 3).operator_input("A", 0, 0)
    s.step(into(0).sum(from_(0).via("A")))
    s.output("y", 0)
    x = torch.randn(complex_["n0"], 3)
    learned = torch.sparse_coo_tensor(A.indices(), vals, A.shape).coalesce()
    y = OperatorNetwork(s)({"x_0": x}, {"A": learned})["y"]
    y.square().sum().backward()
    v = vals.detach().clone().requires_grad_(True)
    torch.sparse.mm(torch.sparse_coo_tensor(A.indices(), v, A.shape), x).square().sum().backward()
    torch.testing.assert_close(vals.grad, v.grad)


def test_forward_releases_the_gil():
    # With a 100 s switch interval the main thread never hands the GIL over by itself: the other
    # thread, woken before the forward, runs during it only if the forward releases the GIL.
    n = 30
    tri = []
    for i in range(n):
        for j in range(n):
            a = i * (n + 1) + j
            tri += [[a, a + 1, a + n + 2], [a, a + n + 2, a + n + 1]]
    sc = topos.SimplicialComplex(tri)
    net = OperatorNetwork(two_rank_schedule())
    x = {"x_0": torch.randn(64, sc.shape[0], 4), "x_1": torch.randn(64, sc.shape[1], 3)}
    operators = {
        "incidence_1": SparseOperator(sc.incidence_matrix(1)),
        "adjacency_0": SparseOperator(sc.adjacency_matrix(0)),
    }
    gate, counter = threading.Lock(), [0]

    def count():
        with gate:  # blocks until the main thread lets it go; then it needs the GIL
            for _ in range(1000):
                counter[0] += 1

    gate.acquire()
    t = threading.Thread(target=count)
    t.start()
    old = sys.getswitchinterval()
    sys.setswitchinterval(100)
    try:
        gate.release()  # does not release the GIL
        net(x, operators)  # 64 forwards in one call
        seen = counter[0]
    finally:
        sys.setswitchinterval(old)
    t.join(timeout=60)
    assert seen == 1000


def test_caching_cpu_allocator_keeps_and_releases_blocks():
    """topos.nn.use_caching_cpu_allocator (a fresh process: it is process-wide): a freed large
    torch tensor's block is kept and handed out again; release gives it back."""
    import subprocess
    import sys

    code = (
        "import torch, topos.nn as n\n"
        "n.use_caching_cpu_allocator()\n"
        "a = torch.empty(1 << 22); p = a.data_ptr(); del a\n"
        "kept = n.cached_cpu_bytes()\n"
        "b = torch.empty(1 << 22); same = b.data_ptr() == p; del b\n"
        "n.release_cached_cpu_memory()\n"
        "print(kept >= 16 << 20, same, n.cached_cpu_bytes())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["True", "True", "0"], out.stdout + out.stderr


def test_step_threads_share_a_parallel_group(complex_):
    """Two step threads: the same outputs as one (gradients up to rounding), Python operations
    included (each takes the GIL on whichever thread runs it)."""
    torch.manual_seed(8)
    s = OperatorSchedule()
    s.input("x_0", 0, 4).operator_input("adjacency_0", 0, 0)
    s.output("y", 0).output("z", 0, "z").output("w", 0, "w")
    s.parallel(
        [
            into(0).sum(from_(0).via("adjacency_0").apply(Gate("g1"))).named("first"),
            into(0, "z").sum(from_(0).apply(Gate("g2")).via("adjacency_0")).named("second"),
            into(0, "w").sum(from_(0).linear("lin", 4).act("relu")).named("third"),
        ]
    )
    net = OperatorNetwork(s).double()
    x = torch.randn(complex_["n0"], 4, dtype=torch.float64, requires_grad=True)
    A0 = complex_["adjacency_0"].double()

    def run():
        out = net({"x_0": x}, {"adjacency_0": A0})
        loss = out["y"].sum() + out["z"].square().sum() + out["w"].sin().sum()
        grads = torch.autograd.grad(loss, [x] + list(net.parameters()))
        return [out["y"], out["z"], out["w"], *grads]

    net.eval()
    assert net.step_threads == 1
    one = run()
    assert net.split_groups == 0
    net.step_threads = 2
    assert net.step_threads == 2
    for k in range(3):
        again = run()
        assert net.split_groups == k + 1  # the group did run on two threads
        assert net.split_steps == 0  # no step's terms aggregate over a batch's neighbourhood
        for a, b in zip(one[:3], again[:3]):  # the outputs bit for bit
            assert torch.equal(a, b)
        for a, b in zip(one[3:], again[3:]):  # gradients up to the order of autograd's sums
            torch.testing.assert_close(a, b, rtol=1e-13, atol=1e-14)
    assert copy.deepcopy(net).step_threads == 2
    with pytest.raises(ValueError, match="step_threads: 0 threads; give 1"):
        net.step_threads = 0
    assert net.step_threads == 2


def test_float32_matmul_precision_reaches_the_kernels():
    """topos.nn.set_float32_matmul_precision('medium'): a schedule's weight multiplies the
    bfloat16-rounded operands with float32 sums (against the same in float64) where the CPU has
    topos's bfloat16 kernels, and stays float32 elsewhere; a bad name is a ValueError."""
    import topos.nn as tnn

    assert tnn.get_float32_matmul_precision() == "highest"
    assert tnn.bfloat16_kernels() in ("amx", "avx512-bf16", "onednn")
    with pytest.raises(ValueError, match="unknown matmul precision 'low'"):
        tnn.set_float32_matmul_precision("low")
    torch.manual_seed(5)
    s = OperatorSchedule()
    s.input("x_0", 0, 48).output("y", 0)
    s.step(into(0).sum(from_(0).linear("lin", 32).act("relu")).named("layer"))
    net = OperatorNetwork(s)
    x = torch.randn(50, 48)  # 3 whole tiles of 16 rows and a remainder
    W, b = net.state_dict()["lin.weight"], net.state_dict()["lin.bias"]

    def reference(round_):
        r = (lambda t: t.bfloat16().double()) if round_ else (lambda t: t.double())
        return torch.relu(r(x) @ r(W).T + b.double())

    highest = net({"x_0": x}, {})["y"]
    torch.testing.assert_close(highest.double(), reference(False), rtol=1e-5, atol=1e-5)
    try:
        tnn.set_float32_matmul_precision("medium")
        assert tnn.get_float32_matmul_precision() == "medium"
        medium = net({"x_0": x}, {})["y"]
    finally:
        tnn.set_float32_matmul_precision("highest")
    assert medium.dtype == torch.float32
    if tnn.bfloat16_kernels() == "onednn":  # the schedule's own products stay float32 there
        assert torch.equal(medium, highest)
    else:
        torch.testing.assert_close(medium.double(), reference(True), rtol=1e-5, atol=1e-5)
        assert (medium - highest).abs().max() > 1e-4  # bfloat16's rounding, not float32's sums

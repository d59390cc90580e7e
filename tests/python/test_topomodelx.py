"""topos.topomodelx, the TopoModelX drop-in, against TopoModelX's golden cases (tdl-golden).

For every model case: the model built under the case's torch.manual_seed has TopoModelX's initial
parameters bit for bit (the case's state_dict is the one TopoModelX's constructor made); with the
case's weights loaded, the outputs and the gradients of Σ out·R match TopoModelX's within the C++
zoo's parity tolerance. The arguments are passed as a TopoModelX user passes them: features as
dense tensors, operators as ``to_sparse()`` of the case's matrices (dense where the case says).
Plus a tutorial-style training loop run through the drop-in unchanged.
"""

import importlib
import importlib.util
import json

import numpy as np
import pytest
import torch

topomodelx = pytest.importorskip("topos.topomodelx")


def _case_names():
    # Parametrised by name; the directory is found at run time (TOPOS_REFERENCE_DIR).
    return [
        "allset-hg15", "allset-transformer-hg15", "can-cell-grid", "ccxn-cell-grid",
        "cwn-cell-grid", "dist2cycle-rgg20", "hmc-cc-torus", "hmpnn-hg15", "hnhn-hg15",
        "hsn-rgg20", "hypergat-hg12", "hypersage-hg15", "san-rgg20", "sca-cmps-rgg20",
        "sccn-rgg20", "sccnn-rgg20", "scconv-rgg20", "scn2-rgg20", "scnn-rgg20", "scone-rgg20",
        "unigcn-hg15", "unigcnii-hg15", "unigin-hg15", "unisage-hg15",
    ]  # fmt: skip


@pytest.fixture
def case(request, reference_dir):
    d = reference_dir / "tdl-golden" / "cases" / request.param
    if not d.is_dir():
        pytest.skip(f"{d} is missing (the TDL golden cases)")
    return d, json.loads((d / "case.json").read_text())


def _model_class(spec):
    module, cls = spec["module"].rsplit(".", 1)
    assert module.startswith("topomodelx.")
    return getattr(importlib.import_module("topos." + module), cls)


def _config(spec):
    """case.json's config as TopoModelX's constructor received it ("torch.nn.X": the class)."""
    out = {}
    for k, v in spec["config"].items():
        if isinstance(v, str) and v.startswith("torch.nn."):
            v = getattr(torch.nn, v[len("torch.nn.") :])
        out[k] = v
    return out


def _npy(path, dtype):
    return torch.from_numpy(np.load(path)).to(dtype)


def _argument(e, d, dtype):
    if e is None:
        return None
    for kind, make in (("tuple", tuple), ("list", list)):
        if kind in e:
            return make(_argument(x, d, dtype) for x in e[kind])
    if "dict" in e:
        return {k: _argument(x, d, dtype) for k, x in e["dict"].items()}
    t = _npy(d / e["from"] / (e["name"] + ".npy"), dtype)
    if e["from"] == "operators" and not e.get("dense", False):
        t = t.to_sparse()
    return t


def _outputs(out):
    if isinstance(out, torch.Tensor):
        return [out]
    if isinstance(out, dict):
        return list(out.values())
    return list(out)


def _built(d, spec, dtype):
    """The model with the case's weights, in eval mode, and its arguments."""
    torch.manual_seed(spec["seed"])
    model = _model_class(spec)(**_config(spec))
    state = {k: _npy(d / "state_dict" / (k + ".npy"), torch.float32) for k in model.state_dict()}
    model.load_state_dict(state)
    model.to(dtype).eval()
    args = [_argument(e, d, dtype) for e in spec["forward"]]
    return model, args


# TopoModelX's float32 rounding, documented in docs/models.md ("Parity"; the C++ zoo test's
# known_mismatches): SCCNN's in_linear_0.bias gradient cancels exactly, and the golden value keeps
# 5.7e-4 (relative) of TopoModelX's rounding, which its own code in float64 does not have. Checked
# here within 1e-3 of its largest value, and strictly by the xfail test below.
KNOWN_MISMATCHES = {"SCCNN": {"in_linear_0.bias"}}


def _close(a, b):
    """The C++ zoo's parity tolerance: max |a - b| within 1e-5, or 1e-4 of the largest |b|."""
    err = (a - b).abs().max().item() if a.numel() else 0.0
    scale = b.abs().max().item() if b.numel() else 0.0
    return err <= 1e-5 or err <= 1e-4 * scale, err


@pytest.mark.parametrize("case", _case_names(), indirect=True)
def test_initial_parameters_are_topomodelx(case):
    d, spec = case
    names = [k for k, _ in json.loads((d / "state_dict.json").read_text())]
    torch.manual_seed(spec["seed"])
    model = _model_class(spec)(**_config(spec))
    state = model.state_dict()
    assert list(state) == names  # TopoModelX's names, in its order
    for k in names:
        golden = torch.from_numpy(np.load(d / "state_dict" / (k + ".npy")))
        # The same draws from the same generator in float32: equal to the bit.
        assert torch.equal(state[k], golden), f"{spec['name']}: {k} differs from TopoModelX's"


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32], ids=["float64", "float32"])
@pytest.mark.parametrize("case", _case_names(), indirect=True)
def test_outputs_and_gradients_are_topomodelx(case, dtype):
    d, spec = case
    model, args = _built(d, spec, dtype)
    out = _outputs(model(*args))
    assert len(out) == len(spec["outputs"])
    loss = 0
    for name, y in zip(spec["outputs"], out):
        golden = _npy(d / "outputs" / (name + ".npy"), dtype)
        assert y.shape == golden.shape, f"{name}: shape {tuple(y.shape)}"
        ok, err = _close(y.detach(), golden)
        assert ok, f"{spec['name']} {name}: max error {err:.3g}"
        loss = loss + (y * _npy(d / "grads" / f"_R_{name}.npy", dtype)).sum()
    loss.backward()
    for k, p in model.named_parameters():
        golden = _npy(d / "grads" / (k + ".npy"), dtype)
        g = p.grad if p.grad is not None else torch.zeros_like(p)
        ok, err = _close(g, golden)
        if k in KNOWN_MISMATCHES.get(spec["model"], ()):
            ok = err <= 1e-3 * golden.abs().max().item()
        assert ok, f"{spec['name']} grad {k}: max error {err:.3g}"


@pytest.mark.xfail(reason="TopoModelX's float32 rounding in the golden value (KNOWN_MISMATCHES)")
@pytest.mark.parametrize("case", ["sccnn-rgg20"], indirect=True)
def test_known_mismatch_sccnn_in_linear_0_bias(case):
    d, spec = case
    model, args = _built(d, spec, torch.float64)
    out = _outputs(model(*args))
    sum((y * _npy(d / "grads" / f"_R_{n}.npy", torch.float64)).sum()
        for n, y in zip(spec["outputs"], out)).backward()  # fmt: skip
    golden = _npy(d / "grads" / "in_linear_0.bias.npy", torch.float64)
    assert _close(model.in_linear_0.bias.grad, golden)[0]


@pytest.mark.parametrize("case", ["scn2-rgg20"], indirect=True)
def test_a_tutorial_training_loop_runs_unchanged(case):
    """TopoModelX's tutorial loop (seed, model, Adam, a few epochs), only the import changed;
    the drop-in's run equals the same loop on a copy of its parameters in plain torch."""
    from topos.topomodelx.nn.simplicial.scn2 import SCN2

    d, spec = case
    args = [_argument(e, d, torch.float32) for e in spec["forward"]]
    x_0, x_1, x_2, lap_0, lap_1, lap_2 = args
    y = (x_0.sum(dim=1) > 0).long()

    torch.manual_seed(0)
    model = SCN2(in_channels_0=4, in_channels_1=3, in_channels_2=2, n_layers=2)
    head = torch.nn.Linear(4, 2)
    opt = torch.optim.Adam(list(model.parameters()) + list(head.parameters()), lr=0.1)
    reference = {k: v.clone() for k, v in model.state_dict().items()}
    losses = []
    for _ in range(5):
        model.train()
        opt.zero_grad()
        out_0, _, _ = model(x_0, x_1, x_2, lap_0, lap_1, lap_2)
        loss = torch.nn.functional.cross_entropy(head(out_0), y)
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert all(np.isfinite(losses)) and losses[-1] < losses[0]
    assert any(not torch.equal(reference[k], v) for k, v in model.state_dict().items())

    # The same loop by hand: SCN2 is x_r <- relu(L_r x_r W_r) per layer and rank (TopoModelX's
    # SCN2Layer: a Conv, then relu).
    torch.manual_seed(0)
    SCN2(in_channels_0=4, in_channels_1=3, in_channels_2=2, n_layers=2)  # the same draws
    head_ref = torch.nn.Linear(4, 2)
    w = {k: v.clone().requires_grad_() for k, v in reference.items()}
    opt_ref = torch.optim.Adam(list(w.values()) + list(head_ref.parameters()), lr=0.1)
    for step in range(5):
        opt_ref.zero_grad()
        h = x_0
        for i in range(2):
            h = torch.relu(torch.sparse.mm(lap_0, h @ w[f"layers.{i}.conv_0_to_0.weight"]))
        loss = torch.nn.functional.cross_entropy(head_ref(h), y)
        loss.backward()
        opt_ref.step()
        assert abs(loss.item() - losses[step]) <= 1e-5 * max(1.0, abs(losses[step]))


def test_from_sparse_is_topomodelx():
    scipy_sparse = pytest.importorskip("scipy.sparse")
    from topos.topomodelx.utils.sparse import from_sparse

    a = scipy_sparse.csc_matrix(np.array([[0.0, 2.5, 0.0], [1.0, 0.0, -3.0]]))
    t = from_sparse(a)
    assert t.layout == torch.sparse_coo and t.is_coalesced() and t.dtype == torch.float32
    assert torch.equal(t.to_dense(), torch.tensor([[0.0, 2.5, 0.0], [1.0, 0.0, -3.0]]))
    with pytest.raises(TypeError, match="expected a scipy.sparse matrix"):
        from_sparse(np.eye(2))


def test_every_topomodelx_model_path_is_there():
    from topos._C.zoo import model_names

    paths = {
        "simplicial": ["dist2cycle", "hsn", "san", "sca_cmps", "sccn", "sccnn", "scconv", "scn2",
                       "scnn", "scone"],
        "cell": ["can", "ccxn", "cwn"],
        "combinatorial": ["hmc"],
        "hypergraph": ["allset", "allset_transformer", "dhgcn", "hmpnn", "hnhn", "hypergat",
                       "hypersage", "unigcn", "unigcnii", "unigin", "unisage"],
    }  # fmt: skip
    found = set()
    for domain, files in paths.items():
        for f in files:
            m = importlib.import_module(f"topos.topomodelx.nn.{domain}.{f}")
            (cls,) = m.__all__
            found.add(cls)
            assert issubclass(getattr(m, cls), torch.nn.Module)
    assert found - {"DHGCN"} <= set(model_names())  # DHGCN is written in torch
    assert len(found) == 25


def test_bad_arguments_are_named():
    from topos.topomodelx.nn.simplicial.scn2 import SCN2

    with pytest.raises(TypeError, match="n_layer"):
        SCN2(4, 3, 2, n_layer=2)  # SCN2 takes no **kwargs, as in TopoModelX
    from topos.topomodelx.nn.hypergraph.hnhn import HNHN

    with pytest.raises(topomodelx.ZooError, match="bias_int"):
        HNHN(4, 5, None, bias_int="xavier_normal")  # a **kwargs the zoo does not read is named
    with pytest.raises(TypeError):
        SCN2(4, 3)  # in_channels_2 missing, as in TopoModelX
    m = SCN2(4, 3, 2)
    lap = torch.eye(3).to_sparse()
    with pytest.raises(ValueError, match="operator 'laplacian_0' is 3 × 3 .* 'x_0' has 5 rows"):
        m(torch.ones(5, 4), torch.ones(3, 3), torch.ones(3, 2), lap, lap, lap)


R, L = torch.nn.ReLU, torch.nn.LayerNorm
INIT_CASES = [  # (module under nn., config): options the golden cases do not cover
    ("simplicial.scn2.SCN2", dict(in_channels_0=5, in_channels_1=2, in_channels_2=7, n_layers=3)),
    ("simplicial.hsn.HSN", dict(channels=6, n_layers=3)),
    ("simplicial.scconv.SCConv", dict(node_channels=4, n_layers=2)),
    ("simplicial.scconv.SCConv",
     dict(node_channels=4, edge_channels=3, face_channels=5, n_layers=3)),
    ("simplicial.sccn.SCCN", dict(channels=3, max_rank=2, n_layers=1)),
    ("simplicial.scnn.SCNN",
     dict(in_channels=3, hidden_channels=6, conv_order_down=1, conv_order_up=3, n_layers=3)),
    ("simplicial.sccnn.SCCNN",
     dict(in_channels_all=[3,4,5], hidden_channels_all=[6,6,6], conv_order=1, sc_order=3,
          n_layers=1)),
    ("simplicial.scone.SCoNe", dict(in_channels=2, hidden_channels=7, n_layers=3)),
    ("simplicial.san.SAN", dict(in_channels=3, hidden_channels=5, n_layers=1)),
    ("simplicial.san.SAN",
     dict(in_channels=3, hidden_channels=5, out_channels=2, n_filters=3, n_layers=3)),
    ("simplicial.dist2cycle.Dist2Cycle", dict(channels=9, n_layers=3)),
    ("cell.cwn.CWN",
     dict(in_channels_0=2, in_channels_1=3, in_channels_2=4, hid_channels=5, n_layers=3)),
    ("cell.ccxn.CCXN",
     dict(in_channels_0=4, in_channels_1=3, in_channels_2=5, n_layers=3, att=True)),
    ("cell.can.CAN", dict(in_channels_0=3, in_channels_1=4, out_channels=4, heads=2, n_layers=3)),
    ("cell.can.CAN",
     dict(in_channels_0=3, in_channels_1=4, out_channels=6, heads=3, n_layers=3, att_lift=False,
          pooling=True)),
    ("cell.can.CAN",
     dict(in_channels_0=3, in_channels_1=4, out_channels=4, heads=1, n_layers=1,
          skip_connection=False, att_lift=False)),
    ("combinatorial.hmc.HMC",
     dict(channels_per_layer=[[[3,4,2],[4,3,5],[2,4,3]], [[2,4,3],[5,5,5],[1,2,3]]])),
    ("hypergraph.allset.AllSet",
     dict(in_channels=4, hidden_channels=5, n_layers=3, mlp_num_layers=3, mlp_activation=R,
          mlp_norm=L)),
    ("hypergraph.allset_transformer.AllSetTransformer",
     dict(in_channels=4, hidden_channels=6, n_layers=2, heads=3, mlp_num_layers=1)),
    ("hypergraph.allset_transformer.AllSetTransformer",
     dict(in_channels=4, hidden_channels=8, n_layers=1, heads=4, mlp_num_layers=3)),
    ("hypergraph.hmpnn.HMPNN", dict(in_channels=4, hidden_channels=5, n_layers=3)),
    ("hypergraph.hnhn.HNHN", dict(in_channels=4, hidden_channels=5, incidence_1=None, n_layers=3)),
    ("hypergraph.hnhn.HNHN",
     dict(in_channels=4, hidden_channels=5, incidence_1=None, n_layers=2,
          bias_init="xavier_normal", bias_gain=0.7)),
    ("hypergraph.hnhn.HNHN",
     dict(in_channels=4, hidden_channels=5, incidence_1=None, use_bias=False)),
    ("hypergraph.hypergat.HyperGAT", dict(in_channels=4, hidden_channels=5, n_layers=3)),
    ("hypergraph.hypersage.HyperSAGE", dict(in_channels=4, hidden_channels=5, n_layers=3)),
    ("hypergraph.unigcn.UniGCN", dict(in_channels=5, hidden_channels=5, n_layers=2)),
    ("hypergraph.unigcn.UniGCN", dict(in_channels=4, hidden_channels=5, n_layers=3, use_bn=True)),
    ("hypergraph.unigcnii.UniGCNII",
     dict(in_channels=4, hidden_channels=5, n_layers=4, use_norm=True)),
    ("hypergraph.unigin.UniGIN",
     dict(in_channels=4, hidden_channels=5, n_layers=3, train_eps=True, eps=0.3)),
    ("hypergraph.unigin.UniGIN", dict(in_channels=4, hidden_channels=5, n_layers=2)),
    ("hypergraph.unisage.UniSAGE",
     dict(in_channels=4, hidden_channels=5, n_layers=3, e_aggr="mean")),
]  # fmt: skip


@pytest.mark.parametrize("path,config", INIT_CASES)
def test_initial_parameters_equal_topomodelx_own(path, config):
    """Against TopoModelX itself where it is installed: the same seed gives the same state_dict
    (names, order, values) and leaves the generator in the same state."""
    if importlib.util.find_spec("topomodelx") is None:
        pytest.skip("TopoModelX is not installed (the golden cases check its default options)")
    module, cls = path.rsplit(".", 1)
    theirs = getattr(importlib.import_module("topomodelx.nn." + module), cls)
    ours = getattr(importlib.import_module("topos.topomodelx.nn." + module), cls)
    torch.manual_seed(7)
    t = theirs(**config).state_dict()
    t_next = torch.rand(1)
    torch.manual_seed(7)
    d = ours(**config).state_dict()
    d_next = torch.rand(1)
    assert list(d) == list(t)
    for k in t:
        assert torch.equal(d[k], t[k]), k
    assert torch.equal(d_next, t_next)


@pytest.mark.parametrize("case", ["unigcnii-hg15"], indirect=True)
def test_the_papers_model_is_one_argument_away(case):
    """UniGCNII: TopoModelX ignores beta (layer i uses log(alpha / (i + 1) + 1)); with
    topomodelx_compatible=False, beta is GCNII's. Equal where beta = alpha, apart where not."""
    from topos.topomodelx.nn.hypergraph.unigcnii import UniGCNII

    d, spec = case
    x, incidence = [_argument(e, d, torch.float64) for e in spec["forward"]]
    names = [k for k, _ in json.loads((d / "state_dict.json").read_text())]
    state = {k: _npy(d / "state_dict" / (k + ".npy"), torch.float64) for k in names}
    golden = _npy(d / "outputs" / "out_x_0.npy", torch.float64)

    def run(beta, compatible):
        m = UniGCNII(4, 5, n_layers=2, alpha=0.5, beta=beta, topomodelx_compatible=compatible)
        m.double().load_state_dict(state)
        return m.eval()(x, incidence)[0].detach()

    assert _close(run(0.9, True), golden)[0]  # beta ignored, as in TopoModelX
    assert torch.allclose(run(0.5, False), run(0.5, True), atol=1e-12)
    assert (run(0.9, False) - golden).abs().max() > 1e-3


@pytest.mark.parametrize("case", ["cwn-cell-grid"], indirect=True)
def test_operators_are_converted_once_and_changes_are_seen(case):
    """The same operator tensors at every forward are converted once (a TopoModelX script passes
    them every epoch); a change to one in place is still seen, sparse or dense."""
    d, spec = case
    model, args = _built(d, spec, torch.float32)
    first = [y.detach().clone() for y in model(*args)]
    again = model(*args)
    assert all(torch.equal(a, b) for a, b in zip(first, again))
    assert len(model._operator_cache._entries) == 3
    x_0, x_1, x_2, adjacency_0, incidence_2, incidence_1_t = args
    with torch.no_grad():
        incidence_2.mul_(2.0)  # sparse, in place
    doubled = model(*args)
    fresh = model(x_0, x_1, x_2, adjacency_0, incidence_2.coalesce().clone(), incidence_1_t)
    assert torch.equal(doubled[1], fresh[1]) and not torch.equal(doubled[1], first[1])
    dense = incidence_1_t.to_dense()
    y = model(x_0, x_1, x_2, adjacency_0, incidence_2, dense)[1].detach().clone()
    with torch.no_grad():
        dense.mul_(0.5)
    y_half = model(x_0, x_1, x_2, adjacency_0, incidence_2, dense)[1]
    expected = model(x_0, x_1, x_2, adjacency_0, incidence_2, dense.to_sparse())[1]
    assert torch.equal(y_half, expected) and not torch.equal(y_half, y)


@pytest.mark.parametrize("case", ["hmc-cc-torus"], indirect=True)
def test_deepcopy_is_an_independent_model(case):
    """copy.deepcopy (an early-stopping snapshot): the same outputs, its own parameters, no
    random draws."""
    import copy

    d, spec = case
    model, args = _built(d, spec, torch.float64)
    before = torch.get_rng_state()
    snapshot = copy.deepcopy(model)
    assert torch.equal(torch.get_rng_state(), before)
    assert list(snapshot.state_dict()) == list(model.state_dict())
    assert not snapshot.training
    for a, b in zip(model(*args), snapshot(*args)):
        assert torch.equal(a, b)
    with torch.no_grad():
        next(model.parameters()).add_(1.0)
    assert not torch.equal(model(*args)[0], snapshot(*args)[0])


def test_dhgcn():
    """DHGCN (written in torch): TopoModelX's parameters under a seed (against TopoModelX itself
    where installed), its hypergraph (each node's k nearest other nodes by brute force; every node
    in one k-means cluster) and its forward from that hypergraph."""
    from topos.topomodelx.nn.hypergraph.dhgcn import DHGCN

    torch.manual_seed(3)
    model = DHGCN(in_channels=4, hidden_channels=5, n_layers=1, k_neighbours=3, k_centroids=4)
    names = ["layers.0.fc_layer.weight", "layers.0.fc_layer.bias",
             "layers.0.conv_dt_level0_0_to_1.weight", "layers.0.conv_dt_level0_1_to_0.weight"]  # fmt: skip
    assert list(model.state_dict()) == names
    torch.manual_seed(3)
    w = torch.empty(5, 4)
    torch.nn.init.kaiming_uniform_(w, a=5**0.5)
    assert torch.equal(model.layers[0].fc_layer.weight, w)

    x = torch.randn(15, 4)
    layer = model.layers[0]
    h = layer.fc_layer(x)
    torch.manual_seed(11)
    H = layer.get_dynamic_topology(h).to_dense()
    assert H.shape == (15, 19)
    for i in range(15):
        d = [((h[i] - h[j]).norm().item(), j) for j in range(15) if j != i]
        nearest = {j for _, j in sorted(d)[:3]}
        assert {j for j in range(15) if H[j, i] == 1} == nearest
    assert torch.equal(H[:, 15:].sum(dim=1), torch.ones(15))

    torch.manual_seed(11)
    y_0, y_1 = model(x)
    W1 = layer.conv_dt_level0_0_to_1.weight
    W2 = layer.conv_dt_level0_1_to_0.weight
    assert torch.allclose(y_1, H.t() @ (h @ W1), atol=1e-5)
    assert torch.allclose(y_0, H @ (y_1 @ W2), atol=1e-5)

    if importlib.util.find_spec("topomodelx") is not None:
        from topomodelx.nn.hypergraph.dhgcn import DHGCN as Theirs

        torch.manual_seed(3)
        theirs = Theirs(in_channels=4, hidden_channels=5, k_neighbours=3, k_centroids=4)
        for k, v in theirs.state_dict().items():
            assert torch.equal(v, model.state_dict()[k]), k
        torch.manual_seed(11)
        for a, b in zip(theirs(x), (y_0, y_1)):
            assert torch.allclose(a, b, atol=1e-6)

# topos.topobench: TopoBench's pipeline from Python with backbones written in Python. The
# protocol against reproduce-hparams.txt and numpy's own permutations; the raw reader against the
# dataset's published counts; the lifting against topos.cycle_lifting; batches against
# torch.block_diag; a schedule with a Python operation and a plain torch.nn.Module trained on
# MUTAG (above the majority class, loss falling, the same numbers twice, the best check's
# parameters and buffers restored, into the Python module's own tensors); the runner's folder;
# bad input as Python exceptions naming the argument. Needs TOPOS_DATASETS_DIR (skipped without).
import numpy as np
import pytest
import torch

import topos
from topos import topobench
from topos.nn import Operation, OperatorSchedule, from_, into
from topos.topobench import Backbone, RankLayout

EPOCHS = 40  # 8 validation checks (every 5 epochs), a few seconds per run


class Gate(Operation):
    """x ⊙ σ(x W): the Python operation of the schedule backbone."""

    def __init__(self, path):
        self.path = path

    def infer(self, ctx, x):
        ctx.parameter(self.path, [x.channels, x.channels])
        return x

    def forward(self, ctx, x):
        return x * torch.sigmoid(x @ ctx.parameter(self.path))


def gated_cell(ctx):
    """Nodes and edges of the cell lifting, a Python gate on the edges, batch norm on the nodes."""
    h = ctx.hidden
    s = OperatorSchedule()
    s.input("x_0", 0, h).input("x_1", 1, h)
    s.operator_input("adjacency_0", 0, 0).operator_input("incidence_1", 1, 0)
    for layer in range(ctx.n_layers):
        p = f"layers.{layer}."
        s.step(
            into(1)
            .sum(from_(1).linear(p + "self_1", h), from_(0).conv(p + "conv_0_to_1", h).via_t("incidence_1"))
            .apply(Gate(p + "gate"))
            .act("relu")
        )
        s.step(
            into(0)
            .sum(
                from_(0).conv(p + "conv_0_to_0", h).via("adjacency_0"),
                from_(1).conv(p + "conv_1_to_0", h).via("incidence_1"),
            )
            .batch_norm(p + "norm_0")
            .act("relu")
        )
    s.output("x_0", 0).output("x_1", 1)
    return s


class TorchCell(torch.nn.Module):
    """A plain torch module: forward(x, operators) on dicts, torch.sparse.mm on the operators."""

    def __init__(self, h, outputs=("x_0", "x_1")):
        super().__init__()
        self.lin0 = torch.nn.Linear(h, h)
        self.lin1 = torch.nn.Linear(h, h)
        self.norm = torch.nn.BatchNorm1d(h)
        self.outputs = outputs

    def forward(self, x, operators):
        B1, A0 = operators["incidence_1"], operators["adjacency_0"]
        x0 = torch.sparse.mm(A0, x["x_0"]) + torch.sparse.mm(B1, x["x_1"])
        x1 = torch.sparse.mm(B1.t(), x["x_0"]) + x["x_1"]
        y = {"x_0": torch.relu(self.norm(self.lin0(x0))), "x_1": torch.relu(self.lin1(x1))}
        return {k: y[k] for k in self.outputs}


LAYOUT = RankLayout("cell", encoded_ranks=[0, 1], cell_dimensions=2, operators={"adjacency_0", "incidence_1"})


@pytest.fixture(scope="module")
def config(datasets_dir):
    c = topobench.find_config("CWN", "MUTAG", root=datasets_dir)
    c.hidden = 64  # CWN's line but narrower: a quick run
    return c


@pytest.fixture(scope="module")
def mutag(datasets_dir, config):
    return topobench.lift("MUTAG", LAYOUT, config, root=datasets_dir)


def test_protocol(datasets_dir):
    c = topobench.find_config("CWN", "MUTAG")  # root from TOPOS_DATASETS_DIR
    lines = (datasets_dir / "topobench" / "reproduce-hparams.txt").read_text().splitlines()
    line = next(x for x in lines if x.startswith("cell/cwn MUTAG "))
    assert (c.model_config, c.dataset_config) == ("cell/cwn", "MUTAG")
    assert f"lr={c.lr:g} hid={c.hidden} L={c.layers} readout={c.readout} dropout={c.dropout:g} " in line
    assert f" bs={c.batch_size} " in line
    assert c.data_seeds == [0, 3, 5, 7, 9] and (c.min_epochs, c.max_epochs, c.val_every, c.patience) == (50, 500, 5, 10)
    g = topobench.find_config("GCCN", "MUTAG")  # no line of its own: CWN's, with topotune.yaml's widths
    assert (g.hidden, g.layers, g.lr, g.batch_size) == (32, 2, c.lr, c.batch_size)
    assert "cell/cwn's line" in g.source
    assert topobench.model_layout("CWN").operators == {"adjacency_1", "incidence_1", "incidence_2", "incidence_1_t"}
    # TopoBench's split: np.random.seed(42), ten permutations in a row, the (seed mod 10)-th; 50/25/25.
    for n, seed in ((188, 0), (188, 7), (31, 13)):
        rs = np.random.RandomState(42)
        perms = [rs.permutation(n) for _ in range(10)]
        perm = perms[seed % 10].tolist()
        train, val, test = topobench.split(n, seed)
        assert (train, val, test) == (perm[: n // 2], perm[n // 2 : n // 2 + n // 4], perm[n // 2 + n // 4 :])


def test_read_dataset(datasets_dir):
    d = topobench.read_dataset("MUTAG", root=datasets_dir)
    graphs = d["graphs"]
    # The published counts (datasets README): 188 graphs, 3,371 nodes, 3,721 undirected edges.
    assert len(graphs) == 188 and d["num_classes"] == 2 and d["num_node_features"] == 7
    assert sum(g["num_nodes"] for g in graphs) == 3371
    assert sum(g["edge_index"].shape[1] for g in graphs) == 3721
    assert sum(g["label"] for g in graphs) == 125  # 125 mutagenic, 63 not
    for g in graphs[:5]:
        assert torch.equal(g["x"].sum(1), torch.ones(g["num_nodes"]))  # atom types one-hot
        assert g["edge_labels"].shape == (g["edge_index"].shape[1],)


def test_lifting_and_batches(datasets_dir, mutag):
    raw = topobench.read_dataset("MUTAG", root=datasets_dir)["graphs"]
    assert len(mutag) == 188 and mutag.num_classes == 2 and mutag.layout.domain == "cell"
    assert mutag.in_channels == [7, 4, 4]  # atoms one-hot; MUTAG's bond types kept on the edges
    for i in (0, 1, 5):
        g, r = mutag.graph(i), raw[i]
        cx = topos.cycle_lifting(r["num_nodes"], r["edge_index"], max_cell_length=10)
        assert g["sizes"] == list(cx.shape) and g["label"] == r["label"]
        assert torch.equal(g["x"][0], r["x"])
        # TopoBench's cell operators are unsigned: |B_1| and |B_1||B_1|ᵀ off the diagonal.
        B1 = cx.incidence_matrix(1, dtype=torch.float32).to_dense().abs()
        assert torch.equal(g["operators"]["incidence_1"].to_dense(), B1)
        A0 = B1 @ B1.t()
        A0.fill_diagonal_(0)
        assert torch.equal(g["operators"]["adjacency_0"].to_dense(), A0)
    b = mutag.batch([3, 0, 7])
    parts = [mutag.graph(i) for i in (3, 0, 7)]
    assert b.num_graphs == 3 and b.labels.tolist() == [raw[i]["label"] for i in (3, 0, 7)]
    for name in ("incidence_1", "adjacency_0"):
        want = torch.block_diag(*[p["operators"][name].to_dense() for p in parts])
        assert torch.equal(b.operators[name].to_dense(), want)
    for r in range(3):
        assert torch.equal(b.x[r], torch.cat([p["x"][r] for p in parts]))
        assert b.batch[r].tolist() == sum(([k] * p["sizes"][r] for k, p in enumerate(parts)), [])


def train(mutag, backbone, config):
    """One quick run, recording the model's state at every validation check."""
    states = {}

    def on_check(check, model):
        assert not model.training  # the trainer hands the model over in eval mode
        states[check.epoch] = {k: v.detach().clone() for k, v in model.state_dict().items()}

    run = topobench.train_run(mutag, backbone, config, seed=0, max_epochs=EPOCHS, on_check=on_check)
    return run, states


def check_run(run, states, mutag, config):
    r = run.result
    assert (r.dataset, r.split_seed, r.epochs) == ("MUTAG", 0, EPOCHS)
    assert [c.epoch for c in run.curve] == list(range(5, EPOCHS + 1, 5))
    # Learned something: above the majority class of the training split on the test split, and
    # the mean training loss of the last check below the first's.
    majority = mutag.majority_accuracy(0)
    assert 0.6 < majority < 0.7
    assert r.test_accuracy > majority + 0.05
    assert run.curve[-1].loss < 0.8 * run.curve[0].loss
    # The best check: the first with the highest validation accuracy, its state put back.
    best = max(run.curve, key=lambda c: (c.val_accuracy, -c.epoch))
    assert r.best_epoch == best.epoch and run.best_val_accuracy == best.val_accuracy
    assert r.best_epoch < EPOCHS  # so that restoring it changes the model
    final = run.model.state_dict()
    assert set(final) == set(states[r.best_epoch])
    for k, v in final.items():
        assert torch.equal(v, states[r.best_epoch][k]), k
    assert any(not torch.equal(v, states[EPOCHS][k]) for k, v in final.items())
    train_idx, val_idx, test_idx = topobench.split(len(mutag), 0)
    assert run.model.accuracy(mutag, test_idx, config.batch_size) == r.test_accuracy
    assert run.model.accuracy(mutag, val_idx, config.batch_size) == run.best_val_accuracy
    return final


def test_python_schedule_backbone_trains(mutag, config):
    backbone = Backbone("GatedCell", LAYOUT, gated_cell)
    run, states = train(mutag, backbone, config)
    final = check_run(run, states, mutag, config)
    assert run.result.model == "GatedCell" and run.model.backbone is None
    assert {"backbone.layers.0.gate", "backbone.layers.1.gate"} <= set(final)  # the Python operation's
    buffers = [k for k in final if "norm_0.running" in k]
    assert buffers and any(not torch.equal(final[k], states[EPOCHS][k]) for k in buffers)  # restored too
    # Seeded: a second run gives the same numbers.
    again, _ = train(mutag, backbone, config)
    def checks(r):
        return [(c.epoch, c.loss, c.val_accuracy) for c in r.curve]

    assert checks(again) == checks(run)
    assert again.result.test_accuracy == run.result.test_accuracy
    for k, v in again.model.state_dict().items():
        assert torch.equal(v, final[k]), k


def test_runs_flush_denormals_while_they_train_unless_asked_not_to(mutag, config):
    backbone = Backbone("TorchCell", LAYOUT, lambda ctx: TorchCell(ctx.hidden))
    tiny = torch.tensor([1e-39])  # a denormal float32
    seen = []

    def on_check(check, model):
        seen.append(float((tiny * 1.0).item()))

    topobench.train_run(mutag, backbone, config, 0, max_epochs=5, on_check=on_check)
    topobench.train_run(mutag, backbone, config, 0, max_epochs=5, on_check=on_check, flush_denormals=False)
    assert seen == [0.0, float(tiny.item())]
    assert float((tiny * 1.0).item()) != 0.0  # the caller's mode is back after the run


def test_torch_module_backbone_trains(mutag, config):
    backbone = Backbone("TorchCell", LAYOUT, lambda ctx: TorchCell(ctx.hidden))
    run, states = train(mutag, backbone, config)
    final = check_run(run, states, mutag, config)
    module = run.model.backbone
    assert isinstance(module, TorchCell) and not module.training
    # The trainer trained and restored the Python module's own tensors, buffers included.
    for k, v in module.state_dict().items():
        assert final["backbone." + k].data_ptr() == v.data_ptr(), k
    assert not torch.equal(final["backbone.norm.running_mean"], states[EPOCHS]["backbone.norm.running_mean"])
    assert int(final["backbone.norm.num_batches_tracked"]) == 3 * run.result.best_epoch  # 94 graphs, batches of 32
    again, _ = train(mutag, backbone, config)
    assert [c.loss for c in again.curve] == [c.loss for c in run.curve]
    assert again.result.test_accuracy == run.result.test_accuracy


class GraphConv(torch.nn.Module):
    def __init__(self, h):
        super().__init__()
        self.lin = torch.nn.Linear(h, h)

    def forward(self, x, operators):
        return {"x_0": torch.relu(self.lin(torch.sparse.mm(operators["gcn_adjacency"], x["x_0"])))}


def test_node_level(datasets_dir):
    cora = topobench.read_dataset("Cora", root=datasets_dir)
    # The datasets README: 2,708 nodes, 5,278 edges, 1,433 features, 7 classes.
    assert (cora["num_nodes"], cora["edge_index"].shape[1]) == (2708, 5278)
    assert (cora["num_node_features"], cora["num_classes"]) == (1433, 7)
    layout = RankLayout("graph", [0], 1, {"gcn_adjacency"})
    config = topobench.find_config("GCN", "Cora", root=datasets_dir)
    assert (config.dataset_config, config.val_every, config.patience) == ("cocitation_cora", 1, 50)
    data = topobench.lift("Cora", layout, config, root=datasets_dir)
    assert data.node_level and len(data) == 2708 and data.num_graphs == 1
    backbone = Backbone("GraphConv", layout, lambda ctx: GraphConv(ctx.hidden))
    run = topobench.train_run(data, backbone, config, 0, max_epochs=10)
    assert [c.epoch for c in run.curve] == list(range(1, 11))
    assert run.result.test_accuracy > data.majority_accuracy(0) + 0.2
    _, val_idx, test_idx = topobench.split(2708, 0)
    assert run.model.accuracy(data, test_idx) == run.result.test_accuracy


def test_runner_folder(datasets_dir, config, tmp_path):
    backbone = Backbone("TorchCell", LAYOUT, lambda ctx: TorchCell(ctx.hidden))
    runs = topobench.run(backbone, "MUTAG", config, seeds=[0, 3], out=tmp_path, root=datasets_dir, max_epochs=5)
    assert [r.result.split_seed for r in runs] == [0, 3]
    rows = (tmp_path / "runs.csv").read_text().splitlines()
    assert rows[0] == "model,dataset,split_seed,test_accuracy,best_epoch,epochs,seconds" and len(rows) == 3
    assert rows[1].startswith(f"TorchCell,MUTAG,0,{runs[0].result.test_accuracy:.6f},5,5,")
    for f in ("curves.csv", "summary.csv", "index.html", "table.md"):
        assert (tmp_path / f).is_file(), f
    # Resumable: the runs the folder holds are skipped.
    assert topobench.run(backbone, "MUTAG", config, seeds=[0, 3], out=tmp_path, root=datasets_dir, max_epochs=5) == []
    assert [r.split_seed for r in topobench.RunsFolder(tmp_path).runs] == [0, 3]


def test_errors(datasets_dir, mutag, config, monkeypatch):
    with pytest.raises(ValueError, match=r"unknown TopoBench dataset 'MUTAGG' \(known: MUTAG, PROTEINS"):
        topobench.lift("MUTAGG", LAYOUT, config)
    with pytest.raises(ValueError, match="unknown TopoBench model 'CWNN'"):
        topobench.find_config("CWNN", "MUTAG")
    with pytest.raises(ValueError, match="lift.layout.: the cell lifting has no operator 'adjacency_9' .it has: "):
        topobench.lift("MUTAG", RankLayout("cell", [0], 1, {"adjacency_9"}), config)
    with pytest.raises(FileNotFoundError, match="root: no such datasets folder"):
        topobench.lift("MUTAG", LAYOUT, config, root=datasets_dir / "missing")
    monkeypatch.delenv("TOPOS_DATASETS_DIR")
    with pytest.raises(ValueError, match="root: not given and TOPOS_DATASETS_DIR is not set"):
        topobench.read_dataset("MUTAG")
    # The backbone needs an operator the data was not lifted with.
    needs_more = RankLayout("cell", [0, 1], 2, {"adjacency_1", "incidence_1"})
    with pytest.raises(ValueError, match="train_run.data.: X needs the operator 'adjacency_1', which MUTAG was not"):
        topobench.train_run(mutag, Backbone("X", needs_more, gated_cell), config, 0, max_epochs=1)
    with pytest.raises(ValueError, match="readout PropagateSignalDown reads incidence_1; add 'incidence_1'"):
        topobench.train_run(mutag, Backbone("X", RankLayout("cell", [0, 1], 2, {"adjacency_0"}), gated_cell), config, 0)
    with pytest.raises(ValueError, match="encoded_ranks must hold every rank below cell_dimensions"):
        Backbone("X", RankLayout("cell", [0], 2, {"incidence_1"}), gated_cell)
    with pytest.raises(ValueError, match="without commas"):
        Backbone("a,b", LAYOUT, gated_cell)
    # What make and forward give back.
    with pytest.raises(TypeError, match="X: make.ctx. returned a int; expected a topos.nn.OperatorSchedule"):
        topobench.train_run(mutag, Backbone("X", LAYOUT, lambda ctx: 3), config, 0, max_epochs=1)
    with pytest.raises(ValueError, match=r"X: the backbone gave no x_1 \(its layout has cell_dimensions 2\)"):
        only_x0 = Backbone("X", LAYOUT, lambda ctx: TorchCell(ctx.hidden, ("x_0",)))
        topobench.train_run(mutag, only_x0, config, 0, max_epochs=1)

    class AsksMore(TorchCell):
        def forward(self, x, operators):
            return {"x_0": torch.sparse.mm(operators["up_laplacian_1"], x["x_0"]), "x_1": x["x_1"]}

    with pytest.raises(KeyError, match="up_laplacian_1"):  # the module's own exception, as raised
        topobench.train_run(mutag, Backbone("X", LAYOUT, lambda ctx: AsksMore(ctx.hidden)), config, 0, max_epochs=1)

    class Replaces(TorchCell):
        def forward(self, x, operators):
            self.lin0.weight = torch.nn.Parameter(self.lin0.weight.detach().clone())
            return super().forward(x, operators)

    with pytest.raises(ValueError, match="parameter 'lin0.weight' was replaced by another tensor"):
        topobench.train_run(mutag, Backbone("X", LAYOUT, lambda ctx: Replaces(ctx.hidden)), config, 0, max_epochs=1)
    with pytest.raises(IndexError, match=r"batch\(indices\): index 188 is outside \[0, 188\)"):
        mutag.batch([0, 188])

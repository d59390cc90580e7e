#!/usr/bin/python3
"""TopoBench's CWN on REDDIT-BINARY, written in plain PyTorch independently of topos.

Usage: topobench_cwn_reddit.py [--seed S] [--epochs E] [--dropout P] [--zip PATH]

Checks whether CWN's low REDDIT-BINARY score in docs/topobench/ is TopoBench's model or a topos
bug (docs/topobench.md, "CWN on REDDIT-BINARY"). Everything is TopoBench's HEAD formulation,
read from its code, not from topos: EqualGausFeatures (one N(0, 0.1) vector of 10 values on every
node, drawn after torch.manual_seed(42)), networkx 3's cycle_basis with cycles of at most 10
nodes as 2-cells, ProjectionSum features, unsigned incidences, adjacency_1 = |B_2||B_2|ᵀ off the
diagonal; the encoder per rank (GraphNorm, Linear, relu, dropout), TopoModelX's CWN (Conv with
Xavier-uniform weights of gain 1.414), the wrapper's residual LayerNorm, PropagateSignalDown, the
sum of each graph's nodes and a Linear; Adam, StepLR(50, 0.5), batches of 16, TopoBench's random
split (np.random.seed(42), ten permutations, the (seed % 10)-th; 50/25/25 %).

Every `--every` epochs it prints the mean training loss, the accuracy of the training batches as
trained (dropout on), the accuracy in evaluation mode of the first 256 training graphs, the
validation and test accuracy, and the validation accuracy with dropout left on. After training it
fits the evaluation-mode logits of the graphs without 2-cells by their numbers of nodes with and
without edges, and prints the largest residual: in evaluation mode such a graph's prediction
depends on nothing else.

Needs torch and numpy (Debian's python3-torch, python3-numpy); the raw REDDIT-BINARY.zip of the
datasets folder (TOPOS_DATASETS_DIR/dgcnn/, docs/datasets.md). One thread; about 20 s an epoch.
"""
import argparse
import os
import time
import zipfile

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
DATASETS = os.environ.get("TOPOS_DATASETS_DIR", "../shared/datasets")
p.add_argument("--zip", default=os.path.join(DATASETS, "dgcnn", "REDDIT-BINARY.zip"))
p.add_argument("--seed", type=int, default=0, help="TopoBench's data seed")
p.add_argument("--epochs", type=int, default=30)
p.add_argument("--dropout", type=float, default=0.5, help="the encoder's (TopoBench: 0.5)")
p.add_argument("--every", type=int, default=5, help="epochs between checks")
args = p.parse_args()
torch.set_num_threads(1)
HIDDEN, LAYERS, BATCH, LR, MAX_CELL = 32, 3, 16, 1e-3, 10  # reproduce.sh's CWN REDDIT-BINARY line

# --- data: the DGCNN text file (first line: graphs; per graph 'n label', n lines 'tag k nbrs') --
lines = zipfile.ZipFile(args.zip).read("REDDIT-BINARY/REDDIT-BINARY.txt").decode().split("\n")
it = iter(lines)
raw = []
for _ in range(int(next(it))):
    n, label = map(int, next(it).split())
    es = set()
    for v in range(n):
        for w in map(int, next(it).split()[2:]):
            if w != v:
                es.add((min(v, w), max(v, w)))
    raw.append((n, sorted(es), label))
classes = sorted({label for _, _, label in raw})


def cycle_basis(n, adj):
    """networkx 3's cycle_basis on nodes 0..n-1 added in order, edges sorted (PyG's order)."""
    gnodes = dict.fromkeys(range(n))
    cycles, root = [], None
    while gnodes:
        if root is None:
            root = gnodes.popitem()[0]
        stack, pred, used = [root], {root: root}, {root: set()}
        while stack:
            z = stack.pop()
            zused = used[z]
            for nbr in adj[z]:
                if nbr not in used:
                    pred[nbr] = z
                    stack.append(nbr)
                    used[nbr] = {z}
                elif nbr == z:
                    cycles.append([z])
                elif nbr not in zused:
                    pn, cycle, q = used[nbr], [nbr, z], pred[z]
                    while q not in pn:
                        cycle.append(q)
                        q = pred[q]
                    cycle.append(q)
                    cycles.append(cycle)
                    used[nbr].add(z)
        for node in pred:
            gnodes.pop(node, None)
        root = None
    return cycles


torch.manual_seed(42)
feature = torch.normal(mean=0.0, std=0.1, size=(1, 10))  # EqualGausFeatures
graphs = []
for n, es, label in raw:
    adj = [[] for _ in range(n)]
    for a, b in es:
        adj[a].append(b), adj[b].append(a)
    for a in adj:
        a.sort()
    eid = {e: i for i, e in enumerate(es)}
    cells = [c for c in cycle_basis(n, adj) if 1 < len(c) <= MAX_CELL]
    m = len(es)
    ends = [a for a, _ in es] + [b for _, b in es]
    b1 = np.array([ends, list(range(m)) * 2], np.int64).reshape(2, -1)
    b2 = [[], []]
    a1 = {}
    for ci, c in enumerate(cells):
        pairs = [(c[k], c[(k + 1) % len(c)]) for k in range(len(c))]
        ring = [eid[(min(a, b), max(a, b))] for a, b in pairs]
        b2[0] += ring
        b2[1] += [ci] * len(ring)
        for x in ring:  # |B_2||B_2|ᵀ off the diagonal: the 2-cells two edges share
            for y in ring:
                if x != y:
                    a1[(x, y)] = a1.get((x, y), 0) + 1
    degree = np.bincount(b1[0], minlength=n)
    graphs.append(dict(n=n, m=m, c=len(cells), b1=b1, b2=np.array(b2, np.int64).reshape(2, -1),
                       a1=np.array(list(a1.keys()), np.int64).reshape(-1, 2).T,
                       a1v=np.array(list(a1.values()), np.float32), y=classes.index(label),
                       isolated=int((degree == 0).sum())))
on_cells = sum(len(set(g["b1"][0][np.isin(g["b1"][1], g["b2"][0])])) for g in graphs)
total = lambda key: sum(g[key] for g in graphs)
print(f"{len(graphs)} graphs: {total('n')} nodes, {total('m')} edges, {total('c')} 2-cells; "
      f"{sum(g['c'] == 0 for g in graphs)} graphs without 2-cells; {on_cells} nodes on an edge of "
      f"a 2-cell", flush=True)


def collate(idx):
    """The block-diagonal union of graphs[idx], as TopoBench's collate builds it."""
    on = oe = oc = 0
    b1, b2, a1, a1v, owner, y = [], [], [], [], ([], [], []), []
    for k, i in enumerate(idx):
        g = graphs[i]
        b1.append(g["b1"] + np.array([[on], [oe]]))
        b2.append(g["b2"] + np.array([[oe], [oc]]))
        a1.append(g["a1"] + oe)
        a1v.append(g["a1v"])
        for r, size in enumerate((g["n"], g["m"], g["c"])):
            owner[r].append(np.full(size, k))
        y.append(g["y"])
        on, oe, oc = on + g["n"], oe + g["m"], oc + g["c"]

    def sparse(ix, values, shape):
        ix = np.concatenate(ix, 1)
        v = torch.ones(ix.shape[1]) if values is None else torch.from_numpy(np.concatenate(values))
        return torch.sparse_coo_tensor(torch.from_numpy(ix), v, shape).coalesce()

    B1, B2, A1 = sparse(b1, None, (on, oe)), sparse(b2, None, (oe, oc)), sparse(a1, a1v, (oe, oe))
    x0 = feature.expand(on, -1)
    x1 = torch.sparse.mm(B1.t(), x0)  # ProjectionSum: x_r = |B_r|ᵀ x_{r-1}
    x2 = torch.sparse.mm(B2.t(), x1)
    return dict(x=[x0, x1, x2], B1=B1, B1t=B1.t().coalesce(), B2=B2, A1=A1,
                batch=[torch.from_numpy(np.concatenate(o)).long() for o in owner],
                y=torch.tensor(y), num=len(idx))


def segment_mean(x, b, G):
    s = torch.zeros(G, x.size(1)).index_add(0, b, x)
    return s / torch.zeros(G).index_add(0, b, torch.ones(b.numel())).clamp_min(1).unsqueeze(1)


class GraphNorm(nn.Module):  # PyG's
    def __init__(self, c, eps=1e-5):
        super().__init__()
        self.weight, self.bias = nn.Parameter(torch.ones(c)), nn.Parameter(torch.zeros(c))
        self.mean_scale, self.eps = nn.Parameter(torch.ones(c)), eps

    def forward(self, x, b, G):
        out = x - segment_mean(x, b, G)[b] * self.mean_scale
        return self.weight * out / (segment_mean(out * out, b, G)[b] + self.eps).sqrt() + self.bias


class Conv(nn.Module):  # TopoModelX's Conv: no attention, no aggregation norm, no update
    def __init__(self, i, o):
        super().__init__()
        self.weight = nn.Parameter(torch.empty(i, o))
        nn.init.xavier_uniform_(self.weight, gain=1.414)

    def forward(self, x, neighborhood):
        return torch.sparse.mm(neighborhood, x @ self.weight)


class Model(nn.Module):
    def __init__(self, h, L, p):
        super().__init__()
        self.p = p
        self.norm = nn.ModuleList(GraphNorm(10) for _ in range(3))
        self.enc = nn.ModuleList(nn.Linear(10, h) for _ in range(3))
        self.proj = nn.ModuleList(nn.Linear(h, h) for _ in range(3))
        self.c11 = nn.ModuleList(Conv(h, h) for _ in range(L))
        self.c21 = nn.ModuleList(Conv(h, h) for _ in range(L))
        self.c01 = nn.ModuleList(Conv(h, h) for _ in range(L))
        self.update = nn.ModuleList(nn.Linear(h, h) for _ in range(L))
        self.wrapper_ln = nn.ModuleList(nn.LayerNorm(h) for _ in range(3))
        self.readout_conv = nn.ModuleList(Conv(h, h) for _ in range(2))  # stages 1, 2
        self.readout_ln = nn.ModuleList(nn.LayerNorm(h) for _ in range(2))
        self.readout_proj = nn.ModuleList(nn.Linear(2 * h, h) for _ in range(2))
        self.classifier = nn.Linear(h, 2)

    def forward(self, d):
        G = d["num"]
        e = [F.relu(self.enc[r](self.norm[r](d["x"][r], d["batch"][r], G))) for r in range(3)]
        e = [F.dropout(v, self.p, self.training) for v in e]
        x0, x1, x2 = (F.elu(self.proj[r](e[r])) for r in range(3))
        for l in range(len(self.update)):
            m = (F.elu(self.c11[l](x1, d["A1"])) + F.elu(self.c21[l](x2, d["B2"]))
                 + F.elu(self.c01[l](x0, d["B1t"])))
            x1 = F.elu(self.update[l](m))
        x = [self.wrapper_ln[r](v + e[r]) for r, v in enumerate((x0, x1, x2))]
        for i, B in ((2, d["B2"]), (1, d["B1"])):  # PropagateSignalDown
            xi = self.readout_ln[i - 1](self.readout_conv[i - 1](x[i], B))
            x[i - 1] = self.readout_proj[i - 1](torch.cat([xi, x[i - 1]], 1))
        return self.classifier(torch.zeros(G, x[0].size(1)).index_add(0, d["batch"][0], x[0]))


n = len(graphs)
np.random.seed(42)
perm = [np.random.permutation(n) for _ in range(10)][args.seed % 10]
n_train, n_val = int(0.5 * n), int(0.25 * n)
train, val, test = perm[:n_train], perm[n_train:n_train + n_val], perm[n_train + n_val:]
batches = lambda idx: [collate(idx[i:i + BATCH]) for i in range(0, len(idx), BATCH)]
val_b, test_b, train_b = batches(val), batches(test), batches(train[:256])

torch.manual_seed(42)
model = Model(HIDDEN, LAYERS, args.dropout)
opt = torch.optim.Adam(model.parameters(), lr=LR)
sched = torch.optim.lr_scheduler.StepLR(opt, 50, 0.5)


def accuracy(bs, dropout_on=False):
    model.train(dropout_on)  # train() changes dropout only: GraphNorm keeps no running statistics
    with torch.no_grad():
        hits = sum((model(b).argmax(1) == b["y"]).sum().item() for b in bs)
    return hits / sum(b["num"] for b in bs)


rng = np.random.RandomState(args.seed)
print("epoch,loss,train_acc_as_trained,train_acc,val_acc,test_acc,val_acc_dropout_on,seconds",
      flush=True)
start = time.time()
for epoch in range(1, args.epochs + 1):
    model.train()
    loss_sum, hits, steps = 0.0, 0, 0
    order = rng.permutation(train)
    for i in range(0, n_train, BATCH):
        b = collate(order[i:i + BATCH])
        out = model(b)
        loss = F.cross_entropy(out, b["y"])
        opt.zero_grad()
        loss.backward()
        opt.step()
        loss_sum, steps = loss_sum + loss.item(), steps + 1
        hits += (out.argmax(1) == b["y"]).sum().item()
    sched.step()
    if epoch % args.every == 0:
        print(f"{epoch},{loss_sum / steps:.4f},{hits / n_train:.3f},{accuracy(train_b):.3f},"
              f"{accuracy(val_b):.3f},{accuracy(test_b):.3f},{accuracy(val_b, True):.3f},"
              f"{time.time() - start:.0f}", flush=True)

# In evaluation mode a graph without 2-cells is seen through its numbers of nodes with and without
# edges only: every edge gets the same x_1, LayerNorm(deg(v) z) = LayerNorm(z) erases the degrees.
forests = [i for i in range(n) if graphs[i]["c"] == 0]
if forests:
    model.eval()
    with torch.no_grad():
        logits = torch.cat([model(b) for b in batches(np.array(forests))]).double()
    X = torch.tensor([[graphs[i]["n"] - graphs[i]["isolated"], graphs[i]["isolated"], 1.0]
                      for i in forests], dtype=torch.float64)
    fit = torch.linalg.lstsq(X, logits).solution
    print(f"{len(forests)} graphs without 2-cells: their logits (largest {logits.abs().max():.1f}) "
          f"fitted by (nodes with edges, isolated nodes, 1) to within "
          f"{(X @ fit - logits).abs().max():.2e}", flush=True)

"""TopoModelX's UniGCNII tutorial (tutorials/hypergraph/unigcnii_train.ipynb) through topos.

The tutorial's steps, written again here: Cora's nodes and one-hop neighbourhoods as hyperedges
(duplicates dropped), UniGCNII with a linear readout per node, Adam at lr 0.01 on the public
Planetoid split's 140 training nodes, cross-entropy, accuracy on its 1,000 test nodes. The only
change a TopoModelX user makes is the import below; Cora comes from the raw Planetoid files under
$TOPOS_DATASETS_DIR (topos.topobench.read_dataset, PyG's node order) instead of
torch_geometric's download.

    TOPOS_DATASETS_DIR=/path/to/datasets PYTHONPATH=build/python \
        /usr/bin/python3 examples/python/unigcnii_cora.py --epochs 50
"""

import argparse
import os
import pathlib

import torch

from topos.topobench import read_dataset
from topos.topomodelx.nn.hypergraph.unigcnii import UniGCNII  # was: from topomodelx.nn.hypergraph.unigcnii


def cora_hypergraph(root):
    """Features, labels, the public split's masks and the one-hop-neighbourhood incidence."""
    cora = read_dataset("Cora", root=root)
    n = cora["num_nodes"]
    ei = cora["edge_index"]
    both = torch.cat([ei, ei.flip(0)], dim=1)  # PyG's edge_index lists both directions
    seen, hyperedges = set(), []
    for node in range(n):
        neighbourhood = tuple(sorted(both[1, both[0] == node].tolist()))
        if neighbourhood not in seen:  # the tutorial drops repeated hyperedges
            seen.add(neighbourhood)
            hyperedges.append(neighbourhood)
    rows = torch.tensor([v for he in hyperedges for v in he])
    cols = torch.tensor([j for j, he in enumerate(hyperedges) for _ in he])
    incidence_1 = torch.sparse_coo_tensor(torch.stack([rows, cols]), torch.ones(len(rows)), (n, len(hyperedges)))
    incidence_1 = incidence_1.coalesce()
    # Planetoid's public split, as torch_geometric builds its masks.
    test_index = [int(v) for v in (pathlib.Path(root) / "planetoid" / "ind.cora.test.index").read_text().split()]
    train_mask = torch.zeros(n, dtype=torch.bool)
    train_mask[:140] = True
    test_mask = torch.zeros(n, dtype=torch.bool)
    test_mask[test_index] = True
    return cora["x"], cora["labels"], incidence_1, train_mask, test_mask


class Network(torch.nn.Module):
    """UniGCNII and a linear layer to the classes, per node (the tutorial's node-level task)."""

    def __init__(self, in_channels, hidden_channels, out_channels, **kwargs):
        super().__init__()
        self.base_model = UniGCNII(in_channels=in_channels, hidden_channels=hidden_channels, **kwargs)
        self.linear = torch.nn.Linear(hidden_channels, out_channels)

    def forward(self, x_0, incidence_1):
        x_0, _ = self.base_model(x_0, incidence_1)
        return self.linear(x_0)


def train(root, epochs=5, test_interval=5, seed=0):
    """The tutorial's loop; returns (epoch, train loss, test accuracy) at every test interval."""
    torch.manual_seed(seed)
    x_0, y, incidence_1, train_mask, test_mask = cora_hypergraph(root)
    model = Network(x_0.shape[1], 128, int(y.max()) + 1, n_layers=2, input_drop=0.5)
    optimizer = torch.optim.Adam(model.parameters(), lr=0.01)
    loss_fn = torch.nn.CrossEntropyLoss()
    history = []
    for epoch in range(epochs):
        model.train()
        loss = loss_fn(model(x_0, incidence_1)[train_mask], y[train_mask])
        loss.backward()
        optimizer.step()
        optimizer.zero_grad()
        if epoch % test_interval == 0 or epoch == epochs - 1:
            model.eval()
            with torch.no_grad():
                y_hat = model(x_0, incidence_1)
            train_loss = loss_fn(y_hat[train_mask], y[train_mask]).item()
            test_acc = (y_hat[test_mask].argmax(1) == y[test_mask]).float().mean().item()
            history.append((epoch, train_loss, test_acc))
    return history


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", default=os.environ.get("TOPOS_DATASETS_DIR"), help="the datasets folder")
    parser.add_argument("--epochs", type=int, default=5)
    parser.add_argument("--test-interval", type=int, default=5)
    args = parser.parse_args()
    if not args.root:
        parser.error("--root: not given and TOPOS_DATASETS_DIR is not set")
    for epoch, train_loss, test_acc in train(args.root, args.epochs, args.test_interval):
        print(f"epoch {epoch}: train loss {train_loss:.4f}, test accuracy {test_acc:.4f}")

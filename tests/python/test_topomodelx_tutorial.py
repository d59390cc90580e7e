# TopoModelX's UniGCNII tutorial on Cora run through topos.topomodelx (examples/python/
# unigcnii_cora.py: the tutorial's loop with only its import changed): it learns, well above the
# majority class of the test nodes, its training loss falling at every check, and the same
# numbers from a second seeded run. Needs TOPOS_DATASETS_DIR (skipped without).
import importlib.util
import pathlib

import torch

EXAMPLE = pathlib.Path(__file__).resolve().parents[2] / "examples" / "python" / "unigcnii_cora.py"


def load_example():
    spec = importlib.util.spec_from_file_location("unigcnii_cora", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_unigcnii_tutorial_learns_cora(datasets_dir):
    example = load_example()
    x, y, incidence_1, train_mask, test_mask = example.cora_hypergraph(datasets_dir)
    # Cora: 2,708 nodes of 1,433 features, 7 classes; 140 training and 1,000 test nodes.
    assert x.shape == (2708, 1433) and int(y.max()) == 6
    assert int(train_mask.sum()) == 140 and int(test_mask.sum()) == 1000
    # Every node's neighbourhood is a hyperedge, the repeated ones once: each column is one node's
    # neighbours, and no two columns are equal.
    dense = incidence_1.to_dense()
    assert dense.shape[0] == 2708 and bool((dense.sum(0) > 0).all()) and bool((dense.sum(1) > 0).all())
    assert torch.unique(dense.t(), dim=0).shape[0] == dense.shape[1]

    history = example.train(datasets_dir, epochs=30, test_interval=10)
    assert [h[0] for h in history] == [0, 10, 20, 29]
    losses = [h[1] for h in history]
    assert all(b < a for a, b in zip(losses, losses[1:])), losses
    majority = torch.bincount(y[test_mask]).max().item() / 1000
    assert history[-1][2] > majority + 0.2, (history, majority)
    assert example.train(datasets_dir, epochs=30, test_interval=10) == history

"""topos's drop-in for ``topomodelx.nn.hypergraph.dhgcn``.

DHGCN builds its hypergraph in every forward from the features (each node's k nearest
neighbours, and k-means clusters seeded by ``torch.randperm``), so it is written here in torch,
not run by the C++ zoo: TopoModelX's computation step for step (the same draws from torch's
generator, the same cluster updates), with torch_cluster's ``knn_graph`` and ``nearest`` written
with ``torch.cdist`` (equal results but for exact distance ties).
"""

import torch

from topos.topomodelx._init import GAIN

__all__ = ["DHGCN"]


class _Conv(torch.nn.Module):
    """TopoModelX's Conv without attention or update: neighborhood @ (x @ weight)."""

    def __init__(self, in_channels, out_channels):
        super().__init__()
        self.weight = torch.nn.Parameter(torch.empty(in_channels, out_channels))
        torch.nn.init.xavier_uniform_(self.weight, gain=GAIN)

    def forward(self, x, neighborhood):
        return torch.mm(neighborhood, torch.mm(x, self.weight))


def _knn_graph(x, k):
    """torch_cluster.knn_graph(x, k, loop=False, flow="source_to_target"): edges (j, i) from
    each node i's k nearest other nodes j."""
    n = x.size(0)
    k = min(k, n - 1)
    d = torch.cdist(x, x)
    d.fill_diagonal_(float("inf"))
    j = d.topk(k, dim=1, largest=False).indices
    i = torch.arange(n).repeat_interleave(k)
    return torch.stack([j.reshape(-1), i])


def _nearest(x, y):
    """torch_cluster.nearest(x, y) in one batch: the index of the closest row of y per row of x."""
    return torch.cdist(x, y).argmin(dim=1)


class DHGCNLayer(torch.nn.Module):
    """TopoModelX's DHGCNLayer: a linear map, a hypergraph of k-NN and k-means hyperedges built
    from its output, then node -> hyperedge and hyperedge -> node convolutions."""

    def __init__(
        self,
        in_channels,
        intermediate_channels,
        out_channels,
        k_neighbours=3,
        k_centroids=4,
        device="cpu",
        **kwargs,
    ):
        super().__init__()
        self.k_neighbours = k_neighbours
        self.k_centroids = k_centroids
        self.fc_layer = torch.nn.Linear(in_channels, intermediate_channels, device=device)
        self.conv_dt_level0_0_to_1 = _Conv(intermediate_channels, intermediate_channels)
        self.conv_dt_level0_1_to_0 = _Conv(intermediate_channels, out_channels)

    @staticmethod
    def kmeans_graph(x, k):
        """TopoModelX's incremental k-means: (node, cluster) index pairs."""
        permutation = torch.randperm(x.size(0), device=x.device)
        centroid_indices = permutation[:k]
        clusters = [centroid_indices[i : i + 1] for i in range(k)]
        for new_index in permutation[k:]:
            centroids = torch.index_select(x, 0, centroid_indices)
            assigned = int(_nearest(x[new_index : new_index + 1], centroids)[0])
            members = torch.cat([clusters[assigned], new_index.view(1)])
            features = torch.index_select(x, 0, members)
            distances = torch.cdist(features, features)
            mean_distances = distances.sum(dim=1) / (distances.size(0) - 1)
            centroid_indices[assigned] = members[torch.argmin(mean_distances)]
            clusters[assigned] = members
        cluster_ids = torch.cat(
            [torch.full((c.size(0),), i, dtype=c.dtype) for i, c in enumerate(clusters)]
        )
        return torch.stack([torch.cat(clusters), cluster_ids])

    def get_dynamic_topology(self, x):
        n = x.size(0)
        if self.k_centroids > n:
            raise ValueError(
                f"There are {n} input nodes. The k-means clustering requires at least "
                f"{self.k_centroids} nodes."
            )
        local = _knn_graph(x.detach().cpu(), self.k_neighbours).to(x.device)
        local = torch.sparse_coo_tensor(
            local, torch.ones(local.size(1), device=x.device), size=(n, n)
        )
        glob = self.kmeans_graph(x.detach().cpu(), self.k_centroids).to(x.device)
        glob = torch.sparse_coo_tensor(
            glob, torch.ones(n, device=x.device), size=(n, self.k_centroids)
        )
        return torch.cat((local, glob), dim=1)

    def forward(self, x_0):
        x = self.fc_layer(x_0)
        incidence = self.get_dynamic_topology(x).to(x.dtype)
        x_1 = self.conv_dt_level0_0_to_1(x, incidence.transpose(1, 0))
        return self.conv_dt_level0_1_to_0(x_1, incidence), x_1


class DHGCN(torch.nn.Module):
    """Dynamic hypergraph convolutional network (TopoModelX's ``nn.hypergraph.dhgcn.DHGCN``,
    written in torch: its hypergraph is rebuilt from the features at every forward)."""

    def __init__(self, in_channels, hidden_channels, n_layers=1, **kwargs):
        super().__init__()
        self.layers = torch.nn.ModuleList(
            DHGCNLayer(
                in_channels=in_channels if i == 0 else hidden_channels,
                intermediate_channels=hidden_channels,
                out_channels=hidden_channels,
                **kwargs,
            )
            for i in range(n_layers)
        )

    def forward(self, x_0):
        for layer in self.layers:
            x_0, x_1 = layer(x_0)
        return x_0, x_1

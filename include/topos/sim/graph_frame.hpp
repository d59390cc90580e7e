// topos/sim/graph_frame.hpp
// One timestep of a graph-network simulator (MeshGraphNet, FIGNet) as plain data: typed node
// sets and edge sets with their raw features, the edges' sender and receiver nodes (several per
// edge for a hyperedge with slots, FIGNet's face-face edges) and the mesh nodes' targets; and the
// row-major matrices the simulation layer keeps its per-node and per-object rows in. The
// simulation layer writes it (mesh_graph.hpp, the baselines' features); the models
// (models/gns/network.hpp) turn it into tensors and operators. Eigen only.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

namespace topos::sim {

using RowMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using IndexMatrix = Eigen::Matrix<std::int64_t, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

/// The cells of one node set: n rows of raw (unnormalised) features.
struct NodeSetData {
  RowMatrix features;
  std::int64_t size() const { return features.rows(); }
};

/// An edge set between two node sets: E rows of features; senders and receivers E × slots
/// (slot k of edge e links sender node senders(e, k) to receiver node receivers(e, k); ordinary
/// edges have one slot). Indices are local to their node set.
struct EdgeSetData {
  RowMatrix features;
  IndexMatrix senders, receivers;
  std::int64_t size() const { return features.rows(); }
};

/// One timestep: node and edge sets by name, and per mesh node its target acceleration
/// x_{t+1} - 2 x_t + x_{t-1} (empty when rolling out), whether it is dynamic, and its object.
struct GraphFrame {
  std::map<std::string, NodeSetData> nodes;
  std::map<std::string, EdgeSetData> edges;
  RowMatrix target;                       ///< mesh nodes × 3, or empty
  std::vector<char> dynamic;              ///< per mesh node: 1 when its object moves
  std::vector<std::int64_t> node_object;  ///< per mesh node: its object (scene order)

  const NodeSetData& node_set(const std::string& name) const {
    auto it = nodes.find(name);
    if (it == nodes.end()) throw std::invalid_argument("graph frame: no node set '" + name + "'");
    return it->second;
  }
  const EdgeSetData& edge_set(const std::string& name) const {
    auto it = edges.find(name);
    if (it == edges.end()) throw std::invalid_argument("graph frame: no edge set '" + name + "'");
    return it->second;
  }
};

}  // namespace topos::sim

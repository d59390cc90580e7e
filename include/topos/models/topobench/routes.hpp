// topos/models/topobench/routes.hpp
// TopoTune's neighbourhood vocabulary (std only): the names TopoBench's TopoTune configs list
// under `neighborhoods`, read as the route (source rank → target rank) a GNN runs along.
//
//   [h-]up_adjacency-k     k → k   cells of rank k sharing a coface of rank k + h
//   [h-]down_adjacency-k   k → k   cells of rank k sharing a face of rank k - h
//   [h-]up_laplacian-k     k → k   the same with every cell that has such a coface joined to itself
//   [h-]down_laplacian-k   k → k   the same through faces
//   [h-]up_incidence-k     k → k+h cells of rank k to their cofaces of rank k + h
//   [h-]down_incidence-k   k → k-h cells of rank k to their faces of rank k - h
//
// h (hops, default 1) goes through h ranks: with M = |B_{k+1}| ⋯ |B_{k+h}| (rank k × rank k + h),
// up_adjacency is the off-diagonal pattern of M Mᵀ and up_incidence that of Mᵀ; down routes use
// M = |B_{k-h+1}| ⋯ |B_k| and MᵀM, M (TopoBench's select_neighborhoods_of_interest). The lifted
// graph's operator of that name (topobench/lifting.hpp) is target × source with every value 1:
// TopoTune's GNNs read only the pattern. TopoBench's get_routes_from_neighborhoods maps every
// name to an inter-rank route (k → k ± h, adjacencies and Laplacians included); here adjacencies
// and Laplacians are the intra-rank routes TopoTune's paper describes (docs/topobench.md).
#pragma once

#include <stdexcept>
#include <string>
#include <vector>

namespace topos::models::topobench {

struct NeighborhoodRoute {
  enum class Kind { adjacency, laplacian, incidence };
  Kind kind = Kind::adjacency;
  bool up = true;
  int hops = 1;
  int rank = 0;  ///< the source rank k
  int source_rank() const { return rank; }
  int target_rank() const {
    return kind != Kind::incidence ? rank : up ? rank + hops : rank - hops;
  }
};

inline const char* neighborhood_forms() {
  return "[h-]up_adjacency-k, [h-]down_adjacency-k, [h-]up_laplacian-k, [h-]down_laplacian-k, "
         "[h-]up_incidence-k, [h-]down_incidence-k (k the source rank, h >= 1 the hops, e.g. "
         "up_adjacency-1, down_incidence-2, 2-up_adjacency-0)";
}

/// A name with a '-' is a neighbourhood (the lifting's other operators have none).
inline bool is_neighborhood_name(const std::string& name) {
  return name.find('-') != std::string::npos;
}

/// The route of a neighbourhood name; throws, listing the valid forms, on another name.
inline NeighborhoodRoute neighborhood_route(const std::string& name) {
  const auto bad = [&](const std::string& why) {
    return std::invalid_argument("neighbourhood '" + name + "': " + why + "; the valid forms are " +
                                 neighborhood_forms());
  };
  std::vector<std::string> parts;
  for (std::size_t at = 0;;) {
    const auto dash = name.find('-', at);
    parts.push_back(name.substr(at, dash == std::string::npos ? std::string::npos : dash - at));
    if (dash == std::string::npos) break;
    at = dash + 1;
  }
  if (parts.size() != 2 && parts.size() != 3) throw bad("expected 2 or 3 parts joined by '-'");
  const auto integer = [&](const std::string& s, const char* what) {
    if (s.empty() || s.size() > 2 || s.find_first_not_of("0123456789") != std::string::npos)
      throw bad(std::string(what) + " '" + s + "' is not a small non-negative integer");
    return std::stoi(s);
  };
  NeighborhoodRoute r;
  r.rank = integer(parts.back(), "the rank");
  if (parts.size() == 3) r.hops = integer(parts[0], "the hops");
  if (r.hops < 1) throw bad("the hops must be at least 1");
  const std::string& type = parts[parts.size() - 2];
  const auto under = type.find('_');
  const std::string direction = type.substr(0, under);
  const std::string kind = under == std::string::npos ? "" : type.substr(under + 1);
  if (direction != "up" && direction != "down")
    throw bad("'" + type + "' does not start with up_ or down_");
  r.up = direction == "up";
  if (kind == "adjacency")
    r.kind = NeighborhoodRoute::Kind::adjacency;
  else if (kind == "laplacian")
    r.kind = NeighborhoodRoute::Kind::laplacian;
  else if (kind == "incidence")
    r.kind = NeighborhoodRoute::Kind::incidence;
  else
    throw bad("'" + type + "' is not adjacency, laplacian or incidence");
  if (!r.up && r.rank - r.hops < 0)
    throw bad("rank " + std::to_string(r.rank) + " has no faces " + std::to_string(r.hops) +
              " ranks down");
  return r;
}

}  // namespace topos::models::topobench

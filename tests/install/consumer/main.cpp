// A downstream project: lifts a tetrahedron and runs a tensor through its incidence.
#include <torch/torch.h>

#include <topos/core/lifting.hpp>
#include <topos/geometry/graph.hpp>

#include <iostream>

int main() {
  topos::TriangleMesh tet;
  tet.vertices.resize(4, 3);
  tet.vertices << 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1;
  tet.faces.resize(4, 3);
  tet.faces << 0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3;
  auto lifted = topos::lift_meshes({tet});
  auto [components, labels] = topos::connected_components(lifted.complex, 0, 1);
  auto x = torch::ones({lifted.complex.size(1), 2});
  const bool ok = lifted.complex.shape() == std::vector<std::int64_t>{4, 6, 4, 1} &&
                  components == 1 && x.sum().item<float>() == 12.0f;
  std::cout << (ok ? "consumer ok" : "consumer FAILED") << "\n";
  return ok ? 0 : 1;
}

// A downstream project: lifts a tetrahedron and runs a tensor through its incidence, by hand and
// through an operator schedule. Built twice: against the compiled topos::nn (the default) and
// against topos::header_only.
#include <torch/torch.h>

#include <topos/core/mesh_lifting.hpp>
#include <topos/geometry/graph.hpp>
#include <topos/nn/operator_schedule.hpp>
#include <topos/util/malloc.hpp>

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
  using namespace topos::nn::ops;
  topos::nn::OperatorSchedule s;
  s.input("x", 1, 2).operator_input("B", 1, 0).output("y", 0);
  s.step(into(0).sum(from(1).via("B").linear("lin", 3, /*bias=*/false)));
  topos::nn::OperatorNetwork net(s);
  const auto B = topos::nn::SparseOperator::from_dense(torch::ones({4, 6}));
  const auto y = net->forward({{"x", x}}, {{"B", B}}).at("y");
  const auto expected = torch::full({4, 2}, 6.0f).matmul(net->parameter("lin.weight").t());
  const bool ok = lifted.complex.shape() == std::vector<std::int64_t>{4, 6, 4, 1} &&
                  components == 1 && x.sum().item<float>() == 12.0f &&
                  torch::allclose(y, expected, 1e-5, 1e-5);
#ifdef TOPOS_HEADER_ONLY
  const char* mode = " (header-only)";
#else
  const char* mode = " (compiled topos::nn)";
#endif
  std::cout << (ok ? "consumer ok" : "consumer FAILED") << mode << ", malloc "
            << topos::malloc_name() << "\n";
  return ok ? 0 : 1;
}

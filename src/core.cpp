// The compiled part of topos::core (topos::core_compiled): the default combinatorial complex, its
// incidence and adjacency neighbourhoods and the mesh lifting, instantiated once here. The
// headers declare these instantiations extern when TOPOS_CORE_COMPILED is set (by this target,
// for what links it: topos::nn), so a model's translation unit does not compile them again (4 s
// of examples/custom_schedule.cpp's 23). Other complex options are instantiated where used.
// Also compiled here, their headers only declaring them under TOPOS_CORE_COMPILED: the dense
// spectral functions (core/spectral.hpp: Eigen's eigen- and singular-value solvers, 17 s of
// compile time for any translation unit that merely included them), the rigid-body helpers
// (mesh/rigid.hpp: the SVD of shape matching) and the built-in meshes (mesh/primitives.hpp).
#define TOPOS_CORE_COMPILED_SOURCE
#include "topos/core/combinatorial_complex.hpp"
#include "topos/core/mesh_lifting.hpp"
#include "topos/core/neighborhood.hpp"
#include "topos/core/spectral.hpp"
#include "topos/mesh/primitives.hpp"
#include "topos/mesh/rigid.hpp"

namespace topos {
template class CombinatorialComplex<DefaultComplexOptions>;
template Neighborhood incidence_neighborhood<DefaultComplexOptions>(
    const CombinatorialComplex<DefaultComplexOptions>&, int, int, std::string);
template Neighborhood adjacency_neighborhood<DefaultComplexOptions>(
    const CombinatorialComplex<DefaultComplexOptions>&, int, int, std::string);
template LiftedMeshes<DefaultComplexOptions> lift_meshes<DefaultComplexOptions>(
    const std::vector<TriangleMesh>&, const LiftOptions&);
}  // namespace topos

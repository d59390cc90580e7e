// The compiled part of topos::core (topos::core_compiled): the default combinatorial complex, its
// incidence and adjacency neighbourhoods and the mesh lifting, instantiated once here. The
// headers declare these instantiations extern when TOPOS_CORE_COMPILED is set (by this target,
// for what links it: topos::nn), so a model's translation unit does not compile them again (4 s
// of examples/custom_schedule.cpp's 23). Other complex options are instantiated where used.
#include "topos/core/combinatorial_complex.hpp"
#include "topos/core/mesh_lifting.hpp"
#include "topos/core/neighborhood.hpp"

namespace topos {
template class CombinatorialComplex<DefaultComplexOptions>;
template Neighborhood incidence_neighborhood<DefaultComplexOptions>(
    const CombinatorialComplex<DefaultComplexOptions>&, int, int, std::string);
template Neighborhood adjacency_neighborhood<DefaultComplexOptions>(
    const CombinatorialComplex<DefaultComplexOptions>&, int, int, std::string);
template LiftedMeshes<DefaultComplexOptions> lift_meshes<DefaultComplexOptions>(
    const std::vector<TriangleMesh>&, const LiftOptions&);
}  // namespace topos

// The compiled part of topos::data: the graph benchmarks' readers (TU, DGCNN, Planetoid pickles)
// and TopoBench's features, built once here instead of in every translation unit that includes
// topos/data/graph_datasets.hpp (topos/config.hpp; TOPOS_HEADER_ONLY inlines them instead).
#ifdef TOPOS_HEADER_ONLY
#error "src/data.cpp is the compiled component; build it without TOPOS_HEADER_ONLY"
#endif

#include "topos/data/graph_datasets-inl.hpp"

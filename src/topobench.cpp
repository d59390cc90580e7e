// The compiled part of topos::topobench: TopoBench's pipeline (the lifting of a graph, batches,
// the model around any backbone, the trainer and the runs folder), built once here instead of in
// every translation unit that trains a backbone through it (topos/config.hpp; TOPOS_HEADER_ONLY
// inlines it instead). The table's ten backbones are not here: table_models.hpp, included by
// what runs the table.
#ifdef TOPOS_HEADER_ONLY
#error "src/topobench.cpp is the compiled component; build it without TOPOS_HEADER_ONLY"
#endif

#include "topos/models/topobench/batch-inl.hpp"
#include "topos/models/topobench/lifting-inl.hpp"
#include "topos/models/topobench/model-inl.hpp"
#include "topos/models/topobench/report-inl.hpp"
#include "topos/models/topobench/trainer-inl.hpp"

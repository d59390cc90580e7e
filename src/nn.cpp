// The compiled part of topos::nn: batch collation, the operator schedule's shape inference,
// interpreter and printers, and the checkpoint reader and writer, built once here instead of in
// every translation unit that includes their headers (topos/config.hpp; TOPOS_HEADER_ONLY
// inlines them instead).
#ifdef TOPOS_HEADER_ONLY
#error "src/nn.cpp is the compiled component; build it without TOPOS_HEADER_ONLY"
#endif

#include "topos/nn/complex_batch-inl.hpp"
#include "topos/nn/operator_schedule/build-inl.hpp"
#include "topos/nn/operator_schedule/builder-inl.hpp"
#include "topos/nn/operator_schedule/checks-inl.hpp"
#include "topos/nn/operator_schedule/cost-inl.hpp"
#include "topos/nn/operator_schedule/elementwise-inl.hpp"
#include "topos/nn/operator_schedule/filter-inl.hpp"
#include "topos/nn/operator_schedule/interpreter-inl.hpp"
#include "topos/nn/operator_schedule/layers-inl.hpp"
#include "topos/nn/operator_schedule/plan-inl.hpp"
#include "topos/nn/operator_schedule/printer-inl.hpp"
#include "topos/nn/operator_schedule/products-inl.hpp"
#include "topos/nn/serialization-inl.hpp"

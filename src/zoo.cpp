// The compiled part of topos::zoo: the model zoo's golden-case runner
// (topos/models/zoo/golden_case.hpp), which builds any of the zoo's models by name, instantiated
// once here instead of in every translation unit that runs a case (topos/config.hpp;
// TOPOS_HEADER_ONLY inlines it instead).
#ifdef TOPOS_HEADER_ONLY
#error "src/zoo.cpp is the compiled component; build it without TOPOS_HEADER_ONLY"
#endif

#include "topos/models/zoo/golden_case-inl.hpp"

// topos/config.hpp
// Compiled or header-only. The heavy implementations (the schedule interpreters, shape inference,
// the checkpoint reader) live in `*-inl.hpp` files beside their declarations. By default they are
// compiled once into the library behind topos::nn (src/nn.cpp), so a model's translation unit
// parses declarations and generates code for its own model only. Define TOPOS_HEADER_ONLY
// (CMake target topos::header_only) to compile them inline in every translation unit instead,
// with no library to link, as fmt's FMT_HEADER_ONLY does.
#pragma once

#ifdef TOPOS_HEADER_ONLY
#define TOPOS_INLINE inline
#else
#define TOPOS_INLINE
#endif

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

// The same for the few core functions compiled in topos::core_compiled (src/core.cpp, which
// defines TOPOS_CORE_COMPILED_SOURCE): declared only where TOPOS_CORE_COMPILED is set (by
// linking that target), inline in every translation unit with topos::core alone.
#if defined(TOPOS_CORE_COMPILED) || defined(TOPOS_CORE_COMPILED_SOURCE)
#define TOPOS_CORE_INLINE
#else
#define TOPOS_CORE_INLINE inline
#endif

// The compiled part of topos::data's TDL golden-case reader (topos/data/tdl_case.hpp): every
// operator of every domain, instantiated once here instead of in every translation unit that
// reads a case (topos/config.hpp; TOPOS_HEADER_ONLY inlines it instead). Its own translation
// unit, beside src/data.cpp: the two compile in parallel, and a program that reads no case links
// none of it.
#ifdef TOPOS_HEADER_ONLY
#error "src/tdl_case.cpp is the compiled component; build it without TOPOS_HEADER_ONLY"
#endif

#include "topos/data/tdl_case-inl.hpp"

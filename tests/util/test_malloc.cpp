// Tests of topos/util/malloc.hpp. This test program is not linked with tcmalloc, so it must name
// glibc's malloc with the running glibc's version; the hopnet_pipeline test checks that the
// programs linked with topos::tcmalloc name tcmalloc.
#include "topos/util/malloc.hpp"

#include <catch2/catch.hpp>

#include <gnu/libc-version.h>

#include <string>

TEST_CASE("malloc_name: glibc's malloc with its version when tcmalloc is not linked") {
  CHECK(topos::malloc_name() == std::string("glibc ") + gnu_get_libc_version());
}

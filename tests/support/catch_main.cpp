// The single Catch2 main object shared by every test executable.
#define CATCH_CONFIG_MAIN
#include <catch2/catch.hpp>

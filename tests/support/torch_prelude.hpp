// The first include of every LibTorch test file: torch first, then Catch2, whose CHECK macro
// must be the one defined last (glog, which LibTorch includes, defines a CHECK of its own).
#pragma once
#include <torch/torch.h>
#include <catch2/catch.hpp>

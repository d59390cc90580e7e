// Precompiled prelude of the LibTorch test executable: torch first, then Catch2 (glog's CHECK
// would otherwise replace Catch's; library-design C.6.4).
#pragma once
#include <torch/torch.h>
#include <catch2/catch.hpp>

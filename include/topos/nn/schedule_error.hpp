// topos/nn/schedule_error.hpp
// The error a schedule reports when its network is built or run: the message names the step.
#pragma once

#include <stdexcept>

namespace topos::nn {

class ScheduleError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

}  // namespace topos::nn

// topos/nn/operator_schedule/parameters-inl.hpp
// OperatorNetwork's parameters, buffers and modules at their dotted paths
// (created once, checked when met again), apart from the shape inference that asks for them
// (build-inl.hpp). Compiled into topos::nn, or inline with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/nn/operator_schedule/network.hpp"

#include <cmath>
#include <memory>
#include <sstream>
#include <string>
#include <typeinfo>
#include <utility>
#include <vector>

namespace topos::nn {

namespace detail {

/// "[2, 3]": a tensor's sizes, for error messages.
TOPOS_INLINE std::string shape_str(const torch::Tensor& x) {
  std::ostringstream o;
  o << x.sizes();
  return o.str();
}

/// A parameter's or module's path must be a dotted name: "layers.0.conv", no empty part.
TOPOS_INLINE void check_dotted_path(const std::string& where, const char* what,
                                    const std::string& path) {
  if (path.empty() || path.front() == '.' || path.back() == '.' ||
      path.find("..") != std::string::npos)
    throw ScheduleError(where + ": " + what + " path '" + path + "' is not a dotted name");
}

}  // namespace detail

TOPOS_INLINE const torch::Tensor& OperatorNetworkImpl::parameter(const std::string& path) const {
  auto it = params_.find(path);
  if (it == params_.end()) throw ScheduleError("no parameter '" + path + "'");
  return it->second;
}

TOPOS_INLINE std::pair<torch::nn::Module*, std::string> OperatorNetworkImpl::owner_of(
    const std::string& path) {
  torch::nn::Module* m = this;
  std::size_t start = 0;
  for (auto dot = path.find('.'); dot != std::string::npos; dot = path.find('.', start)) {
    const auto part = path.substr(start, dot - start);
    auto children = m->named_children();
    auto* child = children.find(part);
    m = child != nullptr ? child->get()
                         : m->register_module(part, std::make_shared<torch::nn::Module>()).get();
    start = dot + 1;
  }
  return {m, path.substr(start)};
}

TOPOS_INLINE void OperatorNetworkImpl::make_parameter(const std::string& where,
                                                      const std::string& path,
                                                      std::vector<std::int64_t> shape,
                                                      ParameterInit init, bool trainable) {
  detail::check_dotted_path(where, "parameter", path);
  auto it = params_.find(path);
  if (it != params_.end()) {
    if (it->second.sizes() != torch::IntArrayRef(shape))
      throw ScheduleError(where + ": parameter '" + path + "' is used with shape " +
                          detail::shape_str(torch::empty(shape)) + " but was made " +
                          detail::shape_str(it->second));
    if (buffers_.count(path) == static_cast<std::size_t>(trainable))
      throw ScheduleError(where + ": '" + path + "' is used as a " +
                          (trainable ? "parameter" : "buffer") + " but was made a " +
                          (trainable ? "buffer" : "parameter"));
    return;
  }
  for (auto d : shape)
    if (d <= 0)
      throw ScheduleError(where + ": parameter '" + path + "' would have shape " +
                          detail::shape_str(torch::empty(shape)));
  auto [owner, leaf] = owner_of(path);
  if (!trainable) {  // non-trainable state, saved in the state_dict at its path
    params_.emplace(path, owner->register_buffer(leaf, torch::full(shape, init.value)));
    buffers_.insert(path);
    return;
  }
  auto p = owner->register_parameter(leaf, torch::empty(shape));
  torch::NoGradGuard g;
  switch (init.kind) {
    case ParameterInit::Kind::glorot:
      xavier_uniform(p, init.value);
      break;
    case ParameterInit::Kind::linear_weight:
      torch::nn::init::kaiming_uniform_(p, std::sqrt(5.0));
      break;
    case ParameterInit::Kind::zeros:
      p.zero_();
      break;
    case ParameterInit::Kind::constant:
      p.fill_(init.value);
      break;
    case ParameterInit::Kind::uniform:
      torch::nn::init::uniform_(p, -init.value, init.value);
      break;
  }
  params_.emplace(path, p);
}

TOPOS_INLINE std::shared_ptr<torch::nn::Module> OperatorNetworkImpl::make_module(
    const std::string& where, const std::string& path, std::shared_ptr<torch::nn::Module> m) {
  if (!m) throw ScheduleError(where + ": module '" + path + "' is null");
  detail::check_dotted_path(where, "module", path);
  if (auto it = modules_.find(path); it != modules_.end()) {
    const auto& a = *it->second;
    const auto& b = *m;
    if (typeid(a) != typeid(b))
      throw ScheduleError(where + ": module '" + path + "' was made " + a.name() + ", not " +
                          b.name());
    return it->second;  // shared by name: the first one stays
  }
  if (params_.count(path)) throw ScheduleError(where + ": '" + path + "' is already a parameter");
  // Parameters under the path ("p.weight" of a linear at "p") hang from a plain module there.
  for (const auto& [name, tensor] : params_)
    if (name.compare(0, path.size() + 1, path + ".") == 0)
      throw ScheduleError(where + ": '" + path + "' already holds the parameter '" + name +
                          "': give the module another path");
  auto [owner, leaf] = owner_of(path);
  return modules_.emplace(path, owner->register_module(leaf, std::move(m))).first->second;
}

}  // namespace topos::nn

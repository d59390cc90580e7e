// topos/nn/operator_schedule/parameters-inl.hpp
// OperatorNetwork's parameters, buffers, modules and normalisations at their dotted paths
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

TOPOS_INLINE void OperatorNetworkImpl::make_module(const std::string& where,
                                                   const std::string& path,
                                                   std::shared_ptr<torch::nn::Module> m) {
  if (!m) throw ScheduleError(where + ": module '" + path + "' is null");
  detail::check_dotted_path(where, "module", path);
  if (auto it = modules_.find(path); it != modules_.end()) {
    const auto& a = *it->second;
    const auto& b = *m;
    if (typeid(a) != typeid(b))
      throw ScheduleError(where + ": module '" + path + "' was made " + a.name() + ", not " +
                          b.name());
    return;  // shared by name: the first one stays
  }
  if (params_.count(path) || batch_norms_.count(path) || layer_norms_.count(path))
    throw ScheduleError(where + ": '" + path + "' is already a parameter or a normalisation");
  auto [owner, leaf] = owner_of(path);
  modules_.emplace(path, owner->register_module(leaf, std::move(m)));
}

TOPOS_INLINE void OperatorNetworkImpl::make_norm(const std::string& where, const TermOp& t,
                                                 std::int64_t channels) {
  const bool batch = t.kind == TermOp::Kind::batch_norm;
  auto same_width = [&](std::int64_t c) {
    if (c != channels)
      throw ScheduleError(where + ": normalisation '" + t.name + "' of " + std::to_string(c) +
                          " channels applied to " + std::to_string(channels));
  };
  if (batch && batch_norms_.count(t.name))
    return same_width(batch_norms_.at(t.name)->options.num_features());
  if (!batch && layer_norms_.count(t.name))
    return same_width(layer_norms_.at(t.name)->options.normalized_shape()[0]);
  if (params_.count(t.name + ".weight") || batch_norms_.count(t.name) || layer_norms_.count(t.name))
    throw ScheduleError(where + ": '" + t.name + "' is already another kind of module");
  auto [owner, leaf] = owner_of(t.name);
  if (batch)
    batch_norms_.emplace(t.name, owner->register_module(leaf, torch::nn::BatchNorm1d(channels)));
  else
    layer_norms_.emplace(t.name,
                         owner->register_module(
                             leaf, torch::nn::LayerNorm(torch::nn::LayerNormOptions({channels}))));
}
}  // namespace topos::nn

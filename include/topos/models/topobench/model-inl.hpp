// topos/models/topobench/model-inl.hpp
// The model's implementation (topos/models/topobench/model.hpp declares it), compiled once into
// topos::topobench (src/topobench.cpp), or inline with TOPOS_HEADER_ONLY (topos/config.hpp).
#pragma once

#include "topos/models/topobench/model.hpp"

#include <algorithm>

namespace topos::models::topobench {

TOPOS_INLINE Backbone::Backbone(std::string name, RankLayout layout, Build build)
    : name_(std::move(name)), layout_(std::move(layout)), build_(std::move(build)) {
  if (name_.empty() || name_.find_first_of(",\"\n") != std::string::npos)
    throw std::invalid_argument("topobench::Backbone: the name '" + name_ +
                                "' must be non-empty, without commas, quotes or newlines "
                                "(it is a field of runs.csv)");
  if (layout_.cell_dimensions < 1 || layout_.encoded_ranks.empty())
    throw std::invalid_argument(name_ +
                                ": a backbone needs cell_dimensions >= 1 and an "
                                "encoded rank");
  for (int r = 0; r < layout_.cell_dimensions; ++r)
    if (std::find(layout_.encoded_ranks.begin(), layout_.encoded_ranks.end(), r) ==
        layout_.encoded_ranks.end())
      throw std::invalid_argument(name_ + ": the wrapper adds the encoded x_" + std::to_string(r) +
                                  " to the backbone's, so encoded_ranks "
                                  "must hold every rank below cell_dimensions");
  if (!build_) throw std::invalid_argument(name_ + ": no build function");
}

TOPOS_INLINE Backbone
Backbone::network(std::string name, RankLayout layout,
                  std::function<nn::OperatorNetwork(const BackboneContext&)> make) {
  const std::string who = name;
  return Backbone(std::move(name), std::move(layout), [make, who](const BackboneContext& c) {
    BuiltBackbone b;
    b.network = make(c);
    b.module = b.network.ptr();
    b.forward = [net = b.network.ptr(), who](const NamedCochains& x, const NamedOperators& ops) {
      NamedCochains in;  // the encoded ranks the schedule reads
      for (const auto& port : net->schedule().inputs()) {
        auto it = x.find(port.name);
        if (it == x.end())
          throw std::invalid_argument(who + ": the backbone reads '" + port.name +
                                      "', which the encoder does not give (encoded_ranks)");
        in[port.name] = it->second;
      }
      return net->forward(in, net->declared_operators(ops));
    };
    return b;
  });
}

TOPOS_INLINE nn::OperatorSchedule head_schedule(const TopoBenchModelOptions& o) {
  using namespace nn::ops;
  const int dims = o.backbone().layout().cell_dimensions;
  const auto h = o.hidden();
  nn::OperatorSchedule s;
  for (int r = 0; r < dims; ++r) {
    const auto R = std::to_string(r);
    s.input("x_" + R, r, h).input("encoded_" + R, r, h, "encoded");
    s.step(into(r).sum(from(r), from(r, "encoded")).layer_norm("wrapper.ln_" + R));
  }
  if (o.propagate_signal_down())
    for (int i = dims - 1; i >= 1; --i) {
      const auto I = std::to_string(i), p = "readout.stage_" + I + ".";
      s.operator_input("incidence_" + I, i, i - 1);
      s.step(into(i - 1)
                 .concat(from(i).conv(p + "conv", h).via("incidence_" + I).layer_norm(p + "ln"),
                         from(i - 1))
                 .linear(p + "linear", h));
    }
  s.output("x_0", 0);
  return s;
}

TOPOS_INLINE TopoBenchModelImpl::TopoBenchModelImpl(TopoBenchModelOptions o)
    : options(std::move(o)) {
  const auto& layout = options.backbone().layout();
  if (options.hidden() < 1 || options.num_classes() < 2 || options.n_layers() < 1)
    throw std::invalid_argument(options.model() +
                                ": hidden and n_layers must be positive, classes at least 2");
  for (int r : layout.encoded_ranks) {
    if (r < 0 || static_cast<std::size_t>(r) >= options.in_channels().size())
      throw std::invalid_argument(options.model() + " encodes rank " + std::to_string(r) +
                                  " but the data has " +
                                  std::to_string(options.in_channels().size()) + " ranks");
    const auto R = std::to_string(r);
    const auto f = options.in_channels()[static_cast<std::size_t>(r)];
    norms_.push_back(register_module("encoder_norm_" + R, nn::GraphNorm(f)));
    linears_.push_back(
        register_module("encoder_linear_" + R, torch::nn::Linear(f, options.hidden())));
  }
  built_ = options.backbone().build(options.context());
  if (!built_.forward)
    throw std::invalid_argument(options.model() + ": the backbone's build gave no forward");
  if (built_.module) register_module("backbone", built_.module);
  backbone = built_.network;
  head = register_module("head", nn::OperatorNetwork(head_schedule(options)));
  classifier =
      register_module("classifier", torch::nn::Linear(options.hidden(), options.num_classes()));
}

TOPOS_INLINE torch::Tensor TopoBenchModelImpl::forward(const Batch& b) {
  const auto& layout = options.backbone().layout();
  NamedCochains encoded;
  for (std::size_t k = 0; k < layout.encoded_ranks.size(); ++k) {
    const auto r = static_cast<std::size_t>(layout.encoded_ranks[k]);
    if (r >= b.x.size())
      throw std::invalid_argument(options.model() + " encodes rank " + std::to_string(r) +
                                  " but the batch has " + std::to_string(b.x.size()) + " ranks");
    auto e = nn::graph_norm_linear(norms_[k], linears_[k], b.x.at(r), b.batch.at(r), b.num_graphs,
                                   nn::Epilogue::relu);
    if (options.dropout() > 0) e = nn::dropout(e, options.dropout(), is_training());
    encoded["x_" + std::to_string(r)] = e;
  }
  const auto out = built_.forward(encoded, backbone_operators(b));
  NamedCochains head_in;
  for (int r = 0; r < layout.cell_dimensions; ++r) {
    const auto R = std::to_string(r);
    const auto it = out.find("x_" + R);
    if (it == out.end())
      throw std::invalid_argument(options.model() + ": the backbone gave no x_" + R +
                                  " (its layout has cell_dimensions " +
                                  std::to_string(layout.cell_dimensions) + ")");
    head_in["x_" + R] = it->second;
    head_in["encoded_" + R] = encoded.at("x_" + R);
  }
  auto x0 = head->forward(head_in, head->declared_operators(b.operators)).at("x_0");
  if (options.graph_level()) x0 = nn::segment_sum(x0, b.batch.at(0), b.num_graphs);
  return classifier->forward(x0);
}

}  // namespace topos::models::topobench

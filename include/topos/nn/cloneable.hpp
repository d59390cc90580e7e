// topos/nn/cloneable.hpp
// Deep copies of models: `Cloneable<Derived, Base>` gives a module built from an options value
// torch's `clone()` (a fresh Derived from the same options, then every parameter and buffer copied
// by name) and a one-line `pretty_print()`. torch::nn::Cloneable needs a reset() that re-registers
// everything; topos's models create their parameters from a schedule in the constructor, so
// building a new one from the options is the same thing, written once here. Also a module's
// state kept aside and put back (StateSnapshot: early stopping's best check).
#pragma once

#include <torch/torch.h>

#include <memory>
#include <ostream>
#include <stdexcept>
#include <string>

namespace topos::nn {

namespace detail {
/// Copies each tensor of `src` into the same-named one of `dst` (same names and shapes).
inline void copy_named(const torch::OrderedDict<std::string, torch::Tensor>& src,
                       torch::OrderedDict<std::string, torch::Tensor> dst, const char* what,
                       const char* who) {
  torch::NoGradGuard no_grad;
  if (src.size() != dst.size())
    throw std::logic_error(std::string(who) + ": " + std::to_string(src.size()) + " " + what +
                           " in the source, " + std::to_string(dst.size()) + " in the copy");
  for (const auto& item : src) {
    auto* t = dst.find(item.key());
    if (t == nullptr || !t->sizes().equals(item.value().sizes()))
      throw std::logic_error(std::string(who) + ": " + what + " '" + item.key() +
                             "' is missing or has another shape in the copy");
    if (t->dtype() != item.value().dtype()) t->set_data(t->to(item.value().dtype()));
    t->copy_(item.value());
  }
}
}  // namespace detail

/// Copies every parameter and buffer of `from` into the same-named one of `to`; the two must
/// have the same names and shapes (a model built from the same options).
inline void copy_state(const torch::nn::Module& from, torch::nn::Module& to) {
  detail::copy_named(from.named_parameters(), to.named_parameters(), "parameters", "copy_state");
  detail::copy_named(from.named_buffers(), to.named_buffers(), "buffers", "copy_state");
}

/// A module's parameters and buffers at one moment, copied, to go back to later (early
/// stopping's best check). Buffers count as much as parameters: BatchNorm's running statistics
/// are what the module computes with in eval(), so a best check restored without them is tested
/// with the last epoch's statistics.
class StateSnapshot {
 public:
  StateSnapshot() = default;
  explicit StateSnapshot(const torch::nn::Module& m) {
    torch::NoGradGuard no_grad;
    for (const auto& p : m.named_parameters()) parameters_.insert(p.key(), p.value().clone());
    for (const auto& b : m.named_buffers()) buffers_.insert(b.key(), b.value().clone());
    taken_ = true;
  }
  bool empty() const { return !taken_; }
  /// Puts the snapshot's values back into `m` (the module it was taken of, or one like it).
  void restore(torch::nn::Module& m) const {
    if (!taken_) throw std::logic_error("StateSnapshot::restore: no snapshot was taken");
    detail::copy_named(parameters_, m.named_parameters(), "parameters", "StateSnapshot::restore");
    detail::copy_named(buffers_, m.named_buffers(), "buffers", "StateSnapshot::restore");
  }

 private:
  torch::OrderedDict<std::string, torch::Tensor> parameters_, buffers_;
  bool taken_ = false;
};

/// `Derived` must have an `options` member and a constructor from it.
template <class Derived, class Base = torch::nn::Module>
class Cloneable : public Base {
 public:
  using Base::Base;

  /// A deep copy: the same options, parameters, buffers and training mode, on `device` if given.
  std::shared_ptr<torch::nn::Module> clone(
      const c10::optional<torch::Device>& device = c10::nullopt) const override {
    const auto& self = static_cast<const Derived&>(*this);
    auto copy = std::make_shared<Derived>(self.options);
    copy_state(self, *copy);
    if (device) copy->to(*device);
    copy->train(this->is_training());
    return copy;
  }

  /// "SCN2(12 parameter tensors, 1,512 values)": the model and its size; children are printed
  /// by torch's operator<< as usual.
  void pretty_print(std::ostream& out) const override {
    std::string name = this->name();
    if (const auto colon = name.rfind("::"); colon != std::string::npos)
      name = name.substr(colon + 2);
    if (name.size() > 4 && name.compare(name.size() - 4, 4, "Impl") == 0)
      name.resize(name.size() - 4);
    std::int64_t values = 0;
    const auto params = this->parameters();
    for (const auto& p : params) values += p.numel();
    out << name << "(" << params.size() << " parameter tensors, " << values << " values)";
  }
};

}  // namespace topos::nn

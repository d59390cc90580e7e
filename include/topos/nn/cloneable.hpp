// topos/nn/cloneable.hpp
// Deep copies of models: `Cloneable<Derived, Base>` gives a module built from an options value
// torch's `clone()` (a fresh Derived from the same options, then every parameter and buffer copied
// by name) and a one-line `pretty_print()`. torch::nn::Cloneable needs a reset() that re-registers
// everything; topos's models create their parameters from a schedule in the constructor, so
// building a new one from the options is the same thing, written once here.
#pragma once

#include <torch/torch.h>

#include <memory>
#include <ostream>
#include <stdexcept>
#include <string>

namespace topos::nn {

/// Copies every parameter and buffer of `from` into the same-named one of `to`; the two must
/// have the same names and shapes (a model built from the same options).
inline void copy_state(const torch::nn::Module& from, torch::nn::Module& to) {
  torch::NoGradGuard no_grad;
  auto copy = [&](const torch::OrderedDict<std::string, torch::Tensor>& src,
                  torch::OrderedDict<std::string, torch::Tensor> dst, const char* what) {
    if (src.size() != dst.size())
      throw std::logic_error("copy_state: " + std::to_string(src.size()) + " " + what +
                             " in the source, " + std::to_string(dst.size()) + " in the copy");
    for (const auto& item : src) {
      auto* t = dst.find(item.key());
      if (t == nullptr || !t->sizes().equals(item.value().sizes()))
        throw std::logic_error("copy_state: " + std::string(what) + " '" + item.key() +
                               "' is missing or has another shape in the copy");
      if (t->dtype() != item.value().dtype()) t->set_data(t->to(item.value().dtype()));
      t->copy_(item.value());
    }
  };
  copy(from.named_parameters(), to.named_parameters(), "parameters");
  copy(from.named_buffers(), to.named_buffers(), "buffers");
}

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

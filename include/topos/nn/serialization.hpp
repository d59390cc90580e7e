// topos/nn/serialization.hpp
// Tensor files that both LibTorch and Python's torch.load read: torch.save's zip format
// written without TorchScript type tags (so torch.load's default weights_only=True accepts
// them), atomically; dicts of tensors by name, and parameters saved and loaded by name with
// errors that name the missing, extra or misshapen tensor. The implementation (and the strict
// reader of untrusted files) is serialization-inl.hpp, compiled into topos::nn.
#pragma once

#include "topos/config.hpp"

#include <torch/torch.h>

#include <cstddef>
#include <map>
#include <string>
#include <vector>

namespace topos::nn {

/// A value (tensors, dicts, lists, strings, numbers) in torch.save's zip format. Unlike
/// torch::pickle_save, containers carry no TorchScript type tags, so Python's torch.load opens
/// the file with its default weights_only=True (a tag is a global it refuses).
std::vector<char> torch_file_bytes(const c10::IValue& value);

/// Writes `value` (torch_file_bytes) to a temporary file first, then renames it, so an
/// interrupted save leaves the old file intact.
void write_torch_file(const c10::IValue& value, const std::string& path);

/// Writes a dict of tensors that Python's torch.load reads (write_torch_file).
void write_tensor_dict(const c10::Dict<std::string, torch::Tensor>& dict, const std::string& path);

/// Saves parameters (and buffers) by name (write_tensor_dict).
void save_parameters(const torch::nn::Module& m, const std::string& path);

/// Parses the bytes of a torch file holding a dict of tensors (save_parameters,
/// torch.save(state_dict)); `source` names it in errors. Untrusted input: the archive and the
/// pickle are checked first (detail::torch_zip_records, detail::check_pickle), storages are
/// the archive's members at their real sizes (whatever element count the pickle claims), and
/// every tensor must lie inside its storage, so a forged file is an error naming it, never a
/// read out of bounds or an allocation larger than the file.
std::map<std::string, torch::Tensor> parse_tensor_dict(const char* data, std::size_t size,
                                                       const std::string& source);

/// Reads a dict of tensors written by save_parameters or torch.save(state_dict)
/// (parse_tensor_dict).
std::map<std::string, torch::Tensor> read_tensor_dict(const std::string& path);

/// Adam's per-parameter state as a dict of tensors by parameter name ("<name>.exp_avg",
/// "<name>.exp_avg_sq", "<name>.max_exp_avg_sq" with amsgrad, "<name>.step" as an int64
/// scalar), in the module's parameter order. Unlike torch::save(optimizer), which writes the
/// state in the order of a hash map keyed by tensor addresses, the bytes are the same for the
/// same state in every process, and Python's torch.load opens them.
c10::Dict<std::string, torch::Tensor> adam_state_dict(torch::optim::Adam& opt,
                                                      const torch::nn::Module& m);

/// Restores what adam_state_dict saved into `opt` (whose parameters are m's); a tensor of the
/// wrong shape or a name that is no parameter of m is an error naming it.
void load_adam_state(torch::optim::Adam& opt, const torch::nn::Module& m,
                     const std::map<std::string, torch::Tensor>& dict, const std::string& source);

/// Loads parameters by name; a missing, extra or misshapen tensor is an error naming it.
void load_parameters(torch::nn::Module& m, const std::map<std::string, torch::Tensor>& dict,
                     const std::string& source);

}  // namespace topos::nn

#ifdef TOPOS_HEADER_ONLY
#include "topos/nn/serialization-inl.hpp"
#endif

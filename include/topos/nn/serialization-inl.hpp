// topos/nn/serialization-inl.hpp
// The implementation of serialization.hpp: compiled into topos::nn, or inline with
// TOPOS_HEADER_ONLY (topos/config.hpp).
//
// Tensor files that both LibTorch and Python's torch.load read: torch.save's zip format
// written without TorchScript type tags (so torch.load's default weights_only=True accepts
// them), atomically; dicts of tensors by name, and parameters saved and loaded by name with
// errors that name the missing, extra or misshapen tensor. A file read is checked first
// (serialization_check-inl.hpp).
#pragma once

#include "topos/io/atomic_file.hpp"
#include "topos/nn/serialization.hpp"
#include "topos/nn/serialization_check-inl.hpp"
#include "topos/util/read_file.hpp"

#include <caffe2/serialize/inline_container.h>
#include <torch/csrc/jit/serialization/export.h>
#include <torch/csrc/jit/serialization/pickler.h>
#include <torch/csrc/jit/serialization/storage_context.h>
#include <torch/csrc/jit/serialization/unpickler.h>
#include <torch/torch.h>

#include <algorithm>
#include <cstring>
#include <memory>
#include <map>
#include <sstream>
#include <string>
#include <vector>

namespace topos::nn {

/// A value (tensors, dicts, lists, strings, numbers) in torch.save's zip format. Unlike
/// torch::pickle_save, containers carry no TorchScript type tags, so Python's torch.load opens
/// the file with its default weights_only=True (a tag is a global it refuses).
TOPOS_INLINE std::vector<char> torch_file_bytes(const c10::IValue& value) {
  std::vector<char> pickle;
  torch::jit::Pickler pickler(
      [&](const char* b, std::size_t n) { pickle.insert(pickle.end(), b, b + n); }, nullptr,
      nullptr, nullptr, nullptr,
      /*tag_aggregates=*/false);
  pickler.protocol();
  pickler.pushIValue(value);
  pickler.stop();
  std::vector<char> out;
  caffe2::serialize::PyTorchStreamWriter writer([&](const void* b, std::size_t n) {
    out.insert(out.end(), static_cast<const char*>(b), static_cast<const char*>(b) + n);
    return n;
  });
  torch::jit::writeArchiveAndTensors("data", pickle.data(), pickle.size(), pickler.tensorData(),
                                     writer);
  writer.writeEndOfFile();
  return out;
}

/// Writes `value` (torch_file_bytes) to a temporary file first, then renames it, so an
/// interrupted save leaves the old file intact.
TOPOS_INLINE void write_torch_file(const c10::IValue& value, const std::string& path) {
  const auto bytes = torch_file_bytes(value);
  io::write_file_atomic(path, bytes.data(), bytes.size());
}

/// Writes a dict of tensors that Python's torch.load reads (write_torch_file).
TOPOS_INLINE void write_tensor_dict(const c10::Dict<std::string, torch::Tensor>& dict,
                                    const std::string& path) {
  write_torch_file(c10::IValue(dict), path);
}

/// Saves parameters (and buffers) by name (write_tensor_dict).
TOPOS_INLINE void save_parameters(const torch::nn::Module& m, const std::string& path) {
  c10::Dict<std::string, torch::Tensor> dict;
  for (const auto& p : m.named_parameters()) dict.insert(p.key(), p.value().detach().cpu());
  for (const auto& b : m.named_buffers()) dict.insert(b.key(), b.value().detach().cpu());
  write_tensor_dict(dict, path);
}

namespace detail {

/// The folder of the archive's one `<folder>/data.pkl` (torch.save names it after the file).
inline std::string torch_archive_prefix(const std::map<std::string, ZipRecord>& records,
                                        const std::string& source) {
  std::string prefix;
  for (const auto& [name, r] : records) {
    const auto slash = name.find('/');
    if (slash != std::string::npos && name.compare(slash, std::string::npos, "/data.pkl") == 0) {
      if (!prefix.empty())
        throw std::runtime_error(source + ": not a readable torch file: two data.pkl members");
      prefix = name.substr(0, slash + 1);
    }
  }
  if (prefix.empty())
    throw std::runtime_error(source +
                             ": not a readable torch file: no data.pkl (not a torch.save file)");
  return prefix;
}

/// LibTorch's unpickler over `pickle` (checked and rewritten), its storages the members under
/// `<prefix>data/`, each copied out at its real size; no types, objects or other storages.
inline c10::IValue unpickle_torch_file(const char* data,
                                       const std::map<std::string, ZipRecord>& records,
                                       const std::string& prefix, const std::string& pickle,
                                       const std::string& source) {
  auto storages = std::make_shared<torch::jit::DeserializationStorageContext>();
  for (const auto& [name, r] : records) {
    if (name.compare(0, prefix.size() + 5, prefix + "data/") != 0) continue;
    at::DataPtr ptr = at::getCPUAllocator()->allocate(r.size);
    if (r.size) std::memcpy(ptr.get(), data + r.offset, r.size);
    storages->addStorage(
        name.substr(prefix.size() + 5),
        c10::Storage(c10::Storage::use_byte_size_t(), r.size, std::move(ptr), nullptr, false));
  }
  std::size_t pos = 0;
  const auto reader = [&](char* out, std::size_t n) {
    const std::size_t k = std::min(n, pickle.size() - pos);
    std::memcpy(out, pickle.data() + pos, k);
    pos += k;
    return k;
  };
  try {
    torch::jit::Unpickler unpickler(
        reader,
        [](const c10::QualifiedName& q) -> c10::StrongTypePtr {
          throw std::runtime_error("unsupported type " + q.qualifiedName());
        },
        [](const at::StrongTypePtr&,
           const c10::IValue&) -> c10::intrusive_ptr<c10::ivalue::Object> {
          throw std::runtime_error("objects are not supported");
        },
        [](const std::string& key) -> at::DataPtr {
          throw std::runtime_error("no storage member data/" + key);
        },
        c10::Device(c10::kCPU), false, torch::jit::Unpickler::defaultTypeParser, storages);
    return unpickler.parse_ivalue();
  } catch (const c10::Error& e) {
    throw std::runtime_error(source + ": not a readable torch file: " + e.what_without_backtrace());
  } catch (const std::exception& e) {
    throw std::runtime_error(source + ": not a readable torch file: " + e.what());
  }
}

/// Refuses a tensor whose elements do not all lie inside its storage (the pickle sets sizes,
/// strides and offsets freely), or that is not a dense CPU tensor.
inline void check_tensor_in_storage(const std::string& name, const torch::Tensor& t,
                                    const std::string& source) {
  const auto fail = [&](const std::string& why) -> void {
    throw std::runtime_error(source + ": tensor '" + name + "' " + why);
  };
  if (!t.defined() || t.layout() != torch::kStrided || !t.device().is_cpu() || !t.has_storage())
    fail("is not a dense CPU tensor");
  if (t.dim() > 64) fail("has more than 64 dimensions");
  __extension__ typedef unsigned __int128 u128;  // sizes × strides cannot overflow it
  u128 last = 0;
  bool empty = false;
  for (int64_t d = 0; d < t.dim(); ++d) {
    if (t.size(d) < 0 || t.stride(d) < 0) fail("has a negative size or stride");
    if (t.size(d) == 0)
      empty = true;
    else
      last += static_cast<u128>(t.size(d) - 1) * static_cast<u128>(t.stride(d));
  }
  if (t.storage_offset() < 0) fail("has a negative storage offset");
  if (!empty) {
    const u128 end =
        (last + 1 + static_cast<u128>(t.storage_offset())) * static_cast<u128>(t.element_size());
    if (end > t.storage().nbytes()) fail("extends past its storage");
  }
}

}  // namespace detail

/// Parses the bytes of a torch file holding a dict of tensors (save_parameters,
/// torch.save(state_dict)); `source` names it in errors. Untrusted input: the archive and the
/// pickle are checked first (detail::torch_zip_records, detail::check_pickle), storages are
/// the archive's members at their real sizes (whatever element count the pickle claims), and
/// every tensor must lie inside its storage, so a forged file is an error naming it, never a
/// read out of bounds or an allocation larger than the file.
TOPOS_INLINE std::map<std::string, torch::Tensor> parse_tensor_dict(const char* data,
                                                                    std::size_t size,
                                                                    const std::string& source) {
  const auto records = detail::torch_zip_records(data, size, source);
  const std::string prefix = detail::torch_archive_prefix(records, source);
  const detail::ZipRecord pkl = records.at(prefix + "data.pkl");
  detail::check_pickle(data + pkl.offset, pkl.size, source);
  const std::string pickle = detail::pickle_for_libtorch(data + pkl.offset, pkl.size, source);
  const c10::IValue v = detail::unpickle_torch_file(data, records, prefix, pickle, source);
  if (!v.isGenericDict()) throw std::runtime_error(source + ": does not hold a dict of tensors");
  std::map<std::string, torch::Tensor> out;
  for (const auto& kv : v.toGenericDict()) {
    if (!kv.key().isString() || !kv.value().isTensor())
      throw std::runtime_error(source + ": an entry is not a (name, tensor) pair");
    const std::string& name = kv.key().toStringRef();
    const torch::Tensor t = kv.value().toTensor();
    detail::check_tensor_in_storage(name, t, source);
    out[name] = t;
  }
  return out;
}

/// Reads a dict of tensors written by save_parameters or torch.save(state_dict)
/// (parse_tensor_dict).
TOPOS_INLINE std::map<std::string, torch::Tensor> read_tensor_dict(const std::string& path) {
  std::string bytes;
  if (!read_file(path, bytes)) throw std::runtime_error(path + ": cannot open file");
  return parse_tensor_dict(bytes.data(), bytes.size(), path);
}

/// Adam's per-parameter state as a dict of tensors by parameter name ("<name>.exp_avg",
/// "<name>.exp_avg_sq", "<name>.max_exp_avg_sq" with amsgrad, "<name>.step" as an int64
/// scalar), in the module's parameter order. Unlike torch::save(optimizer), which writes the
/// state in the order of a hash map keyed by tensor addresses, the bytes are the same for the
/// same state in every process, and Python's torch.load opens them.
TOPOS_INLINE c10::Dict<std::string, torch::Tensor> adam_state_dict(torch::optim::Adam& opt,
                                                                   const torch::nn::Module& m) {
  c10::Dict<std::string, torch::Tensor> dict;
  auto& state = opt.state();
  for (const auto& p : m.named_parameters()) {
    const auto it = state.find(c10::guts::to_string(p.value().unsafeGetTensorImpl()));
    if (it == state.end()) continue;  // never stepped (no gradient yet)
    const auto& st = static_cast<const torch::optim::AdamParamState&>(*it->second);
    dict.insert(p.key() + ".step", torch::tensor(st.step(), torch::kInt64));
    dict.insert(p.key() + ".exp_avg", st.exp_avg().detach().cpu());
    dict.insert(p.key() + ".exp_avg_sq", st.exp_avg_sq().detach().cpu());
    if (st.max_exp_avg_sq().defined())
      dict.insert(p.key() + ".max_exp_avg_sq", st.max_exp_avg_sq().detach().cpu());
  }
  return dict;
}

/// Restores what adam_state_dict saved into `opt` (whose parameters are m's); a tensor of the
/// wrong shape or a name that is no parameter of m is an error naming it.
TOPOS_INLINE void load_adam_state(torch::optim::Adam& opt, const torch::nn::Module& m,
                                  const std::map<std::string, torch::Tensor>& dict,
                                  const std::string& source) {
  auto& state = opt.state();
  state.clear();
  std::size_t used = 0;
  for (const auto& p : m.named_parameters()) {
    const auto step = dict.find(p.key() + ".step");
    if (step == dict.end()) continue;
    auto st = std::make_unique<torch::optim::AdamParamState>();
    st->step(step->second.item<std::int64_t>());
    const auto moment = [&](const char* what, bool required) -> torch::Tensor {
      const auto it = dict.find(p.key() + what);
      if (it == dict.end()) {
        if (required)
          throw std::runtime_error(source + ": missing tensor '" + p.key() + what + "'");
        return {};
      }
      if (it->second.sizes() != p.value().sizes())
        throw std::runtime_error(source + ": tensor '" + p.key() + what +
                                 "' does not have its parameter's shape");
      ++used;
      return it->second.to(p.value().options()).clone();
    };
    st->exp_avg(moment(".exp_avg", true));
    st->exp_avg_sq(moment(".exp_avg_sq", true));
    st->max_exp_avg_sq(moment(".max_exp_avg_sq", false));
    ++used;
    state[c10::guts::to_string(p.value().unsafeGetTensorImpl())] = std::move(st);
  }
  if (used != dict.size())
    for (const auto& [k, v] : dict) {
      const auto dot = k.rfind('.');
      bool known = false;
      for (const auto& p : m.named_parameters()) known = known || k.compare(0, dot, p.key()) == 0;
      if (!known)
        throw std::runtime_error(source + ": '" + k +
                                 "' is the optimizer state of no parameter of this model");
    }
}

/// Loads parameters by name; a missing, extra or misshapen tensor is an error naming it.
TOPOS_INLINE void load_parameters(torch::nn::Module& m,
                                  const std::map<std::string, torch::Tensor>& dict,
                                  const std::string& source) {
  torch::NoGradGuard guard;
  std::size_t used = 0;
  auto assign = [&](const std::string& name, torch::Tensor& target) {
    auto it = dict.find(name);
    if (it == dict.end()) throw std::runtime_error(source + ": missing tensor '" + name + "'");
    if (it->second.sizes() != target.sizes()) {
      std::ostringstream s;
      s << source << ": tensor '" << name << "' has shape " << it->second.sizes() << ", expected "
        << target.sizes();
      throw std::runtime_error(s.str());
    }
    target.copy_(it->second);
    ++used;
  };
  for (auto& p : m.named_parameters()) assign(p.key(), p.value());
  for (auto& b : m.named_buffers()) assign(b.key(), b.value());
  if (used != dict.size()) {
    for (const auto& [k, v] : dict) {
      if (!m.named_parameters().contains(k) && !m.named_buffers().contains(k))
        throw std::runtime_error(source + ": unexpected tensor '" + k + "'");
    }
  }
}

}  // namespace topos::nn

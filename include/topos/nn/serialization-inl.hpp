// topos/nn/serialization-inl.hpp
// The implementation of serialization.hpp: compiled into topos::nn, or inline with
// TOPOS_HEADER_ONLY (topos/config.hpp).
//
// Tensor files that both LibTorch and Python's torch.load read: torch.save's zip format
// written without TorchScript type tags (so torch.load's default weights_only=True accepts
// them), atomically; dicts of tensors by name, and parameters saved and loaded by name with
// errors that name the missing, extra or misshapen tensor.
#pragma once

#include "topos/io/atomic_file.hpp"
#include "topos/nn/serialization.hpp"

#include <caffe2/serialize/inline_container.h>
#include <torch/csrc/jit/serialization/export.h>
#include <torch/csrc/jit/serialization/pickler.h>
#include <torch/csrc/jit/serialization/storage_context.h>
#include <torch/csrc/jit/serialization/unpickler.h>
#include <torch/torch.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <fstream>
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
  write_file_atomic(path, bytes.data(), bytes.size());
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

/// One stored (uncompressed) member of a zip archive: its bytes within the file.
struct ZipRecord {
  std::size_t offset = 0, size = 0;
};

inline std::uint32_t le32(const char* p) {
  std::uint32_t v = 0;
  for (int i = 3; i >= 0; --i) v = (v << 8) | static_cast<unsigned char>(p[i]);
  return v;
}
inline std::uint16_t le16(const char* p) {
  return static_cast<std::uint16_t>(static_cast<unsigned char>(p[0]) |
                                    (static_cast<unsigned char>(p[1]) << 8));
}

/// The members of a torch.save zip archive, checked before anything is read from them: every
/// member stored uncompressed (as torch.save writes them) and lying inside the file, so no read
/// can allocate more than the file holds (a zip bomb or a forged size is an error, not an
/// out-of-memory kill).
inline std::map<std::string, ZipRecord> torch_zip_records(const char* data, std::size_t size,
                                                          const std::string& source) {
  const auto fail = [&](const std::string& why) -> void {
    throw std::runtime_error(source + ": not a readable torch file: " + why);
  };
  if (size < 22) fail("too short for a zip archive");
  // The end-of-central-directory record: the last signature within 64 KiB + 22 bytes of the end.
  std::size_t eocd = std::string::npos;
  for (std::size_t i = size - 22 + 1; i-- > 0 && size - i <= 65557;) {
    if (le32(data + i) == 0x06054b50u) {
      eocd = i;
      break;
    }
  }
  if (eocd == std::string::npos) fail("no zip end-of-central-directory record");
  const std::size_t entries = le16(data + eocd + 10), cd_size = le32(data + eocd + 12),
                    cd_offset = le32(data + eocd + 16);
  if (cd_offset > eocd || cd_size > eocd - cd_offset) fail("central directory outside the file");
  std::map<std::string, ZipRecord> out;
  std::size_t p = cd_offset;
  for (std::size_t e = 0; e < entries; ++e) {
    if (eocd - p < 46 || le32(data + p) != 0x02014b50u) fail("malformed central directory");
    const std::uint16_t method = le16(data + p + 10);
    const std::uint32_t csize = le32(data + p + 20), usize = le32(data + p + 24);
    const std::size_t name_len = le16(data + p + 28), extra_len = le16(data + p + 30),
                      comment_len = le16(data + p + 32);
    const std::size_t local = le32(data + p + 42);
    if (eocd - p - 46 < name_len + extra_len + comment_len) fail("malformed central directory");
    const std::string name(data + p + 46, name_len);
    if (method != 0 || csize != usize)
      fail("member '" + name + "' is compressed (torch.save stores members uncompressed)");
    if (csize == 0xFFFFFFFFu || local == 0xFFFFFFFFu) fail("zip64 archives are not supported");
    if (local > cd_offset || cd_offset - local < 30 || le32(data + local) != 0x04034b50u)
      fail("member '" + name + "' has no local header");
    const std::size_t begin = local + 30 + le16(data + local + 26) + le16(data + local + 28);
    if (begin > cd_offset || cd_offset - begin < csize)
      fail("member '" + name + "' extends past its archive");
    if (!out.emplace(name, ZipRecord{begin, csize}).second)
      fail("member '" + name + "' appears twice");
    p += 46 + name_len + extra_len + comment_len;
  }
  return out;
}

/// One opcode of the protocol-2 subset torch files use, decoded: its length with its argument
/// and its effect on the unpickler's stack (pop to the top mark first when `to_mark`, then pop
/// `pops` items, then push `pushes`).
struct PickleOp {
  unsigned char code = 0;
  std::size_t length = 0;
  bool to_mark = false;
  std::size_t pops = 0, pushes = 0;
};

/// Decodes the opcode at `p` (< n) of the pickle `d` of `n` bytes from the one opcode table
/// behind both walks below. `fail` (which throws) gets why when the argument runs past the
/// end, a GLOBAL line is unterminated within 256 bytes, an integer is wider than 64 bits or the
/// opcode is outside the subset.
template <class Fail>
PickleOp decode_pickle_op(const char* d, std::size_t n, std::size_t p, const Fail& fail) {
  // arg: the argument's bytes, or how it is sized: kLen1/kLen4 a 1- or 4-byte length prefix
  // (LONG1's at most 8), kLines GLOBAL's two lines.
  enum : int { kLen1 = -1, kLen4 = -4, kLines = -2 };
  struct Row {
    unsigned char code;
    int arg;
    bool to_mark;
    unsigned char pops, pushes;
  };
  static constexpr Row kTable[] = {
      {0x80, 1, false, 0, 0},      // PROTO
      {0x95, 8, false, 0, 0},      // FRAME
      {'.', 0, false, 0, 0},       // STOP
      {'(', 0, false, 0, 0},       // MARK
      {'q', 1, false, 0, 0},       // BINPUT
      {'r', 4, false, 0, 0},       // LONG_BINPUT
      {0x94, 0, false, 0, 0},      // MEMOIZE
      {'0', 0, false, 1, 0},       // POP
      {'1', 0, true, 0, 0},        // POP_MARK
      {'N', 0, false, 0, 1},       // NONE
      {0x88, 0, false, 0, 1},      // NEWTRUE
      {0x89, 0, false, 0, 1},      // NEWFALSE
      {')', 0, false, 0, 1},       // EMPTY_TUPLE
      {']', 0, false, 0, 1},       // EMPTY_LIST
      {'}', 0, false, 0, 1},       // EMPTY_DICT
      {'K', 1, false, 0, 1},       // BININT1
      {'M', 2, false, 0, 1},       // BININT2
      {'J', 4, false, 0, 1},       // BININT
      {'G', 8, false, 0, 1},       // BINFLOAT
      {0x8a, kLen1, false, 0, 1},  // LONG1
      {0x8c, kLen1, false, 0, 1},  // SHORT_BINUNICODE
      {'U', kLen1, false, 0, 1},   // SHORT_BINSTRING
      {'C', kLen1, false, 0, 1},   // SHORT_BINBYTES
      {'X', kLen4, false, 0, 1},   // BINUNICODE
      {'B', kLen4, false, 0, 1},   // BINBYTES
      {'c', kLines, false, 0, 1},  // GLOBAL
      {'h', 1, false, 0, 1},       // BINGET
      {'j', 4, false, 0, 1},       // LONG_BINGET
      {'t', 0, true, 0, 1},        // TUPLE
      {'l', 0, true, 0, 1},        // LIST
      {'d', 0, true, 0, 1},        // DICT
      {'e', 0, true, 1, 1},        // APPENDS
      {'u', 0, true, 1, 1},        // SETITEMS
      {0x85, 0, false, 1, 1},      // TUPLE1
      {0x86, 0, false, 2, 1},      // TUPLE2
      {0x87, 0, false, 3, 1},      // TUPLE3
      {'a', 0, false, 2, 1},       // APPEND
      {'s', 0, false, 3, 1},       // SETITEM
      {'R', 0, false, 2, 1},       // REDUCE
      {0x81, 0, false, 2, 1},      // NEWOBJ
      {'b', 0, false, 2, 1},       // BUILD
      {'Q', 0, false, 1, 1},       // BINPERSID
  };
  const unsigned char code = static_cast<unsigned char>(d[p]);
  const Row* row = std::find_if(std::begin(kTable), std::end(kTable),
                                [&](const Row& r) { return r.code == code; });
  if (row == std::end(kTable)) {
    char hex[8];
    std::snprintf(hex, sizeof hex, "0x%02x", code);
    fail(std::string("unsupported pickle opcode ") + hex);
  }
  const std::size_t left = n - p - 1;  // bytes after the opcode
  const auto need = [&](std::size_t k) {
    if (left < k) fail("pickle truncated");
  };
  std::size_t arg = 0;
  if (row->arg >= 0) {
    arg = static_cast<std::size_t>(row->arg);
  } else if (row->arg == kLen1) {
    need(1);
    arg = 1 + static_cast<unsigned char>(d[p + 1]);
    if (code == 0x8a && arg > 9) fail("pickle integer wider than 64 bits");
  } else if (row->arg == kLen4) {
    need(4);
    arg = std::size_t{4} + le32(d + p + 1);
  } else {  // GLOBAL: module and name, each on its own line
    for (int line = 0; line < 2; ++line) {
      const auto* nl = static_cast<const char*>(
          std::memchr(d + p + 1 + arg, '\n', std::min<std::size_t>(left - arg, 256)));
      if (!nl) fail("pickle GLOBAL name unterminated or too long");
      arg = static_cast<std::size_t>(nl - (d + p));
    }
  }
  need(arg);
  return PickleOp{code, 1 + arg, row->to_mark, row->pops, row->pushes};
}

/// Walks a pickle before LibTorch's unpickler sees it, refusing what that unpickler trusts:
/// opcodes outside the protocol-2 subset torch files use, lengths past the end, memo indices
/// no pickle writer produces (the unpickler reserves memory by them), and stack or mark
/// underflow (the unpickler does not check them). `n` is the pickle's size.
inline void check_pickle(const char* d, std::size_t n, const std::string& source) {
  const auto fail = [&](const std::string& why) -> void {
    throw std::runtime_error(source + ": not a readable torch file: " + why);
  };
  std::size_t p = 0, depth = 0, memo = 0;
  std::vector<std::size_t> marks;
  while (true) {
    if (p >= n) fail("pickle truncated");
    const PickleOp op = decode_pickle_op(d, n, p, fail);
    const char* arg = d + p + 1;
    p += op.length;
    if (op.code == '.') {
      if (depth != 1 || !marks.empty()) fail("pickle stops with a malformed stack");
      return;
    }
    if (op.code == '(') marks.push_back(depth);
    if (op.code == 'q' || op.code == 'r' || op.code == 0x94) {  // a memo entry for the top item
      const std::size_t index = op.code == 'q'   ? static_cast<unsigned char>(arg[0])
                                : op.code == 'r' ? le32(arg)
                                                 : memo;
      if (depth == 0) fail("pickle memoizes an empty stack");
      if (index > memo) fail("pickle memo index " + std::to_string(index) + " out of sequence");
      if (index == memo) ++memo;
    }
    if (op.code == 'h' || op.code == 'j') {
      const std::size_t index = op.code == 'h' ? static_cast<unsigned char>(arg[0]) : le32(arg);
      if (index >= memo)
        fail("pickle reads memo entry " + std::to_string(index) + ", which it has not set");
    }
    if (op.to_mark) {
      if (marks.empty()) fail("pickle pops to a mark it has not set");
      const std::size_t items = depth - marks.back();
      depth = marks.back();
      marks.pop_back();
      if (op.code == 'd' && items % 2) fail("pickle dict with an odd number of items");
      if (op.code == 'u' && items % 2) fail("pickle SETITEMS with an odd number of items");
    }
    if (depth < op.pops || (!marks.empty() && depth - op.pops < marks.back()))
      fail("pickle pops more than its stack holds");
    depth = depth - op.pops + op.pushes;
  }
}

/// Python's torch.save(model.state_dict()) writes what LibTorch 1.13's unpickler cannot read:
/// collections.OrderedDicts (the dict itself, each tensor's empty backward hooks, the
/// `_metadata` attribute set by a final BUILD), which it turns into None, and SETITEM (one pair;
/// Python's pickler writes it for a batch of one), which it does not know. The same pickle with
/// each `OrderedDict()` as a plain empty dict, each SETITEM as MARK ... SETITEMS, and the final
/// BUILD dropped with its state (the metadata holds only module versions; LibTorch has no POP).
/// Tracks where each stack item's opcodes begin in the output, to put the MARK before a
/// SETITEM's key. The input passed check_pickle; `source` names it in errors.
inline std::string pickle_for_libtorch(const char* d, std::size_t n, const std::string& source) {
  static const std::string kOrderedDict = "collections\nOrderedDict\n";
  std::string out;
  out.reserve(n + 64);
  std::vector<std::uint32_t> class_memo;  // memo entries holding the OrderedDict class
  std::vector<std::size_t> starts;        // per stack item: its first byte in `out`
  std::vector<std::pair<std::size_t, std::size_t>> marks;  // (stack depth, position in `out`)
  // check_pickle accepted the input, but this walk rewrites it: its stacks are checked again
  // rather than trusted (a fuzzed pickle once popped a mark this walk had not set).
  const auto fail = [&](const std::string& why) -> void {
    throw std::runtime_error(source + ": not a readable torch file: " + why);
  };
  const auto broken = [&]() { fail("malformed pickle stack"); };
  const auto pop_items = [&](std::size_t k) {
    if (starts.size() < k || (!marks.empty() && starts.size() - k < marks.back().first)) broken();
    starts.resize(starts.size() - k);
  };
  const auto pop_to_mark = [&]() {
    if (marks.empty() || starts.size() < marks.back().first) broken();
    const auto m = marks.back();
    marks.pop_back();
    starts.resize(m.first);
    return m.second;
  };
  std::size_t p = 0;
  while (p < n) {
    const PickleOp op = decode_pickle_op(d, n, p, fail);
    const std::size_t at = out.size();
    std::size_t q = p + op.length;
    bool ordered_dict = op.code == 'c' && std::string(d + p + 1, op.length - 1) == kOrderedDict;
    if (op.code == 'h' || op.code == 'j') {
      const std::uint32_t i =
          op.code == 'h' ? static_cast<unsigned char>(d[p + 1]) : le32(d + p + 1);
      ordered_dict = std::find(class_memo.begin(), class_memo.end(), i) != class_memo.end();
    }
    if (ordered_dict) {
      if (q < n && (d[q] == 'q' || d[q] == 'r')) {  // the class memoized: later BINGETs of it
        const std::size_t length = decode_pickle_op(d, n, q, fail).length;
        class_memo.push_back(d[q] == 'q' ? static_cast<unsigned char>(d[q + 1]) : le32(d + q + 1));
        q += length;
      }
      if (q + 1 >= n || d[q] != ')' || d[q + 1] != 'R')
        fail("an OrderedDict made other than from an empty tuple");
      out += '}';
      starts.push_back(at);
      p = q + 2;
      continue;
    }
    if (op.code == 'b' && q < n && d[q] == '.') {  // BUILD just before STOP: drop its state
      if (starts.empty()) broken();
      out.resize(starts.back());
      starts.pop_back();
      p = q;
      continue;
    }
    if (op.code == 's') {  // SETITEM: MARK before the key, SETITEMS
      if (starts.size() < 2) broken();
      out.insert(starts[starts.size() - 2], 1, '(');
      out += 'u';
      starts.resize(starts.size() - 2);
      p = q;
      continue;
    }
    out.append(d + p, op.length);
    p = q;
    if (op.code == '.') break;
    if (op.code == '(') marks.emplace_back(starts.size(), at);
    // The item an opcode pushes begins where the earliest thing it consumed began: the deepest
    // item it pops, else its mark, else the opcode itself.
    std::size_t first = at;
    if (op.to_mark) first = pop_to_mark();
    if (op.pops) {
      if (starts.size() < op.pops) broken();
      first = starts[starts.size() - op.pops];
      pop_items(op.pops);
    }
    if (op.pushes) starts.push_back(first);
  }
  return out;
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
  const auto fail = [&](const std::string& why) -> void {
    throw std::runtime_error(source + ": " + why);
  };
  const auto records = detail::torch_zip_records(data, size, source);
  std::string prefix;
  for (const auto& [name, r] : records) {
    const auto slash = name.find('/');
    if (slash != std::string::npos && name.compare(slash, std::string::npos, "/data.pkl") == 0) {
      if (!prefix.empty()) fail("not a readable torch file: two data.pkl members");
      prefix = name.substr(0, slash + 1);
    }
  }
  if (prefix.empty()) fail("not a readable torch file: no data.pkl (not a torch.save file)");
  const detail::ZipRecord pkl = records.at(prefix + "data.pkl");
  detail::check_pickle(data + pkl.offset, pkl.size, source);
  const std::string pickle = detail::pickle_for_libtorch(data + pkl.offset, pkl.size, source);

  // Storages: every member under data/, copied out at its real size.
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
  c10::IValue v;
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
    v = unpickler.parse_ivalue();
  } catch (const c10::Error& e) {
    fail(std::string("not a readable torch file: ") + e.what_without_backtrace());
  } catch (const std::exception& e) {
    fail(std::string("not a readable torch file: ") + e.what());
  }
  if (!v.isGenericDict()) fail("does not hold a dict of tensors");
  std::map<std::string, torch::Tensor> out;
  for (const auto& kv : v.toGenericDict()) {
    if (!kv.key().isString() || !kv.value().isTensor())
      fail("an entry is not a (name, tensor) pair");
    const std::string& name = kv.key().toStringRef();
    const torch::Tensor t = kv.value().toTensor();
    // The tensor's elements must lie inside its storage (the pickle sets sizes and strides freely).
    if (!t.defined() || t.layout() != torch::kStrided || !t.device().is_cpu() || !t.has_storage())
      fail("tensor '" + name + "' is not a dense CPU tensor");
    if (t.dim() > 64) fail("tensor '" + name + "' has more than 64 dimensions");
    __extension__ typedef unsigned __int128 u128;  // sizes × strides cannot overflow it
    u128 last = 0;
    bool empty = false;
    for (int64_t d = 0; d < t.dim(); ++d) {
      if (t.size(d) < 0 || t.stride(d) < 0)
        fail("tensor '" + name + "' has a negative size or stride");
      if (t.size(d) == 0)
        empty = true;
      else
        last += static_cast<u128>(t.size(d) - 1) * static_cast<u128>(t.stride(d));
    }
    if (t.storage_offset() < 0) fail("tensor '" + name + "' has a negative storage offset");
    if (!empty) {
      const u128 end =
          (last + 1 + static_cast<u128>(t.storage_offset())) * static_cast<u128>(t.element_size());
      if (end > t.storage().nbytes()) fail("tensor '" + name + "' extends past its storage");
    }
    out[name] = t;
  }
  return out;
}

/// Reads a dict of tensors written by save_parameters or torch.save(state_dict)
/// (parse_tensor_dict).
TOPOS_INLINE std::map<std::string, torch::Tensor> read_tensor_dict(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(path + ": cannot open file");
  const std::vector<char> bytes((std::istreambuf_iterator<char>(in)),
                                std::istreambuf_iterator<char>());
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

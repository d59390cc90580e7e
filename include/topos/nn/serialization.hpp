// topos/nn/serialization.hpp
// Tensor files that both LibTorch and Python's torch.load read: torch.save's zip format
// written without TorchScript type tags (so torch.load's default weights_only=True accepts
// them), atomically; dicts of tensors by name, and parameters saved and loaded by name with
// errors that name the missing, extra or misshapen tensor.
#pragma once

#include "topos/io/atomic_file.hpp"

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
inline std::vector<char> torch_file_bytes(const c10::IValue& value) {
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
inline void write_torch_file(const c10::IValue& value, const std::string& path) {
  const auto bytes = torch_file_bytes(value);
  write_file_atomic(path, bytes.data(), bytes.size());
}

/// Writes a dict of tensors that Python's torch.load reads (write_torch_file).
inline void write_tensor_dict(const c10::Dict<std::string, torch::Tensor>& dict,
                              const std::string& path) {
  write_torch_file(c10::IValue(dict), path);
}

/// Saves parameters (and buffers) by name (write_tensor_dict).
inline void save_parameters(const torch::nn::Module& m, const std::string& path) {
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
  const auto need = [&](std::size_t k) {
    if (n - p < k) fail("pickle truncated");
  };
  const auto pop = [&](std::size_t k) {  // k items off the stack, never below the top mark
    if (depth < k || (!marks.empty() && depth - k < marks.back()))
      fail("pickle pops more than its stack holds");
    depth -= k;
  };
  const auto pop_mark = [&]() -> std::size_t {
    if (marks.empty()) fail("pickle pops to a mark it has not set");
    const std::size_t items = depth - marks.back();
    depth = marks.back();
    marks.pop_back();
    return items;
  };
  const auto put = [&](std::size_t index) {
    if (depth == 0) fail("pickle memoizes an empty stack");
    if (index > memo) fail("pickle memo index " + std::to_string(index) + " out of sequence");
    if (index == memo) ++memo;
  };
  const auto get = [&](std::size_t index) {
    if (index >= memo)
      fail("pickle reads memo entry " + std::to_string(index) + ", which it has not set");
    ++depth;
  };
  while (true) {
    need(1);
    const unsigned char op = static_cast<unsigned char>(d[p++]);
    switch (op) {
      case 0x80:
        need(1), ++p;
        break;  // PROTO
      case '.':
        if (depth != 1 || !marks.empty()) fail("pickle stops with a malformed stack");
        return;  // STOP
      case '(':
        marks.push_back(depth);
        break;  // MARK
      case '0':
        pop(1);
        break;  // POP
      case '1':
        pop_mark();
        break;  // POP_MARK
      case 'N':
      case 0x88:
      case 0x89:
      case ')':
      case ']':
      case '}':
        ++depth;
        break;  // NONE, NEWTRUE, NEWFALSE, EMPTY_*
      case 'K':
        need(1), p += 1, ++depth;
        break;  // BININT1
      case 'M':
        need(2), p += 2, ++depth;
        break;  // BININT2
      case 'J':
        need(4), p += 4, ++depth;
        break;  // BININT
      case 'G':
        need(8), p += 8, ++depth;
        break;      // BINFLOAT
      case 0x8a: {  // LONG1
        need(1);
        const std::size_t k = static_cast<unsigned char>(d[p++]);
        if (k > 8) fail("pickle integer wider than 64 bits");
        need(k), p += k, ++depth;
        break;
      }
      case 'X':
      case 'B': {  // BINUNICODE, BINBYTES
        need(4);
        const std::size_t k = le32(d + p);
        p += 4, need(k), p += k, ++depth;
        break;
      }
      case 0x8c:
      case 'U':
      case 'C': {  // SHORT_BINUNICODE, SHORT_BINSTRING, SHORT_BINBYTES
        need(1);
        const std::size_t k = static_cast<unsigned char>(d[p++]);
        need(k), p += k, ++depth;
        break;
      }
      case 'c': {  // GLOBAL: two lines
        for (int line = 0; line < 2; ++line) {
          const auto* nl =
              static_cast<const char*>(std::memchr(d + p, '\n', std::min<std::size_t>(n - p, 256)));
          if (!nl) fail("pickle GLOBAL name unterminated or too long");
          p = static_cast<std::size_t>(nl - d) + 1;
        }
        ++depth;
        break;
      }
      case 'q':
        need(1), put(static_cast<unsigned char>(d[p])), p += 1;
        break;  // BINPUT
      case 'r':
        need(4), put(le32(d + p)), p += 4;
        break;  // LONG_BINPUT
      case 0x94:
        put(memo);
        break;  // MEMOIZE
      case 'h':
        need(1), get(static_cast<unsigned char>(d[p])), p += 1;
        break;  // BINGET
      case 'j':
        need(4), get(le32(d + p)), p += 4;
        break;  // LONG_BINGET
      case 't':
      case 'l':
        pop_mark(), ++depth;
        break;   // TUPLE, LIST
      case 'd':  // DICT
        if (pop_mark() % 2) fail("pickle dict with an odd number of items");
        ++depth;
        break;
      case 0x85:
        pop(1), ++depth;
        break;  // TUPLE1
      case 0x86:
        pop(2), ++depth;
        break;  // TUPLE2
      case 0x87:
        pop(3), ++depth;
        break;  // TUPLE3
      case 'a':
        pop(2), ++depth;
        break;  // APPEND
      case 'e':
        pop_mark(), pop(1), ++depth;
        break;  // APPENDS
      case 's':
        pop(3), ++depth;
        break;   // SETITEM
      case 'u':  // SETITEMS
        if (pop_mark() % 2) fail("pickle SETITEMS with an odd number of items");
        pop(1), ++depth;
        break;
      case 'R':
      case 0x81:
        pop(2), ++depth;
        break;  // REDUCE, NEWOBJ
      case 'b':
        pop(2), ++depth;
        break;  // BUILD
      case 'Q':
        pop(1), ++depth;
        break;  // BINPERSID
      case 0x95:
        need(8), p += 8;
        break;  // FRAME
      default: {
        char hex[8];
        std::snprintf(hex, sizeof hex, "0x%02x", op);
        fail(std::string("unsupported pickle opcode ") + hex);
      }
    }
  }
}

/// The bytes of the opcode at `p` with its argument (a pickle check_pickle accepted); the
/// caller checks the result against the bytes left (0: a GLOBAL without its two lines).
inline std::size_t pickle_opcode_length(const char* d, std::size_t n, std::size_t p) {
  switch (static_cast<unsigned char>(d[p])) {
    case 0x80:
    case 'K':
    case 'q':
    case 'h':
      return 2;
    case 'M':
      return 3;
    case 'J':
    case 'r':
    case 'j':
      return 5;
    case 'G':
    case 0x95:
      return 9;
    case 0x8a:
    case 0x8c:
    case 'U':
    case 'C':
      return 2 + static_cast<unsigned char>(d[p + 1]);
    case 'X':
    case 'B':
      return 5 + le32(d + p + 1);
    case 'c': {
      const auto* a = static_cast<const char*>(std::memchr(d + p + 1, '\n', n - p - 1));
      if (!a) return 0;
      const auto* b = static_cast<const char*>(
          std::memchr(a + 1, '\n', static_cast<std::size_t>(d + n - a - 1)));
      if (!b) return 0;
      return static_cast<std::size_t>(b - (d + p)) + 1;
    }
    default:
      return 1;
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
  const auto broken = [&]() -> void {
    throw std::runtime_error(source + ": not a readable torch file: malformed pickle stack");
  };
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
    const unsigned char op = static_cast<unsigned char>(d[p]);
    const std::size_t len = pickle_opcode_length(d, n, p), at = out.size();
    // This walk may fall out of step with check_pickle's (the rewrites below skip opcodes): a
    // length past the end is an error, not a read past the buffer (a fuzzed file asked for 4 GB).
    if (len == 0 || len > n - p) broken();
    std::size_t q = p + len;
    bool ordered_dict = op == 'c' && std::string(d + p + 1, len - 1) == kOrderedDict;
    if (op == 'h' || op == 'j') {
      const std::uint32_t i = op == 'h' ? static_cast<unsigned char>(d[p + 1]) : le32(d + p + 1);
      ordered_dict = std::find(class_memo.begin(), class_memo.end(), i) != class_memo.end();
    }
    if (ordered_dict) {
      if (q < n && (d[q] == 'q' || d[q] == 'r')) {  // the class memoized: later BINGETs of it
        if (pickle_opcode_length(d, n, q) > n - q) broken();
        class_memo.push_back(d[q] == 'q' ? static_cast<unsigned char>(d[q + 1]) : le32(d + q + 1));
        q += pickle_opcode_length(d, n, q);
      }
      if (q + 1 >= n || d[q] != ')' || d[q + 1] != 'R')
        throw std::runtime_error(
            source +
            ": not a readable torch file: an OrderedDict made other than from an empty tuple");
      out += '}';
      starts.push_back(at);
      p = q + 2;
      continue;
    }
    if (op == 'b' && q < n &&
        d[q] == '.') {  // BUILD just before STOP: drop its state (the _metadata)
      if (starts.empty()) broken();
      out.resize(starts.back());
      starts.pop_back();
      p = q;
      continue;
    }
    if (op == 's') {  // SETITEM: MARK before the key, SETITEMS
      if (starts.size() < 2) broken();
      out.insert(starts[starts.size() - 2], 1, '(');
      out += 'u';
      starts.resize(starts.size() - 2);
      p = q;
      continue;
    }
    out.append(d + p, len);
    p = q;
    switch (op) {
      case '(':
        marks.emplace_back(starts.size(), at);
        break;
      case '0':
        pop_items(1);
        break;
      case '1':
        pop_to_mark();
        break;
      case 't':
      case 'l':
      case 'd':
        starts.push_back(pop_to_mark());
        break;
      case 0x85:
        if (starts.empty()) broken();
        break;  // TUPLE1: same start
      case 0x86:
        pop_items(1);
        break;  // TUPLE2
      case 0x87:
        pop_items(2);
        break;  // TUPLE3
      case 'a':
      case 'b':
        pop_items(1);
        break;  // APPEND, BUILD
      case 'e':
      case 'u':
        pop_to_mark();
        break;  // APPENDS, SETITEMS
      case 'R':
      case 0x81:
        pop_items(1);
        break;  // REDUCE, NEWOBJ
      case 'Q':
      case 0x80:
      case 0x95:
      case 'q':
      case 'r':
      case 0x94:
      case '.':
        break;
      default:
        starts.push_back(at);
        break;  // every other opcode pushes one item
    }
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
inline std::map<std::string, torch::Tensor> parse_tensor_dict(const char* data, std::size_t size,
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
inline std::map<std::string, torch::Tensor> read_tensor_dict(const std::string& path) {
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
inline c10::Dict<std::string, torch::Tensor> adam_state_dict(torch::optim::Adam& opt,
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
inline void load_adam_state(torch::optim::Adam& opt, const torch::nn::Module& m,
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
inline void load_parameters(torch::nn::Module& m, const std::map<std::string, torch::Tensor>& dict,
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

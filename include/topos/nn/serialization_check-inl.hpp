// topos/nn/serialization_check-inl.hpp
// What makes an untrusted torch file safe for LibTorch's unpickler (parse_tensor_dict): its zip
// members checked (torch_zip_records), its pickle walked opcode by opcode (check_pickle), and
// what Python's torch.save writes that LibTorch cannot read rewritten (pickle_for_libtorch).
// The opcodes are decoded by io/pickle.hpp, which the Planetoid reader shares.
#pragma once

#include "topos/io/pickle.hpp"

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <iterator>
#include <map>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace topos::nn {

namespace detail {

/// One stored (uncompressed) member of a zip archive: its bytes within the file.
struct ZipRecord {
  std::size_t offset = 0, size = 0;
};

using io::pickle::le16;
using io::pickle::le32;

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

/// Decodes the opcode at `p` of the pickle `d` of `n` bytes in the subset torch files use.
template <class Fail>
io::pickle::Op decode_pickle_op(const char* d, std::size_t n, std::size_t p, const Fail& fail) {
  return io::pickle::decode(d, n, p, io::pickle::kTorch, fail);
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
    if (p >= n) fail("truncated pickle: no STOP opcode");
    const io::pickle::Op op = decode_pickle_op(d, n, p, fail);
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
    const io::pickle::Op op = decode_pickle_op(d, n, p, fail);
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

}  // namespace topos::nn

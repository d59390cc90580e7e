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
    const io::pickle::Op op = io::pickle::decode(d, n, p, io::pickle::kTorch, fail);
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

/// The walk of pickle_for_libtorch (below): the rewritten pickle, and per stack item where its
/// opcodes begin in it, to put the MARK before a SETITEM's key. check_pickle accepted the input,
/// but this walk rewrites it: its stacks are checked again rather than trusted (a fuzzed pickle
/// once popped a mark this walk had not set).
class LibTorchPickleRewrite {
 public:
  LibTorchPickleRewrite(const char* d, std::size_t n, const std::string& source)
      : d_(d), n_(n), source_(source) {
    out_.reserve(n + 64);
  }

  std::string run() {
    std::size_t p = 0;
    while (p < n_) {
      const io::pickle::Op op = io::pickle::decode(d_, n_, p, io::pickle::kTorch,
                                                   [this](const std::string& why) { fail(why); });
      const std::size_t q = p + op.length;
      if (names_ordered_dict(op, p)) {
        p = empty_dict_for_ordered_dict(q);
      } else if (op.code == 'b' && q < n_ && d_[q] == '.') {  // BUILD just before STOP
        drop_final_build_state();
        p = q;
      } else if (op.code == 's') {
        setitem_as_setitems();
        p = q;
      } else {
        copy(op, p);
        p = q;
        if (op.code == '.') break;
      }
    }
    return std::move(out_);
  }

 private:
  const char* d_;
  std::size_t n_;
  const std::string& source_;
  std::string out_;
  std::vector<std::uint32_t> class_memo_;  // memo entries holding the OrderedDict class
  std::vector<std::size_t> starts_;        // per stack item: its first byte in `out_`
  std::vector<std::pair<std::size_t, std::size_t>> marks_;  // (stack depth, position in `out_`)

  void fail(const std::string& why) const {
    throw std::runtime_error(source_ + ": not a readable torch file: " + why);
  }
  void broken() const { fail("malformed pickle stack"); }

  /// Whether the opcode at `p` pushes the OrderedDict class: its GLOBAL, or a BINGET /
  /// LONG_BINGET of a memo entry that holds it.
  bool names_ordered_dict(const io::pickle::Op& op, std::size_t p) const {
    static const std::string kOrderedDict = "collections\nOrderedDict\n";
    bool ordered_dict = op.code == 'c' && std::string(d_ + p + 1, op.length - 1) == kOrderedDict;
    if (op.code == 'h' || op.code == 'j') {
      const std::uint32_t i =
          op.code == 'h' ? static_cast<unsigned char>(d_[p + 1]) : le32(d_ + p + 1);
      ordered_dict = std::find(class_memo_.begin(), class_memo_.end(), i) != class_memo_.end();
    }
    return ordered_dict;
  }

  /// `OrderedDict()` (the class, maybe memoized, then EMPTY_TUPLE REDUCE from `q`) as EMPTY_DICT;
  /// returns where the input continues.
  std::size_t empty_dict_for_ordered_dict(std::size_t q) {
    const std::size_t at = out_.size();
    if (q < n_ && (d_[q] == 'q' || d_[q] == 'r')) {  // the class memoized: later BINGETs of it
      const std::size_t length =
          io::pickle::decode(d_, n_, q, io::pickle::kTorch, [this](const std::string& why) {
            fail(why);
          }).length;
      class_memo_.push_back(d_[q] == 'q' ? static_cast<unsigned char>(d_[q + 1])
                                         : le32(d_ + q + 1));
      q += length;
    }
    if (q + 1 >= n_ || d_[q] != ')' || d_[q + 1] != 'R')
      fail("an OrderedDict made other than from an empty tuple");
    out_ += '}';
    starts_.push_back(at);
    return q + 2;
  }

  /// The final BUILD (`_metadata`) dropped with its state, the item on top of the stack.
  void drop_final_build_state() {
    if (starts_.empty()) broken();
    out_.resize(starts_.back());
    starts_.pop_back();
  }

  /// SETITEM as MARK (before the key) ... SETITEMS.
  void setitem_as_setitems() {
    if (starts_.size() < 2) broken();
    out_.insert(starts_[starts_.size() - 2], 1, '(');
    out_ += 'u';
    starts_.resize(starts_.size() - 2);
  }

  /// Copies the opcode at `p` as it is, tracking its effect on the stack: the item it pushes
  /// begins where the earliest thing it consumed began (the deepest item it pops, else its mark,
  /// else the opcode itself).
  void copy(const io::pickle::Op& op, std::size_t p) {
    const std::size_t at = out_.size();
    out_.append(d_ + p, op.length);
    if (op.code == '.') return;
    if (op.code == '(') marks_.emplace_back(starts_.size(), at);
    std::size_t first = at;
    if (op.to_mark) first = pop_to_mark();
    if (op.pops) {
      if (starts_.size() < op.pops) broken();
      first = starts_[starts_.size() - op.pops];
      pop_items(op.pops);
    }
    if (op.pushes) starts_.push_back(first);
  }

  void pop_items(std::size_t k) {
    if (starts_.size() < k || (!marks_.empty() && starts_.size() - k < marks_.back().first))
      broken();
    starts_.resize(starts_.size() - k);
  }
  /// Pops the stack to the top mark; returns the mark's position in `out_`.
  std::size_t pop_to_mark() {
    if (marks_.empty() || starts_.size() < marks_.back().first) broken();
    const auto m = marks_.back();
    marks_.pop_back();
    starts_.resize(m.first);
    return m.second;
  }
};

/// Python's torch.save(model.state_dict()) writes what LibTorch 1.13's unpickler cannot read:
/// collections.OrderedDicts (the dict itself, each tensor's empty backward hooks, the
/// `_metadata` attribute set by a final BUILD), which it turns into None, and SETITEM (one pair;
/// Python's pickler writes it for a batch of one), which it does not know. The same pickle with
/// each `OrderedDict()` as a plain empty dict, each SETITEM as MARK ... SETITEMS, and the final
/// BUILD dropped with its state (the metadata holds only module versions; LibTorch has no POP).
/// The input passed check_pickle; `source` names it in errors.
inline std::string pickle_for_libtorch(const char* d, std::size_t n, const std::string& source) {
  return LibTorchPickleRewrite(d, n, source).run();
}

}  // namespace detail

}  // namespace topos::nn

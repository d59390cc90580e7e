// topos/data/planetoid_pickle-inl.hpp
// Part of graph_datasets-inl.hpp (included by it, not by users): the object reader behind
// read_planetoid_pickle. It runs the opcodes that io/pickle.hpp decodes (the Python-2 subset)
// and builds only what Planetoid's files hold: scipy.sparse.csr_matrix, numpy.ndarray and a
// defaultdict(list) of int lists.
#pragma once

#include "topos/data/graph_io-inl.hpp"
#include "topos/io/pickle.hpp"

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <iterator>
#include <limits>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <string_view>
#include <unordered_map>
#include <utility>
#include <vector>

namespace topos::data {

// --- Planetoid: Python-2 pickles -----------------------------------------------------------

namespace pickle {

/// The objects of the pickle subset: Python-2 protocol-2 pickles of scipy.sparse.csr_matrix,
/// numpy.ndarray and a defaultdict(list) of int lists, the opcodes Planetoid's files use and
/// nothing else. Containment is restricted so that no cycle can form (tuples hold only scalars,
/// globals, dtypes and tuples; lists hold only ints; dicts never hold dicts or matrices).
enum class Kind { None, Bool, Int, Str, Tuple, List, Dict, Global, NdArray, DType, Csr };

struct Value;
using Ref = std::shared_ptr<Value>;

struct Value {
  Kind kind = Kind::None;
  std::int64_t i = 0;                    ///< Int, Bool
  std::string s;                         ///< Str: the bytes; Global: "module name"; DType: "i4"
  std::vector<Ref> items;                ///< Tuple
  std::vector<std::int64_t> ints;        ///< List
  std::map<std::int64_t, Ref> int_keys;  ///< Dict
  std::map<std::string, Ref> str_keys;   ///< Dict
  std::vector<std::int64_t> shape;       ///< NdArray
  Ref dtype;                             ///< NdArray
  std::string data;                      ///< NdArray: raw little-endian bytes
  Ref state;                             ///< Csr: its attribute dict
  bool built = false;                    ///< NdArray, DType, Csr: BUILD has given the state
  int depth = 0;                         ///< Tuple nesting
};

inline const char* kind_name(Kind k) {
  switch (k) {
    case Kind::None:
      return "None";
    case Kind::Bool:
      return "bool";
    case Kind::Int:
      return "int";
    case Kind::Str:
      return "str";
    case Kind::Tuple:
      return "tuple";
    case Kind::List:
      return "list";
    case Kind::Dict:
      return "dict";
    case Kind::Global:
      return "global";
    case Kind::NdArray:
      return "ndarray";
    case Kind::DType:
      return "dtype";
    case Kind::Csr:
      return "csr_matrix";
  }
  return "?";
}

inline std::size_t item_size(const std::string& dtype) {
  return (dtype == "i4" || dtype == "f4") ? 4 : (dtype == "i8" || dtype == "f8") ? 8 : 0;
}

/// Runs the pickle machine over `bytes`; errors name `source` and the opcode's byte offset.
class Machine {
 public:
  Machine(std::string_view bytes, std::string source) : b_(bytes), source_(std::move(source)) {}

  Ref run() {
    while (true) {
      at_ = pos_;
      if (pos_ >= b_.size()) fail("truncated pickle: no STOP opcode");
      const auto op = io::pickle::decode(b_.data(), b_.size(), at_, io::pickle::kPython2,
                                         [this](const std::string& why) { fail(why); });
      const char* arg = b_.data() + at_ + 1;
      pos_ = at_ + op.length;
      if (at_ == 0 && op.code != 0x80) fail("not a protocol-2 pickle (no PROTO opcode)");
      switch (op.code) {
        case 0x80:  // PROTO
          if (at_ != 0 || static_cast<unsigned char>(arg[0]) != 2)
            fail("expected PROTO 2 at the start");
          break;
        case 'c': {  // GLOBAL: "module\nname\n"
          const std::string_view lines(arg, op.length - 1);
          const auto nl = lines.find('\n');
          const std::string g = std::string(lines.substr(0, nl)) + " " +
                                std::string(lines.substr(nl + 1, lines.size() - nl - 2));
          static const char* const known[] = {"scipy.sparse.csr csr_matrix",
                                              "scipy.sparse._csr csr_matrix",
                                              "numpy.core.multiarray _reconstruct",
                                              "numpy ndarray",
                                              "numpy dtype",
                                              "collections defaultdict",
                                              "__builtin__ list"};
          if (std::find(std::begin(known), std::end(known), g) == std::end(known))
            fail("unsupported global " + graph_io::quote(g));
          auto v = make(Kind::Global);
          v->s = g == "scipy.sparse._csr csr_matrix" ? "scipy.sparse.csr csr_matrix" : g;
          push(v);
          break;
        }
        case 'q':  // BINPUT
          memo_[static_cast<unsigned char>(arg[0])] = top();
          break;
        case 'r':  // LONG_BINPUT
          memo_[io::pickle::le32(arg)] = top();
          break;
        case 'h': {  // BINGET
          const std::uint32_t k = static_cast<unsigned char>(arg[0]);
          const auto it = memo_.find(k);
          if (it == memo_.end()) fail("BINGET of memo " + std::to_string(k) + ", never stored");
          push(it->second);
          break;
        }
        case ')':  // EMPTY_TUPLE
          push(make_tuple({}));
          break;
        case ']':  // EMPTY_LIST
          push(make(Kind::List));
          break;
        case '}':  // EMPTY_DICT
          push(make(Kind::Dict));
          break;
        case '(':  // MARK
          marks_.push_back(stack_.size());
          break;
        case 't':  // TUPLE
          push(make_tuple(pop_mark()));
          break;
        case 0x85:  // TUPLE1
          push(make_tuple(pop_n(1)));
          break;
        case 0x86:  // TUPLE2
          push(make_tuple(pop_n(2)));
          break;
        case 0x87:  // TUPLE3
          push(make_tuple(pop_n(3)));
          break;
        case 'N':  // NONE
          push(make(Kind::None));
          break;
        case 0x88:  // NEWTRUE
          push(make_int(Kind::Bool, 1));
          break;
        case 0x89:  // NEWFALSE
          push(make_int(Kind::Bool, 0));
          break;
        case 'K':  // BININT1
          push(make_int(Kind::Int, static_cast<unsigned char>(arg[0])));
          break;
        case 'M':  // BININT2
          push(make_int(Kind::Int, io::pickle::le16(arg)));
          break;
        case 'J':  // BININT
          push(make_int(Kind::Int, static_cast<std::int32_t>(io::pickle::le32(arg))));
          break;
        case 'U':  // SHORT_BINSTRING: a length byte, then the bytes
          push(make_str(std::string_view(arg + 1, op.length - 2)));
          break;
        case 'T':  // BINSTRING: a 4-byte length, then the bytes
          push(make_str(std::string_view(arg + 4, op.length - 5)));
          break;
        case 'R':
          reduce();
          break;
        case 0x81:
          newobj();
          break;
        case 'b':
          build();
          break;
        case 'a': {  // APPEND
          const auto v = pop();
          append(top(), {v});
          break;
        }
        case 'e': {  // APPENDS
          auto items = pop_mark();
          append(top(), items);
          break;
        }
        case 'u': {  // SETITEMS
          auto items = pop_mark();
          setitems(top(), items);
          break;
        }
        case '.': {  // STOP
          if (!marks_.empty() || stack_.size() != 1)
            fail("STOP with " + std::to_string(stack_.size()) + " stack items and " +
                 std::to_string(marks_.size()) + " open marks");
          if (pos_ != b_.size())
            fail(std::to_string(b_.size() - pos_) + " bytes after the STOP opcode");
          return stack_.back();
        }
        default:  // in the decoder's Python-2 subset, and every one of those is read above
          fail("unsupported pickle opcode " + io::pickle::opcode_name(op.code));
      }
    }
  }

  [[noreturn]] void fail(const std::string& what) const {
    throw std::runtime_error(source_ + ": offset " + std::to_string(at_) + ": " + what);
  }

 private:
  static constexpr int kMaxTupleDepth = 16;

  static Ref make(Kind k) {
    auto v = std::make_shared<Value>();
    v->kind = k;
    return v;
  }
  static Ref make_int(Kind k, std::int64_t i) {
    auto v = make(k);
    v->i = i;
    return v;
  }
  static Ref make_str(std::string_view s) {
    auto v = make(Kind::Str);
    v->s = std::string(s);
    return v;
  }
  Ref make_tuple(std::vector<Ref> items) {
    auto v = make(Kind::Tuple);
    for (const auto& it : items) {
      switch (it->kind) {
        case Kind::None:
        case Kind::Bool:
        case Kind::Int:
        case Kind::Str:
        case Kind::Global:
        case Kind::DType:
          break;
        case Kind::Tuple:
          v->depth = std::max(v->depth, it->depth + 1);
          break;
        default:
          fail(std::string("a tuple holding a ") + kind_name(it->kind) + " is not supported");
      }
    }
    if (v->depth > kMaxTupleDepth) fail("tuples nested too deeply");
    v->items = std::move(items);
    return v;
  }

  std::size_t fence() const { return marks_.empty() ? 0 : marks_.back(); }
  void push(Ref v) { stack_.push_back(std::move(v)); }
  const Ref& top() const {
    if (stack_.size() <= fence()) fail("stack underflow");
    return stack_.back();
  }
  Ref pop() {
    if (stack_.size() <= fence()) fail("stack underflow");
    auto v = std::move(stack_.back());
    stack_.pop_back();
    return v;
  }
  std::vector<Ref> pop_n(std::size_t n) {
    if (stack_.size() < fence() + n) fail("stack underflow");
    std::vector<Ref> out(stack_.end() - static_cast<std::ptrdiff_t>(n), stack_.end());
    stack_.resize(stack_.size() - n);
    return out;
  }
  std::vector<Ref> pop_mark() {
    if (marks_.empty()) fail("no MARK to pop to");
    const auto m = marks_.back();
    marks_.pop_back();
    std::vector<Ref> out(stack_.begin() + static_cast<std::ptrdiff_t>(m), stack_.end());
    stack_.resize(m);
    return out;
  }

  static bool is(const Ref& v, Kind k, const char* global = nullptr) {
    return v->kind == k && (global == nullptr || v->s == global);
  }

  void reduce() {
    const auto args = pop();
    const auto callable = pop();
    if (!is(args, Kind::Tuple)) fail("REDUCE arguments are not a tuple");
    const auto& a = args->items;
    if (is(callable, Kind::Global, "numpy.core.multiarray _reconstruct")) {
      // _reconstruct(ndarray, (0,), 'b'): an empty array that BUILD fills.
      if (a.size() != 3 || !is(a[0], Kind::Global, "numpy ndarray") || !is(a[1], Kind::Tuple) ||
          a[1]->items.size() != 1 || !is(a[1]->items[0], Kind::Int) || a[1]->items[0]->i != 0 ||
          !is(a[2], Kind::Str) || a[2]->s != "b")
        fail("unexpected arguments to numpy.core.multiarray._reconstruct");
      push(make(Kind::NdArray));
    } else if (is(callable, Kind::Global, "numpy dtype")) {
      // dtype('i4', False, True)
      if (a.size() != 3 || !is(a[0], Kind::Str) || item_size(a[0]->s) == 0 ||
          !is(a[1], Kind::Int) || a[1]->i != 0 || !is(a[2], Kind::Int) || a[2]->i != 1)
        fail("unsupported numpy dtype (only i4, i8, f4, f8)");
      auto d = make(Kind::DType);
      d->s = a[0]->s;
      push(d);
    } else if (is(callable, Kind::Global, "collections defaultdict")) {
      if (a.size() != 1 || !is(a[0], Kind::Global, "__builtin__ list"))
        fail("only defaultdict(list) is supported");
      push(make(Kind::Dict));
    } else {
      fail(std::string("unsupported call of a ") + kind_name(callable->kind) +
           (callable->kind == Kind::Global ? " " + graph_io::quote(callable->s) : ""));
    }
  }

  void newobj() {
    const auto args = pop();
    const auto cls = pop();
    if (!is(cls, Kind::Global, "scipy.sparse.csr csr_matrix") || !is(args, Kind::Tuple) ||
        !args->items.empty())
      fail("NEWOBJ of anything but csr_matrix() is not supported");
    push(make(Kind::Csr));
  }

  void build() {
    const auto state = pop();
    const auto& obj = top();
    if (obj->built) fail(std::string("BUILD of a ") + kind_name(obj->kind) + " twice");
    if (obj->kind == Kind::DType) {
      // (3, '<', None, None, None, -1, -1, 0): version 3, little-endian, no fields.
      const auto& t = state->items;
      const bool ok = is(state, Kind::Tuple) && t.size() == 8 && is(t[0], Kind::Int) &&
                      t[0]->i == 3 && is(t[1], Kind::Str) && t[1]->s == "<" &&
                      is(t[2], Kind::None) && is(t[3], Kind::None) && is(t[4], Kind::None) &&
                      is(t[5], Kind::Int) && t[5]->i == -1 && is(t[6], Kind::Int) &&
                      t[6]->i == -1 && is(t[7], Kind::Int) && t[7]->i == 0;
      if (!ok) fail("unsupported dtype state (only little-endian plain dtypes)");
    } else if (obj->kind == Kind::NdArray) {
      // (1, shape, dtype, is_fortran, raw bytes)
      const auto& t = state->items;
      if (!is(state, Kind::Tuple) || t.size() != 5 || !is(t[0], Kind::Int) || t[0]->i != 1 ||
          !is(t[1], Kind::Tuple) || !is(t[2], Kind::DType) || !t[2]->built ||
          !is(t[3], Kind::Bool) || !is(t[4], Kind::Str))
        fail("unsupported ndarray state");
      std::uint64_t count = 1;
      for (const auto& d : t[1]->items) {
        if (!is(d, Kind::Int) || d->i < 0) fail("ndarray shape is not a tuple of sizes");
        const auto n = static_cast<std::uint64_t>(d->i);
        if (n != 0 && count > std::numeric_limits<std::uint64_t>::max() / 16 / n)
          fail("ndarray shape too large");
        count *= n;
        obj->shape.push_back(d->i);
      }
      if (t[3]->i != 0 && obj->shape.size() > 1) fail("Fortran-ordered arrays are not supported");
      const auto bytes = count * item_size(t[2]->s);
      if (bytes != t[4]->s.size())
        fail("ndarray of " + std::to_string(count) + " " + t[2]->s + " values needs " +
             std::to_string(bytes) + " bytes, its data has " + std::to_string(t[4]->s.size()));
      obj->dtype = t[2];
      obj->data = t[4]->s;
    } else if (obj->kind == Kind::Csr) {
      if (!is(state, Kind::Dict)) fail("csr_matrix state is not a dict");
      obj->state = state;
    } else {
      fail(std::string("BUILD of a ") + kind_name(obj->kind) + " is not supported");
    }
    obj->built = true;
  }

  void append(const Ref& list, const std::vector<Ref>& items) {
    if (!is(list, Kind::List)) fail(std::string("APPEND to a ") + kind_name(list->kind));
    for (const auto& v : items) {
      if (!is(v, Kind::Int))
        fail(std::string("a list item is a ") + kind_name(v->kind) + ", not an int");
      list->ints.push_back(v->i);
    }
  }

  void setitems(const Ref& dict, const std::vector<Ref>& items) {
    if (!is(dict, Kind::Dict)) fail(std::string("SETITEMS on a ") + kind_name(dict->kind));
    if (items.size() % 2 != 0) fail("SETITEMS with an odd number of items");
    for (std::size_t k = 0; k < items.size(); k += 2) {
      const auto& key = items[k];
      const auto& value = items[k + 1];
      if (value->kind == Kind::Dict || value->kind == Kind::Csr)
        fail(std::string("a dict value that is a ") + kind_name(value->kind) + " is not supported");
      bool fresh = false;
      if (is(key, Kind::Int))
        fresh = dict->int_keys.emplace(key->i, value).second;
      else if (is(key, Kind::Str))
        fresh = dict->str_keys.emplace(key->s, value).second;
      else
        fail(std::string("a dict key that is a ") + kind_name(key->kind) + " is not supported");
      if (!fresh) fail("duplicate dict key");
    }
  }

  std::string_view b_;
  std::string source_;
  std::size_t pos_ = 0, at_ = 0;
  std::vector<Ref> stack_;
  std::vector<std::size_t> marks_;
  std::unordered_map<std::uint32_t, Ref> memo_;
};

/// Element k of a built 1-D or flat array, as double.
inline double element(const Value& a, std::size_t k) {
  const auto& t = a.dtype->s;
  const char* p = a.data.data() + k * item_size(t);
  if (t == "i4") {
    std::int32_t v;
    std::memcpy(&v, p, 4);
    return v;
  }
  if (t == "i8") {
    std::int64_t v;
    std::memcpy(&v, p, 8);
    return static_cast<double>(v);
  }
  if (t == "f4") {
    float v;
    std::memcpy(&v, p, 4);
    return v;
  }
  double v;
  std::memcpy(&v, p, 8);
  return v;
}

inline std::int64_t index_element(const Value& a, std::size_t k) {
  const char* p = a.data.data() + k * item_size(a.dtype->s);
  if (a.dtype->s == "i4") {
    std::int32_t v;
    std::memcpy(&v, p, 4);
    return v;
  }
  std::int64_t v;
  std::memcpy(&v, p, 8);
  return v;
}

}  // namespace pickle

}  // namespace topos::data

// topos/io/pickle.hpp
// The one decoder of Python's pickle opcodes (protocol 2) that topos's readers share: the
// opcode table, each opcode's argument length and its effect on the unpickler's stack, with
// every length checked against the bytes. Two walks consume it: the torch-file checks of
// nn/serialization (before LibTorch's unpickler sees a file) and the Planetoid object reader of
// data/graph_datasets. Each accepts a subset of the opcodes: an opcode outside it is an error
// naming its hex code. std only.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <iterator>
#include <string>
#include <string_view>

namespace topos::io::pickle {

inline std::uint32_t le32(const char* p) {
  std::uint32_t v = 0;
  for (int i = 3; i >= 0; --i) v = (v << 8) | static_cast<unsigned char>(p[i]);
  return v;
}
inline std::uint16_t le16(const char* p) {
  return static_cast<std::uint16_t>(static_cast<unsigned char>(p[0]) |
                                    (static_cast<unsigned char>(p[1]) << 8));
}

/// The opcode subsets topos reads: what torch.save writes (and LibTorch's unpickler reads), and
/// what Python 2's pickler wrote for Planetoid's scipy and numpy objects.
enum Subset : unsigned { kTorch = 1, kPython2 = 2 };

/// One decoded opcode: its code, its length with its argument, and its effect on the stack
/// (pop to the top mark first when `to_mark`, then pop `pops` items, then push `pushes`).
struct Op {
  unsigned char code = 0;
  std::size_t length = 0;
  bool to_mark = false;
  std::size_t pops = 0, pushes = 0;
};

/// The hex spelling of an opcode in errors: "0x58".
inline std::string opcode_name(unsigned char code) {
  char hex[8];
  std::snprintf(hex, sizeof hex, "0x%02x", code);
  return hex;
}

/// Decodes the opcode at `p` (< n) of the pickle `d` of `n` bytes. `fail` (which throws) gets
/// why when the opcode is outside `subset`, its argument runs past the end, a GLOBAL line is
/// unterminated within 256 bytes, an integer is wider than 64 bits or a string length is negative.
template <class Fail>
Op decode(const char* d, std::size_t n, std::size_t p, unsigned subset, const Fail& fail) {
  // arg: the argument's bytes, or how it is sized: kLen1/kLen4 a 1- or 4-byte length prefix
  // (LONG1's at most 8), kLines GLOBAL's two lines.
  enum : int { kLen1 = -1, kLen4 = -4, kLines = -2 };
  constexpr unsigned kBoth = kTorch | kPython2;
  struct Row {
    unsigned char code;
    int arg;
    bool to_mark;
    unsigned char pops, pushes;
    unsigned subsets;
  };
  static constexpr Row kTable[] = {
      {0x80, 1, false, 0, 0, kBoth},        // PROTO
      {0x95, 8, false, 0, 0, kTorch},       // FRAME
      {'.', 0, false, 0, 0, kBoth},         // STOP
      {'(', 0, false, 0, 0, kBoth},         // MARK
      {'q', 1, false, 0, 0, kBoth},         // BINPUT
      {'r', 4, false, 0, 0, kBoth},         // LONG_BINPUT
      {0x94, 0, false, 0, 0, kTorch},       // MEMOIZE
      {'0', 0, false, 1, 0, kTorch},        // POP
      {'1', 0, true, 0, 0, kTorch},         // POP_MARK
      {'N', 0, false, 0, 1, kBoth},         // NONE
      {0x88, 0, false, 0, 1, kBoth},        // NEWTRUE
      {0x89, 0, false, 0, 1, kBoth},        // NEWFALSE
      {')', 0, false, 0, 1, kBoth},         // EMPTY_TUPLE
      {']', 0, false, 0, 1, kBoth},         // EMPTY_LIST
      {'}', 0, false, 0, 1, kBoth},         // EMPTY_DICT
      {'K', 1, false, 0, 1, kBoth},         // BININT1
      {'M', 2, false, 0, 1, kBoth},         // BININT2
      {'J', 4, false, 0, 1, kBoth},         // BININT
      {'G', 8, false, 0, 1, kTorch},        // BINFLOAT
      {0x8a, kLen1, false, 0, 1, kTorch},   // LONG1
      {0x8c, kLen1, false, 0, 1, kTorch},   // SHORT_BINUNICODE
      {'U', kLen1, false, 0, 1, kBoth},     // SHORT_BINSTRING
      {'C', kLen1, false, 0, 1, kTorch},    // SHORT_BINBYTES
      {'X', kLen4, false, 0, 1, kTorch},    // BINUNICODE
      {'B', kLen4, false, 0, 1, kTorch},    // BINBYTES
      {'T', kLen4, false, 0, 1, kPython2},  // BINSTRING
      {'c', kLines, false, 0, 1, kBoth},    // GLOBAL
      {'h', 1, false, 0, 1, kBoth},         // BINGET
      {'j', 4, false, 0, 1, kTorch},        // LONG_BINGET
      {'t', 0, true, 0, 1, kBoth},          // TUPLE
      {'l', 0, true, 0, 1, kTorch},         // LIST
      {'d', 0, true, 0, 1, kTorch},         // DICT
      {'e', 0, true, 1, 1, kBoth},          // APPENDS
      {'u', 0, true, 1, 1, kBoth},          // SETITEMS
      {0x85, 0, false, 1, 1, kBoth},        // TUPLE1
      {0x86, 0, false, 2, 1, kBoth},        // TUPLE2
      {0x87, 0, false, 3, 1, kBoth},        // TUPLE3
      {'a', 0, false, 2, 1, kBoth},         // APPEND
      {'s', 0, false, 3, 1, kTorch},        // SETITEM
      {'R', 0, false, 2, 1, kBoth},         // REDUCE
      {0x81, 0, false, 2, 1, kBoth},        // NEWOBJ
      {'b', 0, false, 2, 1, kBoth},         // BUILD
      {'Q', 0, false, 1, 1, kTorch},        // BINPERSID
  };
  const unsigned char code = static_cast<unsigned char>(d[p]);
  const Row* row = std::find_if(std::begin(kTable), std::end(kTable),
                                [&](const Row& r) { return r.code == code; });
  if (row == std::end(kTable) || (row->subsets & subset) == 0)
    fail("unsupported pickle opcode " + opcode_name(code));
  const std::size_t left = n - p - 1;  // bytes after the opcode
  const auto need = [&](std::size_t k) {
    if (left < k)
      fail("truncated pickle: " + std::to_string(k) + " bytes wanted, " + std::to_string(left) +
           " left");
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
    const std::uint32_t length = le32(d + p + 1);
    // BINSTRING's length is signed (Python 2's pickler never writes a negative one).
    if (code == 'T' && length > 0x7fffffffu) fail("negative string length");
    arg = std::size_t{4} + length;
  } else {  // GLOBAL: module and name, each on its own line
    for (int line = 0; line < 2; ++line) {
      const auto* nl = static_cast<const char*>(
          std::memchr(d + p + 1 + arg, '\n', std::min<std::size_t>(left - arg, 256)));
      if (!nl) fail("pickle GLOBAL name unterminated or too long");
      arg = static_cast<std::size_t>(nl - (d + p));
    }
  }
  need(arg);
  return Op{code, 1 + arg, row->to_mark, row->pops, row->pushes};
}

}  // namespace topos::io::pickle

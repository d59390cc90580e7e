// Tests of topos/util/read_file.hpp: every byte back, across and between its 64 KiB blocks,
// from a stream's position on, from a stream that cannot seek, a missing file and a directory.
#include "topos/util/read_file.hpp"

#include <catch2/catch.hpp>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <streambuf>
#include <string>

using topos::read_all;
using topos::read_file;

namespace {
// Bytes of every value, NULs and line ends included.
std::string random_bytes(std::size_t n, unsigned seed) {
  std::mt19937 gen(seed);
  std::string s(n, '\0');
  for (auto& c : s) c = static_cast<char>(gen() & 0xFF);
  return s;
}
// A stream buffer that hands out its bytes a few at a time and cannot seek, as a pipe or a /proc
// file does.
class UnseekableBuffer : public std::streambuf {
 public:
  explicit UnseekableBuffer(std::string bytes) : bytes_(std::move(bytes)) {}

 protected:
  int_type underflow() override {
    if (next_ >= bytes_.size()) return traits_type::eof();
    const auto n = std::min<std::size_t>(7, bytes_.size() - next_);
    char* p = bytes_.data() + next_;
    setg(p, p, p + n);
    next_ += n;
    return traits_type::to_int_type(*p);
  }

 private:
  std::string bytes_;
  std::size_t next_ = 0;
};
}  // namespace

TEST_CASE("read_file gives every byte of a file, whatever its size") {
  const auto dir = std::filesystem::temp_directory_path() / "topos_test_read_file";
  std::filesystem::create_directories(dir);
  for (const std::size_t n : {0u, 1u, 65535u, 65536u, 65537u, 3u * 65536u + 11u}) {
    INFO(n << " bytes");
    const auto path = (dir / ("f" + std::to_string(n))).string();
    const auto bytes = random_bytes(n, static_cast<unsigned>(n));
    std::ofstream(path, std::ios::binary) << bytes;
    std::string got = "stale";
    REQUIRE(read_file(path, got));
    CHECK(got == bytes);
    std::ifstream in(path, std::ios::binary);  // from a position inside the file
    in.seekg(static_cast<std::streamoff>(n / 3));
    CHECK(read_all(in) == bytes.substr(n / 3));
  }
  std::filesystem::remove_all(dir);
  std::string untouched = "kept";
  CHECK_FALSE(read_file((dir / "missing").string(), untouched));
  CHECK(untouched == "kept");
}

TEST_CASE("read_file refuses a directory and read_all reports its read error") {
  const auto dir = std::filesystem::temp_directory_path() / "topos_test_read_file_dir";
  std::filesystem::create_directories(dir);
  std::string untouched = "kept";
  CHECK_FALSE(read_file(dir.string(), untouched));
  CHECK(untouched == "kept");
  // The stream opens, seeks to an end of 2^63 - 1 bytes and fails its first read: no throw, no
  // bytes, badbit set.
  std::ifstream in(dir, std::ios::binary);
  std::string got = "stale";
  REQUIRE_NOTHROW(got = read_all(in));
  CHECK(got.empty());
  CHECK(in.bad());
  std::filesystem::remove_all(dir);
}

TEST_CASE("read_all reads a stream that cannot seek until it ends") {
  const auto bytes = random_bytes(200000, 3);
  UnseekableBuffer buffer(bytes);
  std::istream in(&buffer);
  CHECK(read_all(in) == bytes);
  std::istringstream text("line one\nline two\n");
  std::string first;
  std::getline(text, first);
  CHECK(read_all(text) == "line two\n");
}

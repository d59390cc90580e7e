// topos/util/malloc.hpp
// Which malloc this process runs on, for programs to print beside their timings: the allocator
// moves HOPNet's training step by 30 % (topos::tcmalloc in CMake). "tcmalloc <version>" when
// gperftools' tcmalloc is the process's malloc, else "glibc <version>". Linux and glibc; std
// and dlfcn only.
#pragma once

#include <dlfcn.h>
#include <gnu/libc-version.h>

#include <string>

namespace topos {

inline std::string malloc_name() {
  // The process's malloc is tcmalloc's exactly when the global symbol resolves to tc_malloc (a
  // tcmalloc loaded later, with dlopen, would not have replaced it).
  void* tc_malloc = ::dlsym(RTLD_DEFAULT, "tc_malloc");
  if (tc_malloc != nullptr && ::dlsym(RTLD_DEFAULT, "malloc") == tc_malloc) {
    using Version = const char* (*)(int*, int*, const char**);
    if (void* v = ::dlsym(RTLD_DEFAULT, "tc_version")) {
      int major = 0, minor = 0;
      const char* patch = nullptr;
      reinterpret_cast<Version>(v)(&major, &minor, &patch);
      return "tcmalloc " + std::to_string(major) + "." + std::to_string(minor) +
             (patch != nullptr ? patch : "");
    }
    return "tcmalloc";
  }
  return std::string("glibc ") + ::gnu_get_libc_version();
}

}  // namespace topos

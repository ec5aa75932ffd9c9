#pragma once
// Property checks of the libFuzzer targets (fuzz_codec.cpp, fuzz_firmware.cpp). A violated
// property prints which one and the values involved, then aborts: libFuzzer saves the input as a
// crash artifact, and the message says what to look for when it is replayed.
#include <cstdio>
#include <cstdlib>

#define FUZZ_CHECK(cond, ...)                                                              \
  do {                                                                                     \
    if (!(cond)) {                                                                         \
      std::fprintf(stderr, "%s:%d: property violated: %s\n  ", __FILE__, __LINE__, #cond); \
      std::fprintf(stderr, __VA_ARGS__);                                                   \
      std::fputc('\n', stderr);                                                            \
      std::abort();                                                                        \
    }                                                                                      \
  } while (0)

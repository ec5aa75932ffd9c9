#pragma once
// Four floats or ints in one register (GCC / Clang vector extensions: SSE on x86-64, NEON on
// ARM). Private to the core's sources.
#include <cstring>

namespace depth_track {
namespace simd4 {

typedef float V4f __attribute__((vector_size(16)));
typedef int V4i __attribute__((vector_size(16)));
inline V4f splat(float x) { return V4f{x, x, x, x}; }
inline V4f load4(const float* p) {
  V4f v;
  std::memcpy(&v, p, sizeof v);
  return v;
}

}  // namespace simd4
}  // namespace depth_track

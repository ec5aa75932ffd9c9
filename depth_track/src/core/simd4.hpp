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

// Four floats from p[u], those at u1 and beyond 0 (not read).
inline V4f load4OrZero(const float* p, int u, int u1) {
  if (u + 4 <= u1) return load4(p + u);
  V4f v{0.0f, 0.0f, 0.0f, 0.0f};
  for (int k = 0; u + k < u1; ++k) v[k] = p[u + k];
  return v;
}
// Stores the lanes of v to p[u], those at u1 and beyond left out.
inline void store4(float* p, int u, int u1, V4f v) {
  if (u + 4 <= u1) {
    std::memcpy(p + u, &v, sizeof v);
    return;
  }
  for (int k = 0; u + k < u1; ++k) p[u + k] = v[k];
}

}  // namespace simd4
}  // namespace depth_track

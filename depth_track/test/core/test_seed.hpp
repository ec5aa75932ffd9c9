// Noise seed of the rendered runs in the whole-run tests: the committed seed, or DT_TEST_SEED
// when set. The guards near the measured figures have margins taken from the seed-to-seed
// spread; this is how that spread is re-measured with the tests themselves, e.g.
//   for s in 1 2 3 4 5; do DT_TEST_SEED=$s ./devel/lib/depth_track/dt_test_whole_runs; done
// (the tests print their figures; with another seed a guard may trip, which is the point of
// measuring the spread before setting one).
#pragma once

#include <cstdint>
#include <cstdlib>
#include <string>

namespace dt_test {

/// `committed` unless DT_TEST_SEED holds a number.
inline std::uint64_t runSeed(std::uint64_t committed) {
  const char* v = std::getenv("DT_TEST_SEED");
  if (v == nullptr || *v == '\0') return committed;
  return std::stoull(v);
}

}  // namespace dt_test

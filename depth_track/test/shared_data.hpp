// The real sequences (TUM RGB-D with motion-capture ground truth) live outside the repository,
// in a `shared/` folder. Every test that reads them finds them here and follows one rule when
// they are missing:
//   - DT_REQUIRE_SHARED_DATA=1 in the environment (CI: .ci/run sets it): the test FAILS, because
//     there the real-data accuracy checks must run, and a missing folder would otherwise pass;
//   - otherwise (a user's clone without the data): the test is SKIPPED with the reason printed,
//     and test_summary.py lists the reason beside the skip count.
// Looked for: $DT_SHARED_DIR/<sub> only, when that is set; else, in order,
// <checkout>/../shared/<sub> (the shared folder next to the checkout),
// <checkout>/../../shared/<sub> (next to a folder of worktrees), /work/shared/<sub>.
#pragma once

#include <gtest/gtest.h>

#include <string>

#include "shared_data_paths.hpp"

namespace dt_test {

/// True when the environment asks for the shared data (DT_REQUIRE_SHARED_DATA set, not "0").
inline bool sharedDataRequired() {
  const char* v = std::getenv("DT_REQUIRE_SHARED_DATA");
  return v != nullptr && *v != '\0' && std::string(v) != "0";
}

/// What was looked for and where, for the failure or skip message.
inline std::string sharedDataMissing(const std::string& sub, const std::string& marker) {
  std::string m = "shared data " + sub + "/" + marker + " not found; looked in:";
  for (const std::string& d : sharedDataCandidates(sub)) m += " " + d;
  m += " (set DT_SHARED_DIR to the folder holding data/)";
  return m;
}

}  // namespace dt_test

/// Declares `const std::string var` = the folder of shared/<sub> (holding `marker`), or ends the
/// test: FAIL when DT_REQUIRE_SHARED_DATA is set, SKIP with the reason otherwise. Use it in the
/// body of a TEST (it returns from the enclosing void function).
#define DT_SHARED_DATA_OR_SKIP(var, sub, marker)                                   \
  const std::string var = dt_test::findSharedData(sub, marker);                    \
  if (var.empty()) {                                                               \
    if (dt_test::sharedDataRequired())                                             \
      FAIL() << dt_test::sharedDataMissing(sub, marker)                            \
             << " and DT_REQUIRE_SHARED_DATA is set";                              \
    else                                                                           \
      GTEST_SKIP() << dt_test::sharedDataMissing(sub, marker)                      \
                   << " (skipped; DT_REQUIRE_SHARED_DATA=1 makes this a failure)"; \
  }

/// The TUM fr3/teddy sequence (depth.txt, groundtruth.txt, depth/*.png).
#define DT_TEDDY_OR_SKIP(var) DT_SHARED_DATA_OR_SKIP(var, "data/tum_fr3_teddy", "depth.txt")
/// The TUM fr1/xyz sequence (same layout).
#define DT_FR1_XYZ_OR_SKIP(var) DT_SHARED_DATA_OR_SKIP(var, "data/tum_fr1_xyz", "depth.txt")

// Where the shared real sequences are looked for (see shared_data.hpp for the rule the tests
// follow when they are missing). Free of gtest, so the benchmarks find the data the same way.
#pragma once

#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#ifndef DT_SOURCE_DIR
#error "DT_SOURCE_DIR must name depth_track's source folder"
#endif

namespace dt_test {

/// Folders searched for shared/<sub>, in order (listed in shared_data.hpp's file comment).
inline std::vector<std::string> sharedDataCandidates(const std::string& sub) {
  std::vector<std::string> out;
  if (const char* env = std::getenv("DT_SHARED_DIR"); env != nullptr && *env != '\0')
    return {std::string(env) + "/" + sub};  // an explicit folder is the only place looked in
  // DT_SOURCE_DIR may come through the src/ links of the catkin space: resolve them first.
  std::error_code ec;
  const std::filesystem::path checkout =
      std::filesystem::weakly_canonical(DT_SOURCE_DIR, ec).parent_path();
  out.push_back((checkout.parent_path() / "shared" / sub).string());
  out.push_back((checkout.parent_path().parent_path() / "shared" / sub).string());
  out.push_back("/work/shared/" + sub);
  return out;
}

/// The first candidate folder holding `marker` (a file inside shared/<sub>), or "" if none does.
inline std::string findSharedData(const std::string& sub, const std::string& marker) {
  for (const std::string& d : sharedDataCandidates(sub))
    if (std::filesystem::exists(d + "/" + marker)) return d;
  return "";
}

}  // namespace dt_test

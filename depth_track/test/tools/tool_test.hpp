#pragma once
// Running an offline tool from a test: a temporary folder removed afterwards, and the tool's exit
// code with everything it printed. Shared by the tool tests (tum_to_bag, camera_check).
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

namespace depth_track {
namespace tool_test {

/// A fresh folder under /tmp, removed with everything in it when this goes out of scope.
struct TmpDir {
  std::string path;
  TmpDir() {
    char tmpl[] = "/tmp/dt_tool_test_XXXXXX";
    const char* d = mkdtemp(tmpl);
    path = d ? d : "/tmp";
  }
  ~TmpDir() {
    std::error_code ec;
    std::filesystem::remove_all(path, ec);
  }
  TmpDir(const TmpDir&) = delete;
  TmpDir& operator=(const TmpDir&) = delete;
};

struct ToolRun {
  int rc = -1;
  std::string output;  ///< stdout and stderr
};

/// Runs `exe args` through the shell, its output collected in log_dir/tool.log.
inline ToolRun runTool(const std::string& exe, const std::string& args,
                       const std::string& log_dir) {
  const std::string log = log_dir + "/tool.log";
  const int status = std::system((exe + " " + args + " > " + log + " 2>&1").c_str());
  ToolRun r;
  r.rc = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  std::ifstream in(log);
  std::stringstream s;
  s << in.rdbuf();
  r.output = s.str();
  return r;
}

}  // namespace tool_test
}  // namespace depth_track

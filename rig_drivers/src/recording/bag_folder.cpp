#include "rig_drivers/recording/bag_folder.hpp"

#include <dirent.h>
#include <sys/stat.h>
#include <sys/statvfs.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>

namespace rig_drivers {

namespace {
bool endsWith(const std::string& s, const std::string& e) {
  return s.size() >= e.size() && s.compare(s.size() - e.size(), e.size(), e) == 0;
}
bool isDir(const std::string& p) {
  struct stat st {};
  return ::stat(p.c_str(), &st) == 0 && S_ISDIR(st.st_mode);
}
}  // namespace

bool ensureFolder(const std::string& dir, std::string* why) {
  if (dir.empty()) {
    *why = "no bag folder given";
    return false;
  }
  // mkdir -p: every prefix that ends at a '/', then the folder itself.
  for (std::size_t i = 1; i <= dir.size(); ++i) {
    if (i < dir.size() && dir[i] != '/') continue;
    const std::string part = dir.substr(0, i);
    if (isDir(part)) continue;
    if (::mkdir(part.c_str(), 0775) != 0 && errno != EEXIST) {
      *why = "cannot create the bag folder " + dir + ": " + part + ": " + std::strerror(errno);
      return false;
    }
    if (!isDir(part)) {
      *why = "cannot create the bag folder " + dir + ": " + part + " exists and is not a folder";
      return false;
    }
  }
  if (::access(dir.c_str(), W_OK | X_OK) != 0) {
    *why = "cannot write into the bag folder " + dir + ": " + std::strerror(errno);
    return false;
  }
  return true;
}

std::optional<std::uint64_t> freeBytes(const std::string& path) {
  struct statvfs s {};
  if (::statvfs(path.c_str(), &s) != 0) return std::nullopt;
  return static_cast<std::uint64_t>(s.f_bavail) * s.f_frsize;
}

std::optional<FolderId> folderId(const std::string& dir) {
  struct stat st {};
  if (::stat(dir.c_str(), &st) != 0 || !S_ISDIR(st.st_mode)) return std::nullopt;
  return FolderId{st.st_dev, st.st_ino};
}

BagFiles listBags(const std::string& dir, const std::string& prefix) {
  BagFiles out;
  DIR* d = ::opendir(dir.c_str());
  if (!d) return out;
  while (dirent* e = ::readdir(d)) {
    const std::string name = e->d_name;
    if (name.compare(0, prefix.size() + 1, prefix + "_") != 0) continue;
    const bool closed = endsWith(name, ".bag");
    if (!closed && !endsWith(name, ".bag.active")) continue;
    struct stat st {};
    if (::stat((dir + "/" + name).c_str(), &st) != 0) continue;
    const std::int64_t mtime_ns =
        static_cast<std::int64_t>(st.st_mtim.tv_sec) * 1000000000 + st.st_mtim.tv_nsec;
    (closed ? out.closed : out.active)
        .push_back({name, static_cast<std::uint64_t>(st.st_size), mtime_ns});
  }
  ::closedir(d);
  auto by_name = [](const BagFile& a, const BagFile& b) { return a.name < b.name; };
  std::sort(out.closed.begin(), out.closed.end(), by_name);
  std::sort(out.active.begin(), out.active.end(), by_name);
  return out;
}

std::string humanBytes(std::uint64_t bytes) {
  char buf[32];
  if (bytes >= 10ull * 1000 * 1000 * 1000)
    std::snprintf(buf, sizeof buf, "%.0f GB", bytes * 1e-9);
  else if (bytes >= 1000ull * 1000 * 1000)
    std::snprintf(buf, sizeof buf, "%.2f GB", bytes * 1e-9);
  else
    std::snprintf(buf, sizeof buf, "%.1f MB", bytes * 1e-6);
  return buf;
}

}  // namespace rig_drivers

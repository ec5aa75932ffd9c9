#pragma once
/// The folder the rig records into (ROS-free): created when missing, checked for room, watched
/// for removal, and listed for the bags a recorder closed or left open.
#include <sys/types.h>

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

namespace rig_drivers {

/// Creates `dir` and its missing parents (mode 0775 less the umask). True when it exists as a
/// writable folder afterwards; else false with the reason, naming the folder, in *why.
bool ensureFolder(const std::string& dir, std::string* why);

/// Bytes free for an unprivileged writer on the file system holding `path`; nullopt when it
/// cannot be read (the folder is gone).
std::optional<std::uint64_t> freeBytes(const std::string& path);

/// Identity of a folder (device and inode): a folder removed and made again is another one.
struct FolderId {
  dev_t dev = 0;
  ino_t ino = 0;
  bool operator==(const FolderId& o) const { return dev == o.dev && ino == o.ino; }
};
std::optional<FolderId> folderId(const std::string& dir);

/// One bag file in the folder.
struct BagFile {
  std::string name;  ///< file name without the folder
  std::uint64_t bytes = 0;
  std::int64_t mtime_ns = 0;  ///< last modification
};

/// The bags of a recorder writing `<prefix>_*.bag`: closed (indexed, renamed to .bag) and active
/// (`.bag.active`: open, or left unindexed by a recorder that died), each sorted by name.
struct BagFiles {
  std::vector<BagFile> closed, active;
};
BagFiles listBags(const std::string& dir, const std::string& prefix);

/// "12.3 MB" / "4.56 GB" for log lines.
std::string humanBytes(std::uint64_t bytes);

}  // namespace rig_drivers

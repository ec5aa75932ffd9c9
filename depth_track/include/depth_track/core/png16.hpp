#pragma once
/// 16-bit grayscale PNG in memory, the one libpng wrapper of the project: TUM depth files
/// (tum_io) and the compressedDepth transport both go through it. ROS-free core; thread-safe
/// (no shared state).
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <string>
#include <vector>

namespace depth_track {

/// Why PNG data could not be decoded or encoded. what() is the bare problem, without the
/// source's name: callers prefix the file or message it came from.
class Png16Error : public std::runtime_error {
 public:
  enum class Kind {
    kNotPng,       ///< the data does not start with the PNG signature
    kCorrupt,      ///< libpng rejected the data (truncated, bad CRC, bad zlib stream ...)
    kWrongFormat,  ///< a valid PNG, but not 16-bit grayscale or absurdly large
    kEncode,       ///< encoding failed (libpng error, out of memory)
  };
  Png16Error(Kind kind, const std::string& what) : std::runtime_error(what), kind_(kind) {}
  Kind kind() const { return kind_; }

 private:
  Kind kind_;
};

/// Largest image accepted (width * height), so a corrupt or hostile header cannot make the
/// decoder allocate gigabytes: 64 Mpx, far beyond any depth camera.
constexpr unsigned long long kPng16MaxPixels = 1ull << 26;

struct Png16Image {
  std::vector<std::uint16_t> pixels;  ///< width*height samples, row-major, host byte order
  int width = 0;
  int height = 0;
};

/// Decodes a 16-bit single-channel PNG (Adam7 interlaced files too). Throws Png16Error: kNotPng,
/// kCorrupt with libpng's message, or kWrongFormat naming the bit depth and colour type found
/// ("8-bit RGB") or the size.
Png16Image decodePng16(const std::uint8_t* data, std::size_t size);

/// Encodes width*height host-order samples (row-major) as a 16-bit grayscale PNG. `level` is the
/// zlib compression level 0-9, or -1 for libpng's default. Throws Png16Error (kEncode) on a size
/// that does not match, a level out of range, or a libpng failure.
std::vector<std::uint8_t> encodePng16(const std::uint16_t* pixels, std::size_t count, int width,
                                      int height, int level = -1);

inline bool hostIsLittleEndian() {
  const std::uint16_t one = 1;
  unsigned char first;
  std::memcpy(&first, &one, 1);
  return first == 1;
}

}  // namespace depth_track

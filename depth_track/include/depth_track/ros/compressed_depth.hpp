#pragma once
/// The `compressedDepth` image_transport wire format (sensor_msgs/CompressedImage on
/// `<base>/compressedDepth`), reimplemented so that Debian, which packages no
/// compressed_depth_image_transport, can send depth between machines, and stays compatible with
/// the ROS community's plugin on the other end:
///   format  "<encoding>; compressedDepth png"  (a format without a compression word is png too)
///   data    a 12-byte ConfigHeader {int32 format = 0 (inverse depth); float32 quant_a, quant_b}
///           in host (little-endian) order, then a 16-bit grayscale PNG.
/// 16UC1 / mono16 go as the PNG of the raw values (lossless). 32FC1 metres go as quantised
/// inverse depth q = round(quant_a / z + quant_b), quant_a = Q (Q + 1), quant_b = 1 - quant_a /
/// depth_max (Q = depth_quantization), q = 0 for no return, decoded z = quant_a / (q - quant_b):
/// the error is at most z^2 / (2 quant_a - z) (0.012 / 0.20 / 1.24 mm at 0.5 / 2 / 5 m with the
/// defaults).
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>

#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace depth_track {
namespace compressed_depth {

/// A payload or image the codec cannot handle; the message names what was wrong.
class CodecError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Publisher settings, with the community plugin's parameter names (read from
/// `<base>/compressedDepth/<name>`) and defaults, except png_level (the community's 9 costs ~200 ms
/// of CPU per 640x480 frame here: no 30 Hz).
struct EncoderConfig {
  double depth_max = 10.0;            ///< m; 32FC1 beyond it is sent as no return
  double depth_quantization = 100.0;  ///< Q of the inverse-depth quantisation (larger = finer)
  int png_level = 1;  ///< zlib level 0..9; 1: 5 % more bytes than 9 at 1/12 of the CPU (docs)
  std::string format = "png";  ///< compression: png only ("rvl" is not implemented)
};

/// Every problem of the settings, one message each (empty = valid).
std::vector<std::string> validate(const EncoderConfig& c);

/// The 12-byte header before the PNG.
struct ConfigHeader {
  std::int32_t format = 0;  ///< 0 = inverse depth (the only one defined)
  float quant_a = 0.0f;
  float quant_b = 0.0f;
};
constexpr std::size_t kHeaderBytes = 12;

/// The quantisation constants for 32FC1 under `c` (quant_a, quant_b).
ConfigHeader quantisationFor(const EncoderConfig& c);

/// Largest |decoded - z| of a 32FC1 depth z (m) under `c`: half a quantisation step, z^2 /
/// (2 quant_a - z), ignoring float rounding (~1e-7 z).
double maxQuantisationError(double z_m, const EncoderConfig& c);

/// Nearest 32FC1 depth (m) the quantisation can represent; closer depths are sent as no
/// return (0.15 m at the defaults).
double minRepresentableDepth(const EncoderConfig& c);

/// Image (16UC1 / mono16 / 32FC1, either byte order) -> compressedDepth message with the same
/// header. Throws CodecError naming the encoding, a size that does not fit or a bad setting.
/// Thread-safe.
sensor_msgs::CompressedImage encode(const sensor_msgs::Image& image, const EncoderConfig& c);

/// compressedDepth message -> image (16UC1 / mono16 as sent; 32FC1 metres, NaN = no return),
/// little-endian. Throws CodecError naming what is wrong: a format string that is not
/// compressedDepth png, an encoding other than 16UC1 / mono16 / 32FC1, a payload too short
/// for its header, a header of another format or with unusable constants, a PNG that is
/// truncated, corrupt, or not 16-bit grayscale. Thread-safe.
sensor_msgs::ImagePtr decode(const sensor_msgs::CompressedImage& message);

}  // namespace compressed_depth
}  // namespace depth_track

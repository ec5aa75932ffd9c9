#include "depth_track/ros/compressed_depth.hpp"

#include "depth_track/core/png16.hpp"

#include <boost/make_shared.hpp>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>

namespace depth_track {
namespace compressed_depth {
namespace {

enum class Kind { kU16, kF32 };

Kind kindOf(const std::string& encoding, const std::string& context) {
  if (encoding == "16UC1" || encoding == "mono16") return Kind::kU16;
  if (encoding == "32FC1") return Kind::kF32;
  throw CodecError(context + "encoding '" + encoding +
                   "' is not a depth encoding (16UC1, mono16 or 32FC1)");
}

std::string trim(const std::string& s) {
  const auto a = s.find_first_not_of(" \t");
  if (a == std::string::npos) return "";
  return s.substr(a, s.find_last_not_of(" \t") - a + 1);
}

// The project's one PNG codec (core/png16), with the payload's context on its errors.
std::vector<std::uint8_t> encodePayload(const std::vector<std::uint16_t>& pixels, int width,
                                        int height, int level) {
  try {
    return encodePng16(pixels.data(), pixels.size(), width, height, level);
  } catch (const Png16Error& e) {
    throw CodecError(e.what());
  }
}

Png16Image decodePayload(const std::uint8_t* data, std::size_t size) {
  try {
    return decodePng16(data, size);
  } catch (const Png16Error& e) {
    if (e.kind() == Png16Error::Kind::kNotPng)
      throw CodecError(std::string("the payload after the header is ") + e.what());
    throw CodecError(e.what());
  }
}

void checkLayout(const sensor_msgs::Image& image, std::size_t bytes_per_px) {
  if (image.is_bigendian)
    throw CodecError("image is big-endian (" + image.encoding +
                     "); only little-endian images are handled");
  if (image.width == 0 || image.height == 0)
    throw CodecError("image is empty (" + std::to_string(image.width) + "x" +
                     std::to_string(image.height) + ")");
  if (static_cast<unsigned long long>(image.width) * image.height > kPng16MaxPixels)
    throw CodecError("image of " + std::to_string(image.width) + "x" +
                     std::to_string(image.height) + " px is too large");
  if (image.step < image.width * bytes_per_px)
    throw CodecError("image step " + std::to_string(image.step) + " B is less than " +
                     std::to_string(image.width) + " px x " + std::to_string(bytes_per_px) + " B");
  if (image.data.size() != static_cast<std::size_t>(image.step) * image.height)
    throw CodecError("image holds " + std::to_string(image.data.size()) + " B, expected height " +
                     std::to_string(image.height) + " x step " + std::to_string(image.step));
}

void putHeader(const ConfigHeader& h, std::vector<std::uint8_t>* out) {
  out->resize(kHeaderBytes);
  std::memcpy(out->data(), &h.format, 4);
  std::memcpy(out->data() + 4, &h.quant_a, 4);
  std::memcpy(out->data() + 8, &h.quant_b, 4);
}

}  // namespace

std::vector<std::string> validate(const EncoderConfig& c) {
  std::vector<std::string> problems;
  if (!(std::isfinite(c.depth_max) && c.depth_max > 0.0))
    problems.push_back("depth_max " + std::to_string(c.depth_max) + " m must be positive");
  if (!(std::isfinite(c.depth_quantization) && c.depth_quantization > 0.0))
    problems.push_back("depth_quantization " + std::to_string(c.depth_quantization) +
                       " must be positive");
  if (c.png_level < 0 || c.png_level > 9)
    problems.push_back("png_level " + std::to_string(c.png_level) + " must lie in [0, 9]");
  if (c.format != "png")
    problems.push_back("format '" + c.format + "' is not supported (only png)");
  return problems;
}

ConfigHeader quantisationFor(const EncoderConfig& c) {
  ConfigHeader h;
  h.quant_a = static_cast<float>(c.depth_quantization * (c.depth_quantization + 1.0));
  h.quant_b = static_cast<float>(1.0 - h.quant_a / c.depth_max);
  return h;
}

double maxQuantisationError(double z_m, const EncoderConfig& c) {
  const double a = quantisationFor(c).quant_a;
  return z_m * z_m / (2.0 * a - z_m);
}

double minRepresentableDepth(const EncoderConfig& c) {
  const ConfigHeader h = quantisationFor(c);
  return h.quant_a / (65535.5 - h.quant_b);
}

sensor_msgs::CompressedImage encode(const sensor_msgs::Image& image, const EncoderConfig& c) {
  const auto problems = validate(c);
  if (!problems.empty()) throw CodecError("compressedDepth settings: " + problems.front());
  const Kind kind = kindOf(image.encoding, "compressedDepth: ");
  checkLayout(image, kind == Kind::kU16 ? 2 : 4);
  const int w = static_cast<int>(image.width), h = static_cast<int>(image.height);
  std::vector<std::uint16_t> pixels(static_cast<std::size_t>(w) * h);
  ConfigHeader header;
  if (kind == Kind::kU16) {
    // Every value as it is: the unit (mm, 0.25 mm, 0.2 mm) is not on the wire, so no range cut.
    for (int v = 0; v < h; ++v)
      std::memcpy(pixels.data() + static_cast<std::size_t>(v) * w,
                  image.data.data() + static_cast<std::size_t>(v) * image.step, 2 * w);
  } else {
    header = quantisationFor(c);
    const double a = header.quant_a, b = header.quant_b;
    for (int v = 0; v < h; ++v) {
      const std::uint8_t* row = image.data.data() + static_cast<std::size_t>(v) * image.step;
      for (int u = 0; u < w; ++u) {
        float z;
        std::memcpy(&z, row + 4 * u, 4);
        std::uint16_t q = 0;
        // Rounding (the community's encoder truncates) halves the error; its decoder reads both.
        if (std::isfinite(z) && z > 0.0f && z < c.depth_max) {
          const double inv = a / z + b;
          if (inv < 65535.5) q = static_cast<std::uint16_t>(std::lround(inv));
        }
        pixels[static_cast<std::size_t>(v) * w + u] = q;
      }
    }
  }
  sensor_msgs::CompressedImage out;
  out.header = image.header;
  out.format = image.encoding + "; compressedDepth png";
  putHeader(header, &out.data);
  const std::vector<std::uint8_t> png = encodePayload(pixels, w, h, c.png_level);
  out.data.insert(out.data.end(), png.begin(), png.end());
  return out;
}

sensor_msgs::ImagePtr decode(const sensor_msgs::CompressedImage& message) {
  const std::string& f = message.format;
  const auto semi = f.find(';');
  const std::string encoding = trim(f.substr(0, semi));
  if (semi != std::string::npos) {
    const std::string rest = trim(f.substr(semi + 1));
    if (rest == "compressedDepth rvl")
      throw CodecError("format '" + f + "': RVL compression is not implemented (only png)");
    if (rest != "compressedDepth" && rest != "compressedDepth png")
      throw CodecError("format '" + f +
                       "' is not compressedDepth (expected '<encoding>; compressedDepth png')");
  }
  const Kind kind = kindOf(encoding, "format '" + f + "': ");
  if (message.data.size() <= kHeaderBytes)
    throw CodecError("payload of " + std::to_string(message.data.size()) +
                     " B is too short for the 12-byte header and a PNG");
  ConfigHeader hd;
  std::memcpy(&hd.format, message.data.data(), 4);
  std::memcpy(&hd.quant_a, message.data.data() + 4, 4);
  std::memcpy(&hd.quant_b, message.data.data() + 8, 4);
  if (hd.format != 0)
    throw CodecError("header format " + std::to_string(hd.format) +
                     " is not 0 (inverse depth): no compressedDepth header before the PNG?");
  // b = 1 - a / depth_max < 1 <= q, so every nonzero q decodes to a positive depth.
  if (kind == Kind::kF32 && !(std::isfinite(hd.quant_a) && hd.quant_a > 0.0f &&
                              std::isfinite(hd.quant_b) && hd.quant_b < 1.0f))
    throw CodecError("header quantisation a = " + std::to_string(hd.quant_a) +
                     ", b = " + std::to_string(hd.quant_b) +
                     " cannot be decoded (a must be positive and b below 1)");
  const Png16Image png =
      decodePayload(message.data.data() + kHeaderBytes, message.data.size() - kHeaderBytes);

  auto image = boost::make_shared<sensor_msgs::Image>();
  image->header = message.header;
  image->encoding = encoding;
  image->width = png.width;
  image->height = png.height;
  image->is_bigendian = hostIsLittleEndian() ? 0 : 1;
  const std::size_t n = png.pixels.size();
  if (kind == Kind::kU16) {
    image->step = 2 * png.width;
    image->data.resize(2 * n);
    std::memcpy(image->data.data(), png.pixels.data(), 2 * n);
  } else {
    image->step = 4 * png.width;
    image->data.resize(4 * n);
    const double a = hd.quant_a, b = hd.quant_b;
    float* z = reinterpret_cast<float*>(image->data.data());
    for (std::size_t i = 0; i < n; ++i)
      z[i] = png.pixels[i] == 0 ? std::numeric_limits<float>::quiet_NaN()
                                : static_cast<float>(a / (png.pixels[i] - b));
  }
  return image;
}

}  // namespace compressed_depth
}  // namespace depth_track

#include "depth_track/ros/compressed_depth.hpp"

#include <png.h>

#include <boost/make_shared.hpp>

#include <cmath>
#include <csetjmp>
#include <cstdio>
#include <cstring>
#include <limits>

namespace depth_track {
namespace compressed_depth {
namespace {

// A hostile or corrupt header must not make us allocate gigabytes: 64 Mpx is far beyond any
// depth camera.
constexpr unsigned long long kMaxPixels = 1ull << 26;

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

bool hostIsLittleEndian() {
  const std::uint16_t one = 1;
  unsigned char first;
  std::memcpy(&first, &one, 1);
  return first == 1;
}

// ---- libpng in memory ---------------------------------------------------------------------------
// libpng reports errors by longjmp. The functions that call setjmp keep every C++ object outside
// the jump's reach (constructed before, reached through a pointer), and messages go into a plain
// buffer, so a jump skips no destructor and reads no clobbered local.
struct PngState {
  char message[200] = {0};
  const std::uint8_t* in = nullptr;  // reading: the payload
  std::size_t in_size = 0, in_pos = 0;
  std::vector<std::uint8_t>* out = nullptr;  // writing: the encoded bytes
  bool out_of_memory = false;
};

void pngError(png_structp png, png_const_charp msg) {
  auto* st = static_cast<PngState*>(png_get_error_ptr(png));
  std::snprintf(st->message, sizeof(st->message), "%s", msg);
  png_longjmp(png, 1);
}
void pngWarning(png_structp, png_const_charp) {}  // e.g. unknown chunks: harmless

void pngRead(png_structp png, png_bytep dst, png_size_t n) {
  auto* st = static_cast<PngState*>(png_get_io_ptr(png));
  if (st->in_size - st->in_pos < n) png_error(png, "the payload ends inside the PNG (truncated)");
  std::memcpy(dst, st->in + st->in_pos, n);
  st->in_pos += n;
}
void pngWrite(png_structp png, png_bytep src, png_size_t n) {
  auto* st = static_cast<PngState*>(png_get_io_ptr(png));
  try {
    st->out->insert(st->out->end(), src, src + n);
  } catch (const std::bad_alloc&) {
    st->out_of_memory = true;
  }
  if (st->out_of_memory) png_error(png, "out of memory");
}
void pngFlush(png_structp) {}

/// Appends `rows` (host-order 16-bit samples, `width` each) as a 16-bit grayscale PNG to *out.
/// False with st->message on a libpng error.
bool writePng(png_structp png, png_infop info, png_bytep* rows, png_uint_32 width,
              png_uint_32 height, int level, PngState* st) {
  if (setjmp(png_jmpbuf(png))) return false;
  png_set_write_fn(png, st, pngWrite, pngFlush);
  png_set_IHDR(png, info, width, height, 16, PNG_COLOR_TYPE_GRAY, PNG_INTERLACE_NONE,
               PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_set_compression_level(png, level);
  png_write_info(png, info);
  if (hostIsLittleEndian()) png_set_swap(png);  // PNG stores 16-bit samples big-endian
  png_write_image(png, rows);
  png_write_end(png, nullptr);
  return true;
}

std::vector<std::uint8_t> encodePng16(const std::vector<std::uint16_t>& pixels, int width,
                                      int height, int level) {
  std::vector<std::uint8_t> out;
  out.reserve(pixels.size());
  std::vector<png_bytep> rows(static_cast<std::size_t>(height));
  for (int v = 0; v < height; ++v)
    rows[v] = reinterpret_cast<png_bytep>(const_cast<std::uint16_t*>(pixels.data()) +
                                          static_cast<std::size_t>(v) * width);
  PngState st;
  st.out = &out;
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, &st, pngError, pngWarning);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  if (!info) {
    png_destroy_write_struct(&png, nullptr);
    throw CodecError("cannot create a PNG writer");
  }
  const bool ok = writePng(png, info, rows.data(), static_cast<png_uint_32>(width),
                           static_cast<png_uint_32>(height), level, &st);
  png_destroy_write_struct(&png, &info);
  if (!ok) throw CodecError(std::string("PNG encoding failed: ") + st.message);
  return out;
}

struct DecodedPng {
  std::vector<std::uint16_t> pixels;
  std::vector<png_bytep> rows;
  png_uint_32 width = 0, height = 0;
  char wrong_format[120] = {0};  // set when the PNG is valid but not 16-bit grayscale
};

bool readPng(png_structp png, png_infop info, PngState* st, DecodedPng* d) {
  if (setjmp(png_jmpbuf(png))) return false;
  png_set_read_fn(png, st, pngRead);
  png_read_info(png, info);
  int bit_depth = 0, colour_type = 0;
  png_get_IHDR(png, info, &d->width, &d->height, &bit_depth, &colour_type, nullptr, nullptr,
               nullptr);
  if (bit_depth != 16 || colour_type != PNG_COLOR_TYPE_GRAY) {
    std::snprintf(d->wrong_format, sizeof(d->wrong_format), "a %d-bit PNG of colour type %d",
                  bit_depth, colour_type);
    return true;
  }
  if (static_cast<unsigned long long>(d->width) * d->height > kMaxPixels) {
    std::snprintf(d->wrong_format, sizeof(d->wrong_format), "a %lux%lu PNG (more than %llu px)",
                  static_cast<unsigned long>(d->width), static_cast<unsigned long>(d->height),
                  kMaxPixels);
    return true;
  }
  if (hostIsLittleEndian()) png_set_swap(png);
  png_set_interlace_handling(png);
  png_read_update_info(png, info);
  d->pixels.resize(static_cast<std::size_t>(d->width) * d->height);
  d->rows.resize(d->height);
  for (png_uint_32 v = 0; v < d->height; ++v)
    d->rows[v] =
        reinterpret_cast<png_bytep>(d->pixels.data() + static_cast<std::size_t>(v) * d->width);
  png_read_image(png, d->rows.data());
  png_read_end(png, nullptr);
  return true;
}

DecodedPng decodePng16(const std::uint8_t* data, std::size_t size) {
  if (size < 8 || png_sig_cmp(const_cast<png_bytep>(data), 0, 8) != 0)
    throw CodecError("the payload after the header is not a PNG (bad signature)");
  PngState st;
  st.in = data;
  st.in_size = size;
  DecodedPng d;
  png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &st, pngError, pngWarning);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  if (!info) {
    png_destroy_read_struct(&png, nullptr, nullptr);
    throw CodecError("cannot create a PNG reader");
  }
  const bool ok = readPng(png, info, &st, &d);
  png_destroy_read_struct(&png, &info, nullptr);
  if (!ok) throw CodecError(std::string("corrupt PNG: ") + st.message);
  if (d.wrong_format[0] != '\0')
    throw CodecError(std::string("expected a 16-bit grayscale PNG, found ") + d.wrong_format);
  return d;
}

void checkLayout(const sensor_msgs::Image& image, std::size_t bytes_per_px) {
  if (image.is_bigendian)
    throw CodecError("image is big-endian (" + image.encoding +
                     "); only little-endian images are handled");
  if (image.width == 0 || image.height == 0)
    throw CodecError("image is empty (" + std::to_string(image.width) + "x" +
                     std::to_string(image.height) + ")");
  if (static_cast<unsigned long long>(image.width) * image.height > kMaxPixels)
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
  const std::vector<std::uint8_t> png = encodePng16(pixels, w, h, c.png_level);
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
  const DecodedPng png =
      decodePng16(message.data.data() + kHeaderBytes, message.data.size() - kHeaderBytes);

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

#include "depth_track/core/png16.hpp"

#include <png.h>

#include <csetjmp>
#include <cstdio>
#include <new>

namespace depth_track {
namespace {

// libpng reports errors by longjmp. The functions that call setjmp keep every C++ object outside
// the jump's reach (constructed before, reached through a pointer), and messages go into a plain
// buffer, so a jump skips no destructor and reads no clobbered local.
struct PngState {
  char message[200] = {0};
  const std::uint8_t* in = nullptr;  // reading: the data
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
  if (st->in_size - st->in_pos < n) png_error(png, "the data ends inside the PNG (truncated)");
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

const char* colourTypeName(int colour_type) {
  switch (colour_type) {
    case PNG_COLOR_TYPE_GRAY:
      return "grayscale";
    case PNG_COLOR_TYPE_GRAY_ALPHA:
      return "grayscale+alpha";
    case PNG_COLOR_TYPE_RGB:
      return "RGB";
    case PNG_COLOR_TYPE_RGB_ALPHA:
      return "RGBA";
    case PNG_COLOR_TYPE_PALETTE:
      return "palette";
    default:
      return "unknown colour type";
  }
}

struct Decoded {
  std::vector<std::uint16_t> pixels;
  std::vector<png_bytep> rows;
  png_uint_32 width = 0, height = 0;
  char wrong_format[120] = {0};  // set when the PNG is valid but not what we read
};

bool readPng(png_structp png, png_infop info, PngState* st, Decoded* d) {
  if (setjmp(png_jmpbuf(png))) return false;
  png_set_read_fn(png, st, pngRead);
  png_read_info(png, info);
  int bit_depth = 0, colour_type = 0;
  png_get_IHDR(png, info, &d->width, &d->height, &bit_depth, &colour_type, nullptr, nullptr,
               nullptr);
  if (bit_depth != 16 || colour_type != PNG_COLOR_TYPE_GRAY) {
    std::snprintf(d->wrong_format, sizeof(d->wrong_format), "%d-bit %s", bit_depth,
                  colourTypeName(colour_type));
    return true;
  }
  if (static_cast<unsigned long long>(d->width) * d->height > kPng16MaxPixels) {
    std::snprintf(d->wrong_format, sizeof(d->wrong_format), "a %lux%lu image (more than %llu px)",
                  static_cast<unsigned long>(d->width), static_cast<unsigned long>(d->height),
                  kPng16MaxPixels);
    return true;
  }
  if (hostIsLittleEndian()) png_set_swap(png);  // PNG stores 16-bit samples big-endian
  png_set_interlace_handling(png);              // Adam7 files are read whole as well
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

bool writePng(png_structp png, png_infop info, png_bytep* rows, png_uint_32 width,
              png_uint_32 height, int level, PngState* st) {
  if (setjmp(png_jmpbuf(png))) return false;
  png_set_write_fn(png, st, pngWrite, pngFlush);
  png_set_IHDR(png, info, width, height, 16, PNG_COLOR_TYPE_GRAY, PNG_INTERLACE_NONE,
               PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  if (level >= 0) png_set_compression_level(png, level);
  png_write_info(png, info);
  if (hostIsLittleEndian()) png_set_swap(png);
  png_write_image(png, rows);
  png_write_end(png, nullptr);
  return true;
}

}  // namespace

Png16Image decodePng16(const std::uint8_t* data, std::size_t size) {
  using Kind = Png16Error::Kind;
  if (data == nullptr || size < 8 || png_sig_cmp(const_cast<png_bytep>(data), 0, 8) != 0)
    throw Png16Error(Kind::kNotPng, "not a PNG file (bad signature)");
  PngState st;
  st.in = data;
  st.in_size = size;
  Decoded d;
  png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &st, pngError, pngWarning);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  if (!info) {
    png_destroy_read_struct(&png, nullptr, nullptr);
    throw Png16Error(Kind::kCorrupt, "cannot create a PNG reader");
  }
  const bool ok = readPng(png, info, &st, &d);
  png_destroy_read_struct(&png, &info, nullptr);
  if (!ok) throw Png16Error(Kind::kCorrupt, std::string("corrupt PNG (") + st.message + ")");
  if (d.wrong_format[0] != '\0')
    throw Png16Error(Kind::kWrongFormat,
                     std::string("expected a 16-bit grayscale depth PNG, found ") + d.wrong_format);
  Png16Image image;
  image.pixels = std::move(d.pixels);
  image.width = static_cast<int>(d.width);
  image.height = static_cast<int>(d.height);
  return image;
}

std::vector<std::uint8_t> encodePng16(const std::uint16_t* pixels, std::size_t count, int width,
                                      int height, int level) {
  using Kind = Png16Error::Kind;
  if (width <= 0 || height <= 0 ||
      count != static_cast<std::size_t>(width) * static_cast<std::size_t>(height)) {
    throw Png16Error(Kind::kEncode, "cannot write PNG: " + std::to_string(count) +
                                        " values for a " + std::to_string(width) + "x" +
                                        std::to_string(height) + " image");
  }
  if (level < -1 || level > 9)
    throw Png16Error(Kind::kEncode,
                     "PNG compression level " + std::to_string(level) + " must lie in [-1, 9]");
  std::vector<std::uint8_t> out;
  out.reserve(count);
  std::vector<png_bytep> rows(static_cast<std::size_t>(height));
  for (int v = 0; v < height; ++v)
    rows[v] = reinterpret_cast<png_bytep>(const_cast<std::uint16_t*>(pixels) +
                                          static_cast<std::size_t>(v) * width);
  PngState st;
  st.out = &out;
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, &st, pngError, pngWarning);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  if (!info) {
    png_destroy_write_struct(&png, nullptr);
    throw Png16Error(Kind::kEncode, "cannot create a PNG writer");
  }
  const bool ok = writePng(png, info, rows.data(), static_cast<png_uint_32>(width),
                           static_cast<png_uint_32>(height), level, &st);
  png_destroy_write_struct(&png, &info);
  if (!ok) throw Png16Error(Kind::kEncode, std::string("PNG encoding failed (") + st.message + ")");
  return out;
}

}  // namespace depth_track

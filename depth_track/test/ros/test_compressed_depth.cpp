// The compressedDepth codec (no roscore): 16UC1 / mono16 round trips bit for bit; 32FC1 comes
// back within half an inverse-depth quantisation step (the documented z^2 / (2a - z)) at 0.5, 2
// and 5 m; a payload quantised the community encoder's way (truncating, legacy format string)
// decodes within its step; every kind of bad payload or image is a CodecError naming the
// problem, and random damage never crashes the decoder.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <random>

#include "depth_track/ros/compressed_depth.hpp"

using namespace depth_track;
namespace cd = depth_track::compressed_depth;

namespace {

sensor_msgs::Image image16(int w, int h, const std::string& encoding = "16UC1") {
  sensor_msgs::Image img;
  img.header.stamp = ros::Time(1234, 5678);
  img.header.frame_id = "camera_depth_optical_frame";
  img.encoding = encoding;
  img.width = w;
  img.height = h;
  img.step = 2 * w;
  img.data.resize(img.step * h);
  // A tilted plane with noise and holes (what a depth camera sends), plus the extremes.
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, 4.0);
  std::vector<std::uint16_t> px(static_cast<std::size_t>(w) * h);
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      double d = 4000 + 6 * u + 3 * v + noise(rng);
      if ((u * 7 + v * 13) % 97 == 0) d = 0;
      px[v * w + u] = static_cast<std::uint16_t>(d);
    }
  px[0] = 65535;
  px[1] = 1;
  std::memcpy(img.data.data(), px.data(), img.data.size());
  return img;
}

sensor_msgs::Image image32(const std::vector<float>& z, int w) {
  sensor_msgs::Image img;
  img.header.stamp = ros::Time(42, 0);
  img.encoding = "32FC1";
  img.width = w;
  img.height = static_cast<std::uint32_t>(z.size() / w);
  img.step = 4 * w;
  img.data.resize(z.size() * 4);
  std::memcpy(img.data.data(), z.data(), img.data.size());
  return img;
}

std::vector<float> floats(const sensor_msgs::Image& img) {
  std::vector<float> z(img.data.size() / 4);
  std::memcpy(z.data(), img.data.data(), img.data.size());
  return z;
}

std::string errorOf(const sensor_msgs::CompressedImage& m) {
  try {
    cd::decode(m);
  } catch (const cd::CodecError& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(CompressedDepth, Unsigned16RoundTripIsExact) {
  for (const std::string enc : {"16UC1", "mono16"}) {
    const sensor_msgs::Image in = image16(640, 480, enc);
    const sensor_msgs::CompressedImage c = cd::encode(in, cd::EncoderConfig{});
    EXPECT_EQ(c.format, enc + "; compressedDepth png");
    EXPECT_EQ(c.header.stamp, in.header.stamp);
    EXPECT_EQ(c.header.frame_id, in.header.frame_id);
    std::int32_t format = -1;
    std::memcpy(&format, c.data.data(), 4);
    EXPECT_EQ(format, 0);
    EXPECT_EQ(std::memcmp(c.data.data() + cd::kHeaderBytes, "\x89PNG", 4), 0);
    // A noisy plane still compresses (the PNG filters predict the slope).
    EXPECT_LT(c.data.size(), in.data.size() * 0.7) << c.data.size() << " B";
    const sensor_msgs::ImagePtr out = cd::decode(c);
    EXPECT_EQ(out->encoding, enc);
    EXPECT_EQ(out->width, in.width);
    EXPECT_EQ(out->height, in.height);
    EXPECT_EQ(out->step, in.step);
    EXPECT_EQ(out->is_bigendian, 0);
    EXPECT_EQ(out->header.stamp, in.header.stamp);
    EXPECT_TRUE(out->data == in.data) << "16-bit depth must come back bit for bit";
  }
  // A padded row (step > width * 2) is sent without its padding and comes back packed.
  sensor_msgs::Image padded = image16(5, 3);
  sensor_msgs::Image wide = padded;
  wide.step = 16;
  wide.data.assign(wide.step * wide.height, 0xEE);
  for (int v = 0; v < 3; ++v) std::memcpy(&wide.data[v * 16], &padded.data[v * 10], 10);
  EXPECT_TRUE(cd::decode(cd::encode(wide, cd::EncoderConfig{}))->data == padded.data);
}

TEST(CompressedDepth, FloatDepthWithinTheQuantisationError) {
  const cd::EncoderConfig c;  // Q = 100, depth_max 10 m: a = 10100
  const double a = 100.0 * 101.0;
  // The documented figures: half a step at 0.5 / 2 / 5 m.
  EXPECT_NEAR(cd::maxQuantisationError(0.5, c), 0.25 / (2 * a - 0.5), 1e-12);
  EXPECT_NEAR(cd::maxQuantisationError(0.5, c) * 1e3, 0.0124, 0.0001);
  EXPECT_NEAR(cd::maxQuantisationError(2.0, c) * 1e3, 0.198, 0.001);
  EXPECT_NEAR(cd::maxQuantisationError(5.0, c) * 1e3, 1.238, 0.001);
  std::mt19937 rng(3);
  for (const double z0 : {0.5, 2.0, 5.0}) {
    std::uniform_real_distribution<double> near(z0 * 0.99, z0 * 1.01);
    std::vector<float> z(200 * 100);
    for (auto& v : z) v = static_cast<float>(near(rng));
    const sensor_msgs::ImagePtr out = cd::decode(cd::encode(image32(z, 200), c));
    ASSERT_EQ(out->encoding, "32FC1");
    const std::vector<float> back = floats(*out);
    ASSERT_EQ(back.size(), z.size());
    double worst = 0.0, worst_ratio = 0.0;
    for (std::size_t i = 0; i < z.size(); ++i) {
      const double err = std::abs(double(back[i]) - z[i]);
      const double bound = cd::maxQuantisationError(z[i], c) + 1e-6 * z[i];  // + float rounding
      ASSERT_LE(err, bound) << "z " << z[i] << " m came back as " << back[i];
      worst = std::max(worst, err);
      worst_ratio = std::max(worst_ratio, err / cd::maxQuantisationError(z[i], c));
    }
    // 20000 uniform depths hit the half-step bound closely: the quantisation is real, and a
    // truncating one (twice the error) would have failed above.
    EXPECT_GT(worst_ratio, 0.95) << "at " << z0 << " m";
    std::printf("32FC1 at %.1f m: max error %.4f mm (bound %.4f mm)\n", z0, worst * 1e3,
                cd::maxQuantisationError(z0 * 1.01, c) * 1e3);
  }
  // No return stays no return: NaN, Inf, 0, negative, beyond depth_max, closer than the
  // nearest representable depth; just inside the limits survives.
  const double zmin = cd::minRepresentableDepth(c);
  EXPECT_NEAR(zmin, a / (65535.5 - (1.0 - a / 10.0)), 1e-6);
  const std::vector<float> special = {NAN,
                                      INFINITY,
                                      0.0f,
                                      -1.0f,
                                      10.0f,
                                      12.0f,
                                      static_cast<float>(zmin * 0.99),
                                      static_cast<float>(zmin * 1.01),
                                      9.99f};
  const std::vector<float> back = floats(*cd::decode(cd::encode(image32(special, 9), c)));
  for (int i = 0; i < 7; ++i) EXPECT_TRUE(std::isnan(back[i])) << i << ": " << back[i];
  EXPECT_NEAR(back[7], zmin * 1.01, 1e-5);
  EXPECT_NEAR(back[8], 9.99, cd::maxQuantisationError(9.99, c) + 1e-5);
  // Doubling Q quarters the error (a ~ Q^2).
  cd::EncoderConfig fine;
  fine.depth_quantization = 200.0;
  EXPECT_NEAR(cd::maxQuantisationError(5.0, fine) / cd::maxQuantisationError(5.0, c), 0.25, 0.01);
}

TEST(CompressedDepth, DecodesTheCommunityEncodersTruncatedQuantisation) {
  // compressed_depth_image_transport truncates a / z + b and older versions write the format
  // without the compression word. Build such a payload: the q image as 16UC1, then the header
  // and format of a 32FC1 message.
  const cd::ConfigHeader h = cd::quantisationFor(cd::EncoderConfig{});
  std::vector<float> z = {0.5f, 1.0f, 2.0f, 3.3f, 5.0f, 7.5f};
  sensor_msgs::Image q = image16(6, 1);
  std::vector<std::uint16_t> qv;
  for (float d : z) qv.push_back(static_cast<std::uint16_t>(h.quant_a / d + h.quant_b));
  std::memcpy(q.data.data(), qv.data(), 12);
  sensor_msgs::CompressedImage m = cd::encode(q, cd::EncoderConfig{});
  m.format = "32FC1; compressedDepth";
  std::memcpy(m.data.data() + 4, &h.quant_a, 4);
  std::memcpy(m.data.data() + 8, &h.quant_b, 4);
  const std::vector<float> back = floats(*cd::decode(m));
  for (std::size_t i = 0; i < z.size(); ++i) {
    // Truncation only ever decodes farther, by less than one step z^2 / (a - z).
    EXPECT_GE(back[i], z[i] - 1e-6f);
    EXPECT_LE(back[i] - z[i], z[i] * z[i] / (h.quant_a - z[i]) + 1e-6);
  }
}

TEST(CompressedDepth, BadPayloadsAreNamedErrors) {
  const sensor_msgs::CompressedImage good = cd::encode(image16(64, 48), cd::EncoderConfig{});
  ASSERT_EQ(errorOf(good), "");

  sensor_msgs::CompressedImage m = good;
  m.data.resize(cd::kHeaderBytes + (good.data.size() - cd::kHeaderBytes) / 2);
  EXPECT_NE(errorOf(m).find("truncated"), std::string::npos) << errorOf(m);

  m = good;
  m.data.resize(cd::kHeaderBytes);
  EXPECT_NE(errorOf(m).find("too short"), std::string::npos) << errorOf(m);

  m = good;
  const std::int32_t seven = 7;
  std::memcpy(m.data.data(), &seven, 4);
  EXPECT_NE(errorOf(m).find("header format 7"), std::string::npos) << errorOf(m);

  m = good;  // the `compressed` transport's PNG: no header before the signature
  m.data.erase(m.data.begin(), m.data.begin() + cd::kHeaderBytes);
  EXPECT_NE(errorOf(m).find("no compressedDepth header"), std::string::npos) << errorOf(m);

  m = good;  // header fine, but what follows is no PNG
  m.data[cd::kHeaderBytes + 1] = 'X';
  EXPECT_NE(errorOf(m).find("not a PNG"), std::string::npos) << errorOf(m);

  m = good;  // damaged inside the compressed image data: libpng's CRC / zlib check
  m.data[m.data.size() / 2] ^= 0x5A;
  EXPECT_NE(errorOf(m).find("corrupt PNG"), std::string::npos) << errorOf(m);

  m = good;  // 32FC1 with the quantisation constants zeroed
  m.format = "32FC1; compressedDepth png";
  EXPECT_NE(errorOf(m).find("cannot be decoded"), std::string::npos) << errorOf(m);

  for (const std::string f : {"rgb8; jpeg compressed bgr8", "16UC1; compressed png", "png"}) {
    m = good;
    m.format = f;
    const std::string e = errorOf(m);
    EXPECT_NE(e.find(f), std::string::npos) << f << " -> " << e;
  }
  m = good;
  m.format = "bgr8; compressedDepth png";
  EXPECT_NE(errorOf(m).find("'bgr8' is not a depth encoding"), std::string::npos) << errorOf(m);
  m = good;
  m.format = "16UC1; compressedDepth rvl";
  EXPECT_NE(errorOf(m).find("RVL"), std::string::npos) << errorOf(m);
}

TEST(CompressedDepth, RandomDamageNeverCrashes) {
  const sensor_msgs::CompressedImage good = cd::encode(image16(80, 60), cd::EncoderConfig{});
  std::mt19937 rng(11);
  int errors = 0, decoded = 0;
  for (std::size_t len = 0; len < good.data.size(); len += 37) {
    sensor_msgs::CompressedImage m = good;
    m.data.resize(len);
    errorOf(m).empty() ? ++decoded : ++errors;
  }
  for (int i = 0; i < 300; ++i) {
    sensor_msgs::CompressedImage m = good;
    for (int k = 0; k < 1 + i % 4; ++k)
      m.data[std::uniform_int_distribution<std::size_t>(0, m.data.size() - 1)(rng)] ^=
          static_cast<std::uint8_t>(1 + rng() % 255);
    try {
      const sensor_msgs::ImagePtr img = cd::decode(m);
      EXPECT_EQ(img->data.size(), static_cast<std::size_t>(img->step) * img->height);
      ++decoded;
    } catch (const cd::CodecError&) {
      ++errors;
    }
  }
  EXPECT_GT(errors, 250) << "truncations and most flips must be detected (PNG CRCs, zlib)";
  std::printf("random damage: %d errors, %d decoded\n", errors, decoded);
}

TEST(CompressedDepth, BadImagesAndSettingsAreNamed) {
  sensor_msgs::Image rgb = image16(4, 4);
  rgb.encoding = "rgb8";
  try {
    cd::encode(rgb, cd::EncoderConfig{});
    ADD_FAILURE() << "rgb8 encoded";
  } catch (const cd::CodecError& e) {
    EXPECT_NE(std::string(e.what()).find("'rgb8' is not a depth encoding"), std::string::npos)
        << e.what();
  }
  sensor_msgs::Image shortimg = image16(4, 4);
  shortimg.data.resize(10);
  EXPECT_THROW(cd::encode(shortimg, cd::EncoderConfig{}), cd::CodecError);
  sensor_msgs::Image big = image16(4, 4);
  big.is_bigendian = 1;
  EXPECT_THROW(cd::encode(big, cd::EncoderConfig{}), cd::CodecError);

  cd::EncoderConfig bad;
  bad.png_level = 12;
  bad.depth_max = -1;
  bad.format = "rvl";
  const auto problems = cd::validate(bad);
  ASSERT_EQ(problems.size(), 3u);
  EXPECT_NE(problems[0].find("depth_max"), std::string::npos);
  EXPECT_NE(problems[1].find("png_level 12 must lie in [0, 9]"), std::string::npos);
  EXPECT_NE(problems[2].find("rvl"), std::string::npos);
  EXPECT_THROW(cd::encode(image16(4, 4), bad), cd::CodecError);
}

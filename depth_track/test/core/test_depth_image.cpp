#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <limits>

#include "depth_track/core/camera.hpp"
#include "depth_track/core/depth_image.hpp"

using namespace depth_track;

TEST(DepthImage, U16ScaleAndRange) {
  const std::uint16_t raw[4] = {0, 1000, 5000, 30000};  // 0 m, 0.2 m, 1 m, 6 m at 1/5000 m
  DepthRange range{0.5, 4.0};
  DepthImage d = depthFromRaw(raw, 4, 1, 8, DepthEncoding::kU16, 1.0 / 5000.0, range);
  EXPECT_EQ(d.at(0, 0), 0.0f);          // no return
  EXPECT_EQ(d.at(1, 0), 0.0f);          // below d_min
  EXPECT_FLOAT_EQ(d.at(2, 0), 1.0f);    // 5000 units * 0.2 mm
  EXPECT_EQ(d.at(3, 0), 0.0f);          // beyond d_max
  EXPECT_EQ(d.countValid(), 1u);
}

TEST(DepthImage, F32NanInfBecomeNoReturn) {
  const float raw[4] = {std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity(),
                        1.5f, -1.0f};
  DepthImage d = depthFromRaw(raw, 2, 2, 8, DepthEncoding::kF32, 1.0, DepthRange{});
  EXPECT_EQ(d.at(0, 0), 0.0f);
  EXPECT_EQ(d.at(1, 0), 0.0f);
  EXPECT_FLOAT_EQ(d.at(0, 1), 1.5f);
  EXPECT_EQ(d.at(1, 1), 0.0f);
}

TEST(DepthImage, RowStridePaddingIsSkipped) {
  // 2x2 frame of 16-bit depth with 2 bytes of padding per row.
  const std::uint16_t raw[6] = {1000, 2000, 0xFFFF, 3000, 4000, 0xFFFF};
  DepthImage d = depthFromRaw(raw, 2, 2, 6, DepthEncoding::kU16, 0.001, DepthRange{0.1, 10.0});
  EXPECT_FLOAT_EQ(d.at(0, 1), 3.0f);
  EXPECT_FLOAT_EQ(d.at(1, 1), 4.0f);
}

TEST(DepthImage, BadInputIsNamed) {
  EXPECT_THROW(parseDepthEncoding("bgr8"), DepthInputError);
  try {
    parseDepthEncoding("8UC3");
    ADD_FAILURE() << "parseDepthEncoding(\"8UC3\") accepted a colour encoding";
  } catch (const DepthInputError& e) {
    EXPECT_NE(std::string(e.what()).find("8UC3"), std::string::npos) << e.what();
  }
  const std::uint16_t raw[4] = {};
  EXPECT_THROW(depthFromRaw(raw, 4, 1, 4, DepthEncoding::kU16, 0.001, DepthRange{}), DepthInputError);
  EXPECT_THROW(depthFromRaw(nullptr, 4, 1, 8, DepthEncoding::kU16, 0.001, DepthRange{}), DepthInputError);
  EXPECT_THROW(depthFromRaw(raw, 4, 1, 8, DepthEncoding::kU16, 0.0, DepthRange{}), DepthInputError);
  PinholeIntrinsics k = PinholeIntrinsics::isotropic(640, 480, 600.0);
  EXPECT_THROW(checkFrameSize(DepthImage(320, 240), k), DepthInputError);
  EXPECT_NO_THROW(checkFrameSize(DepthImage(640, 480), k));
}

TEST(Camera, ProjectInvertsBackProject) {
  PinholeIntrinsics k{640, 480, 535.4, 539.2, 320.1, 247.6};
  EXPECT_TRUE(k.validate().empty());
  const Eigen::Vector3f p = k.backProject(100.25f, 400.5f, 2.0f);
  float u, v;
  ASSERT_TRUE(k.project(p, &u, &v));
  EXPECT_NEAR(u, 100.25f, 1e-3f);
  EXPECT_NEAR(v, 400.5f, 1e-3f);
  EXPECT_FALSE(k.project(Eigen::Vector3f(0, 0, -1), &u, &v));
  PinholeIntrinsics bad{0, 480, -1.0, 500, 320, 240};
  EXPECT_EQ(bad.validate().size(), 3u);
}

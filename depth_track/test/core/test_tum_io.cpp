#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "depth_track/core/png16.hpp"
#include "depth_track/core/tum_io.hpp"
#include "../shared_data.hpp"

using namespace depth_track;

namespace {

std::string tempDir() {
  static std::string dir = [] {
    std::string templ = testing::TempDir() + "dt_tum_io_XXXXXX";
    std::vector<char> buf(templ.begin(), templ.end());
    buf.push_back('\0');
    const char* made = mkdtemp(buf.data());
    return std::string(made != nullptr ? made : "/tmp");
  }();
  return dir;
}

void writeText(const std::string& path, const std::string& text) {
  std::ofstream out(path);
  out << text;
}

void writeBytes(const std::string& path, const std::vector<unsigned char>& bytes) {
  std::ofstream out(path, std::ios::binary);
  out.write(reinterpret_cast<const char*>(bytes.data()),
            static_cast<std::streamsize>(bytes.size()));
}

// Expects `fn` to throw FileFormatError whose message contains every string in `parts`.
template <typename Fn>
void expectFileError(Fn fn, const std::vector<std::string>& parts) {
  try {
    fn();
    ADD_FAILURE() << "no FileFormatError thrown";
  } catch (const FileFormatError& e) {
    const std::string msg = e.what();
    for (const auto& p : parts) EXPECT_NE(msg.find(p), std::string::npos) << msg << " lacks " << p;
  }
}

}  // namespace

TEST(Png16, RoundTripKeepsEveryValue) {
  const int w = 7, h = 3;
  std::vector<std::uint16_t> data(w * h);
  for (int i = 0; i < w * h; ++i) data[i] = static_cast<std::uint16_t>(i * 3121 % 65536);
  data[0] = 0;
  data[1] = 65535;
  data[2] = 1;    // low byte only: catches a missing byte swap
  data[3] = 256;  // high byte only
  const std::string path = tempDir() + "/round.png";
  writePng16(path, data, w, h);
  int rw = 0, rh = 0;
  const auto back = readPng16(path, &rw, &rh);
  EXPECT_EQ(rw, w);
  EXPECT_EQ(rh, h);
  EXPECT_EQ(back, data);
}

TEST(Png16, WrongFormatsAreNamed) {
  // A 2x1 8-bit grayscale PNG and a 1x1 16-bit RGB PNG, built byte by byte.
  const std::vector<unsigned char> gray8 = {
      0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x48,
      0x44, 0x52, 0x00, 0x00, 0x00, 0x02, 0x00, 0x00, 0x00, 0x01, 0x08, 0x00, 0x00, 0x00,
      0x00, 0xd1, 0x49, 0x20, 0x56, 0x00, 0x00, 0x00, 0x0b, 0x49, 0x44, 0x41, 0x54, 0x78,
      0x9c, 0x63, 0x10, 0x50, 0x00, 0x00, 0x00, 0x43, 0x00, 0x31, 0xea, 0xdd, 0xb3, 0xcd,
      0x00, 0x00, 0x00, 0x00, 0x49, 0x45, 0x4e, 0x44, 0xae, 0x42, 0x60, 0x82};
  const std::vector<unsigned char> rgb16 = {
      0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x48, 0x44,
      0x52, 0x00, 0x00, 0x00, 0x01, 0x00, 0x00, 0x00, 0x01, 0x10, 0x02, 0x00, 0x00, 0x00, 0xc0,
      0xe7, 0x8f, 0x9d, 0x00, 0x00, 0x00, 0x0f, 0x49, 0x44, 0x41, 0x54, 0x78, 0x9c, 0x63, 0x60,
      0x64, 0x62, 0x66, 0x61, 0x65, 0x03, 0x00, 0x00, 0x3f, 0x00, 0x16, 0x21, 0xba, 0xd4, 0x54,
      0x00, 0x00, 0x00, 0x00, 0x49, 0x45, 0x4e, 0x44, 0xae, 0x42, 0x60, 0x82};
  const std::string p8 = tempDir() + "/gray8.png", prgb = tempDir() + "/rgb16.png";
  writeBytes(p8, gray8);
  writeBytes(prgb, rgb16);
  int w, h;
  expectFileError([&] { readPng16(p8, &w, &h); }, {"gray8.png", "8-bit", "grayscale"});
  expectFileError([&] { readPng16(prgb, &w, &h); }, {"rgb16.png", "16-bit", "RGB"});

  const std::string text = tempDir() + "/not_a.png";
  writeText(text, "hello, this is text\n");
  expectFileError([&] { readPng16(text, &w, &h); }, {"not_a.png", "not a PNG"});
  expectFileError([&] { readPng16(tempDir() + "/missing.png", &w, &h); }, {"missing.png"});
  // Truncated after the header: libpng's own error surfaces with the file name, no crash.
  std::vector<unsigned char> cut(rgb16.begin(), rgb16.begin() + 40);
  writeBytes(tempDir() + "/cut.png", cut);
  expectFileError([&] { readPng16(tempDir() + "/cut.png", &w, &h); }, {"cut.png"});
  EXPECT_THROW(writePng16(tempDir() + "/bad.png", std::vector<std::uint16_t>(5), 2, 2),
               FileFormatError);
}

TEST(Png16, EveryTruncationAndCorruptionIsAnError) {
  // A small valid depth PNG, then every strict prefix of it and a flipped byte at every
  // position: each must end in FileFormatError naming the file (libpng's longjmp path), never a
  // crash or a silently wrong image.
  std::vector<std::uint16_t> data(16 * 8);
  for (std::size_t i = 0; i < data.size(); ++i) data[i] = static_cast<std::uint16_t>(i * 977);
  const std::string good = tempDir() + "/good.png";
  writePng16(good, data, 16, 8);
  std::ifstream in(good, std::ios::binary);
  const std::vector<unsigned char> bytes((std::istreambuf_iterator<char>(in)),
                                         std::istreambuf_iterator<char>());
  ASSERT_GT(bytes.size(), 60u);
  const std::string bad = tempDir() + "/bad_bytes.png";
  int w, h;
  for (std::size_t n = 0; n < bytes.size(); ++n) {
    writeBytes(bad, std::vector<unsigned char>(bytes.begin(), bytes.begin() + n));
    expectFileError([&] { readPng16(bad, &w, &h); }, {"bad_bytes.png"});
  }
  int undetected = 0;
  for (std::size_t i = 8; i < bytes.size(); ++i) {
    std::vector<unsigned char> flipped = bytes;
    flipped[i] ^= 0x5a;
    writeBytes(bad, flipped);
    try {
      const auto v = readPng16(bad, &w, &h);
      // Only bytes libpng does not check can slip through (e.g. ancillary parts); they must
      // then still decode to the original image.
      if (v != data) ++undetected;
    } catch (const FileFormatError& e) {
      EXPECT_NE(std::string(e.what()).find("bad_bytes.png"), std::string::npos);
    }
  }
  EXPECT_EQ(undetected, 0);
}

TEST(Png16, InMemoryCodecRoundTripsAndNamesEachKindOfError) {
  // The codec tum_io and the compressedDepth transport share: every level round-trips
  // exactly; each failure carries the kind its callers map to their own messages.
  std::vector<std::uint16_t> data(7 * 3);
  for (std::size_t i = 0; i < data.size(); ++i) data[i] = static_cast<std::uint16_t>(65535 - i * 3001);
  for (int level : {-1, 0, 9}) {
    const auto bytes = encodePng16(data.data(), data.size(), 7, 3, level);
    const Png16Image back = decodePng16(bytes.data(), bytes.size());
    EXPECT_EQ(back.width, 7);
    EXPECT_EQ(back.height, 3);
    EXPECT_EQ(back.pixels, data) << "level " << level;
  }
  auto kindOf = [](auto&& f) {
    try {
      f();
    } catch (const Png16Error& e) {
      return e.kind();
    }
    ADD_FAILURE() << "no Png16Error";
    return Png16Error::Kind::kEncode;
  };
  using K = Png16Error::Kind;
  EXPECT_EQ(kindOf([&] { encodePng16(data.data(), data.size(), 7, 2); }), K::kEncode);
  EXPECT_EQ(kindOf([&] { encodePng16(data.data(), data.size(), 7, 3, 10); }), K::kEncode);
  const std::uint8_t text[] = "not a png at all";
  EXPECT_EQ(kindOf([&] { decodePng16(text, sizeof(text)); }), K::kNotPng);
  EXPECT_EQ(kindOf([&] { decodePng16(nullptr, 0); }), K::kNotPng);
  const auto bytes = encodePng16(data.data(), data.size(), 7, 3);
  EXPECT_EQ(kindOf([&] { decodePng16(bytes.data(), bytes.size() / 2); }), K::kCorrupt);
}

TEST(Png16, InterlacedFileIsReadWhole) {
  // A 5x3 16-bit grayscale Adam7-interlaced PNG built byte by byte; pixel (x, y) holds
  // 1000 y + 7 x + 1.
  const std::vector<unsigned char> adam7 = {
      0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x48, 0x44,
      0x52, 0x00, 0x00, 0x00, 0x05, 0x00, 0x00, 0x00, 0x03, 0x10, 0x00, 0x00, 0x00, 0x01, 0x59,
      0xca, 0x76, 0xf1, 0x00, 0x00, 0x00, 0x2e, 0x49, 0x44, 0x41, 0x54, 0x78, 0x9c, 0x63, 0x60,
      0x60, 0x64, 0x60, 0x90, 0x65, 0x60, 0xe0, 0x67, 0x60, 0xbf, 0xc8, 0x7e, 0x9f, 0xfd, 0x2d,
      0x03, 0x03, 0x07, 0x83, 0x18, 0x03, 0xfb, 0x0d, 0xf6, 0x67, 0x0c, 0xcc, 0x2f, 0x99, 0x3f,
      0x30, 0x7f, 0x67, 0xfe, 0xc7, 0xc2, 0x0a, 0x00, 0x76, 0x81, 0x08, 0xad, 0x14, 0x8d, 0x25,
      0xad, 0x00, 0x00, 0x00, 0x00, 0x49, 0x45, 0x4e, 0x44, 0xae, 0x42, 0x60, 0x82};
  const std::string path = tempDir() + "/adam7.png";
  writeBytes(path, adam7);
  int w = 0, h = 0;
  const auto v = readPng16(path, &w, &h);
  ASSERT_EQ(w, 5);
  ASSERT_EQ(h, 3);
  for (int y = 0; y < 3; ++y)
    for (int x = 0; x < 5; ++x) EXPECT_EQ(v[y * 5 + x], 1000 * y + 7 * x + 1) << x << "," << y;
}

TEST(TumDepth, TeddyFirstFrame) {
  DT_TEDDY_OR_SKIP(teddy);
  const auto frames = readTumFrameList(teddy + "/depth.txt");
  ASSERT_EQ(frames.size(), 200u);
  EXPECT_NEAR(frames.front().stamp_s, 1341841873.273820, 1e-6);
  // The dataset lists frames at the Kinect's 30 Hz.
  EXPECT_NEAR((frames.back().stamp_s - frames.front().stamp_s) / 199.0, 1.0 / 30.0, 0.005);
  const DepthImage d = loadTumDepth(frames.front().path, 1.0 / 5000.0, DepthRange{0.1, 10.0});
  EXPECT_EQ(d.width, 640);
  EXPECT_EQ(d.height, 480);
  std::vector<float> valid;
  for (float z : d.data)
    if (z > 0.0f) valid.push_back(z);
  // Counted by an independent decoder (Python zlib + PNG unfiltering) on the same file.
  EXPECT_EQ(valid.size(), 228398u);
  std::nth_element(valid.begin(), valid.begin() + valid.size() / 2, valid.end());
  const float median = valid[valid.size() / 2];
  // README: median depth about 2.1 m; the independent decoder gives 2.143 m for this frame
  // (tolerance: one 0.2 mm depth step either side plus float rounding).
  EXPECT_NEAR(median, 2.143, 5e-4);
  // Values are multiples of 1/5000 m: the byte order is right only if they land on the grid.
  for (std::size_t i = 0; i < valid.size(); i += 997)
    EXPECT_NEAR(valid[i] * 5000.0, std::round(valid[i] * 5000.0), 1e-2);

  // The same frame with a tighter range loses the far readings only.
  const DepthImage near = loadTumDepth(frames.front().path, 1.0 / 5000.0, DepthRange{0.1, 2.0});
  EXPECT_LT(near.countValid(), d.countValid());
  for (std::size_t i = 0; i < d.data.size(); i += 101)
    if (near.data[i] > 0.0f) {
      EXPECT_EQ(near.data[i], d.data[i]);
    }
}

TEST(TumDepth, SaveLoadRoundTripAtScale) {
  DepthImage d(4, 2);
  d.at(0, 0) = 1.0f;
  d.at(1, 0) = 2.5f;
  d.at(3, 1) = 0.7f;
  const std::string path = tempDir() + "/depth_rt.png";
  saveTumDepth(path, d, 1.0 / 5000.0);
  const DepthImage back = loadTumDepth(path, 1.0 / 5000.0, DepthRange{0.1, 10.0});
  ASSERT_EQ(back.data.size(), d.data.size());
  for (std::size_t i = 0; i < d.data.size(); ++i) EXPECT_NEAR(back.data[i], d.data[i], 1e-4);
  d.at(2, 0) = 20.0f;  // 100000 units does not fit 16 bits
  expectFileError([&] { saveTumDepth(path, d, 1.0 / 5000.0); }, {"depth_rt.png", "(2, 0)"});
}

TEST(TumDepth, FrameListErrorsNameFileAndLine) {
  const std::string dir = tempDir();
  writeBytes(dir + "/a.png", {});
  writeText(dir + "/list_ok.txt", "# header\n\n0.5 a.png\n");
  const auto ok = readTumFrameList(dir + "/list_ok.txt");
  ASSERT_EQ(ok.size(), 1u);
  EXPECT_EQ(ok[0].path, dir + "/a.png");
  EXPECT_DOUBLE_EQ(ok[0].stamp_s, 0.5);

  writeText(dir + "/list_bad.txt", "# header\n0.5 a.png\nzero a.png\n");
  expectFileError([&] { readTumFrameList(dir + "/list_bad.txt"); }, {"list_bad.txt:3:", "zero"});
  writeText(dir + "/list_missing.txt", "# header\n0.5 a.png\n\n0.6 b.png\n");
  expectFileError([&] { readTumFrameList(dir + "/list_missing.txt"); },
                  {"list_missing.txt:4:", "b.png", "does not exist"});
  expectFileError([&] { readTumFrameList(dir + "/nope.txt"); }, {"nope.txt"});
}

TEST(TumTrajectory, WriteReadRoundTrip) {
  Trajectory traj;
  for (int i = 0; i < 5; ++i) {
    StampedPose p;
    p.stamp_s = 1341841873.0 + i / 30.0;
    p.T_W_C.linear() = Eigen::AngleAxisd(0.3 * i + 0.1, Eigen::Vector3d(1, -2, 0.5).normalized())
                           .toRotationMatrix();
    p.T_W_C.translation() = Eigen::Vector3d(0.1 * i, -2.0 + i, 1.5);
    traj.push_back(p);
  }
  const std::string path = tempDir() + "/traj.txt";
  writeTumTrajectory(path, traj, "test trajectory");
  const Trajectory back = readTumTrajectory(path);
  ASSERT_EQ(back.size(), traj.size());
  for (std::size_t i = 0; i < traj.size(); ++i) {
    EXPECT_NEAR(back[i].stamp_s, traj[i].stamp_s, 1e-6);  // 6 decimals written
    EXPECT_LT((back[i].T_W_C.translation() - traj[i].T_W_C.translation()).norm(), 1e-6);
    EXPECT_LT((back[i].T_W_C.linear() - traj[i].T_W_C.linear()).norm(), 1e-8);
  }
}

TEST(TumTrajectory, MalformedLinesReportLineNumbers) {
  const std::string dir = tempDir();
  writeText(dir + "/t7.txt", "# c\n1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 1\n3 0 0 0 0 0 1\n");
  expectFileError([&] { readTumTrajectory(dir + "/t7.txt"); }, {"t7.txt:4:", "8 fields", "got 7"});
  writeText(dir + "/tnan.txt", "1 0 0 0 0 0 0 1\n2 0 nan 0 0 0 0 1\n");
  expectFileError([&] { readTumTrajectory(dir + "/tnan.txt"); }, {"tnan.txt:2:", "field 3", "nan"});
  writeText(dir + "/tword.txt", "\n\n1 0 0 0 0 0 0 1\n2 0 0 x1 0 0 0 1\n");
  expectFileError([&] { readTumTrajectory(dir + "/tword.txt"); }, {"tword.txt:4:", "x1"});
  writeText(dir + "/tzero.txt", "1 0 0 0 0 0 0 0\n");
  expectFileError([&] { readTumTrajectory(dir + "/tzero.txt"); }, {"tzero.txt:1:", "quaternion"});
  // Commas as separators and a non-unit quaternion are accepted (normalised).
  writeText(dir + "/tcomma.txt", "1,0.5,0,0,0,0,0,2\n");
  const auto t = readTumTrajectory(dir + "/tcomma.txt");
  ASSERT_EQ(t.size(), 1u);
  EXPECT_TRUE(t[0].T_W_C.linear().isIdentity(1e-12));
  EXPECT_DOUBLE_EQ(t[0].T_W_C.translation().x(), 0.5);
}

TEST(TumTrajectory, NearestStampAssociation) {
  const std::vector<double> q = {0.0, 0.1, 0.2, 0.3};
  const std::vector<double> ref = {0.19, 0.005, 0.125, 0.305, 0.315};  // unsorted on purpose
  const auto pairs = associateStamps(q, ref, 0.02);
  ASSERT_EQ(pairs.size(), 3u);  // 0.1 is 25 ms from its nearest (0.125): dropped
  EXPECT_EQ(pairs[0], std::make_pair(std::size_t{0}, std::size_t{1}));
  EXPECT_EQ(pairs[1], std::make_pair(std::size_t{2}, std::size_t{0}));
  EXPECT_EQ(pairs[2], std::make_pair(std::size_t{3}, std::size_t{3}));
  EXPECT_TRUE(associateStamps(q, {}, 0.02).empty());
}

TEST(TumTrajectory, TeddyDepthFramesAssociateWithGroundTruth) {
  DT_TEDDY_OR_SKIP(teddy);
  const auto frames = readTumFrameList(teddy + "/depth.txt");
  const Trajectory gt = readTumTrajectory(teddy + "/groundtruth.txt");
  EXPECT_EQ(gt.size(), 773u);
  std::vector<double> stamps;
  for (const auto& f : frames) stamps.push_back(f.stamp_s);
  std::vector<double> gt_s;
  for (const auto& p : gt) gt_s.push_back(p.stamp_s);
  // The dataset README: 196 of the 200 frames have ground truth within 20 ms.
  EXPECT_EQ(associateStamps(stamps, gt_s, 0.02).size(), 196u);
  for (const auto& p : gt) EXPECT_NEAR(p.T_W_C.linear().determinant(), 1.0, 1e-9);
}

namespace {

// A fresh folder under the test's temp dir.
std::string freshDir(const std::string& name) {
  const std::string d = tempDir() + "/" + name;
  std::filesystem::remove_all(d);
  std::filesystem::create_directories(d);
  return d;
}

// A 4x3 depth PNG whose first pixel is `mm` and whose second is 65535 (7-Scenes: no return).
void writeSevenScenesDepth(const std::string& path, std::uint16_t mm) {
  std::vector<std::uint16_t> raw(12, 1500);
  raw[0] = mm;
  raw[1] = 65535;
  writePng16(path, raw, 4, 3);
}

std::string poseText(double tx, double ty, double tz, double yaw_rad) {
  const double c = std::cos(yaw_rad), s = std::sin(yaw_rad);
  char buf[512];
  std::snprintf(buf, sizeof buf,
                "%.7e %.7e %.7e %.7e\n%.7e %.7e %.7e %.7e\n%.7e %.7e %.7e %.7e\n"
                "0.0000000e+00 0.0000000e+00 0.0000000e+00 1.0000000e+00\n",
                c, 0.0, s, tx, 0.0, 1.0, 0.0, ty, -s, 0.0, c, tz);
  return buf;
}

}  // namespace

TEST(DepthSequence, SevenScenesLayoutFramesPosesIntrinsicsAndUnit) {
  const std::string root = freshDir("seq7");
  const std::string d = root + "/data";  // the layout's data/ subfolder is found too
  std::filesystem::create_directories(d);
  // Written out of order: the frames are taken in file-name order, stamped i / 30 s.
  for (int i : {2, 0, 1}) {
    char name[64];
    std::snprintf(name, sizeof name, "/frame-%06d", i);
    writeSevenScenesDepth(d + name + ".depth.png", static_cast<std::uint16_t>(1000 + i));
    writeText(d + name + ".pose.txt", poseText(0.1 * i, -0.2, 0.3, 0.05 * i));
  }
  writeText(d + "/frame-000000.color.png", "not read");
  const DepthSequence seq = readDepthSequence(root);
  EXPECT_EQ(seq.layout, "7-Scenes");
  ASSERT_EQ(seq.frames.size(), 3u);
  ASSERT_EQ(seq.ground_truth.size(), 3u);
  for (int i = 0; i < 3; ++i) {
    EXPECT_DOUBLE_EQ(seq.frames[i].stamp_s, i / 30.0);
    EXPECT_DOUBLE_EQ(seq.ground_truth[i].stamp_s, i / 30.0);
    EXPECT_NE(seq.frames[i].path.find("frame-00000" + std::to_string(i) + ".depth.png"),
              std::string::npos);
    EXPECT_NEAR(seq.ground_truth[i].T_W_C.translation().x(), 0.1 * i, 1e-9);
    EXPECT_NEAR(Eigen::AngleAxisd(seq.ground_truth[i].T_W_C.rotation()).angle(), 0.05 * i, 1e-6);
  }
  EXPECT_DOUBLE_EQ(seq.depth_scale_m, 0.001);
  // No camera-intrinsics.txt: the dataset's published calibration, and it says so.
  ASSERT_TRUE(seq.intrinsics.has_value());
  EXPECT_DOUBLE_EQ(seq.intrinsics->fx, 585.0);
  EXPECT_DOUBLE_EQ(seq.intrinsics->cy, 240.0);
  EXPECT_NE(seq.intrinsics_source.find("published"), std::string::npos);
  // Millimetres in, metres out; 65535 (the layout's "no return") is no return at any range.
  const DepthImage depth = loadSequenceDepth(seq, 2, seq.depth_scale_m, DepthRange{0.1, 100.0});
  EXPECT_FLOAT_EQ(depth.at(0, 0), 1.002f);
  EXPECT_EQ(depth.at(1, 0), 0.0f);
  int w = 0, h = 0;
  const std::vector<std::uint16_t> raw = readSequenceDepthRaw(seq, 2, &w, &h);
  EXPECT_EQ(raw[1], 0);
  EXPECT_EQ(raw[0], 1002);
  EXPECT_THROW(readSequenceDepthRaw(seq, 3, &w, &h), std::out_of_range);

  writeText(d + "/camera-intrinsics.txt", "585.5 0 319.5\n0 586.5 241.5\n0 0 1\n");
  const DepthSequence with_k = readDepthSequence(root);
  ASSERT_TRUE(with_k.intrinsics.has_value());
  EXPECT_DOUBLE_EQ(with_k.intrinsics->fx, 585.5);
  EXPECT_DOUBLE_EQ(with_k.intrinsics->fy, 586.5);
  EXPECT_DOUBLE_EQ(with_k.intrinsics->cx, 319.5);
  EXPECT_DOUBLE_EQ(with_k.intrinsics->cy, 241.5);
  EXPECT_EQ(with_k.intrinsics_source, d + "/camera-intrinsics.txt");
}

TEST(DepthSequence, SevenScenesErrorsNameTheFile) {
  const std::string d = freshDir("seq7bad");
  for (int i = 0; i < 3; ++i) {
    char name[64];
    std::snprintf(name, sizeof name, "/frame-%06d", i);
    writeSevenScenesDepth(d + name + ".depth.png", 1000);
    writeText(d + name + ".pose.txt", poseText(0, 0, 0, 0));
  }
  // A pose file with a field that is not a number: file and line.
  writeText(d + "/frame-000001.pose.txt", "1 0 0 0\n0 1 0 0\n0 0 1 x\n0 0 0 1\n");
  expectFileError([&] { readDepthSequence(d); }, {"frame-000001.pose.txt:3:", "'x'"});
  // Three rows only.
  writeText(d + "/frame-000001.pose.txt", "1 0 0 0\n0 1 0 0\n0 0 1 0\n");
  expectFileError([&] { readDepthSequence(d); }, {"frame-000001.pose.txt", "expected 4 rows"});
  // Not a rotation (a scaled matrix), and a mirror.
  writeText(d + "/frame-000001.pose.txt", "1.1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n");
  expectFileError([&] { readDepthSequence(d); }, {"frame-000001.pose.txt", "not a rotation"});
  writeText(d + "/frame-000001.pose.txt", "-1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n");
  expectFileError([&] { readDepthSequence(d); }, {"frame-000001.pose.txt", "not a rotation"});
  writeText(d + "/frame-000001.pose.txt", "1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 1 1\n");
  expectFileError([&] { readDepthSequence(d); }, {"frame-000001.pose.txt:4:", "0 0 0 1"});
  // One frame without its pose file: named, with the count.
  std::remove((d + "/frame-000001.pose.txt").c_str());
  expectFileError([&] { readDepthSequence(d); }, {"frame-000001.pose.txt: missing", "2 of 3"});
  // No pose file at all: a sequence without ground truth.
  std::remove((d + "/frame-000000.pose.txt").c_str());
  std::remove((d + "/frame-000002.pose.txt").c_str());
  EXPECT_TRUE(readDepthSequence(d).ground_truth.empty());
  EXPECT_EQ(readDepthSequence(d).frames.size(), 3u);
  // A malformed intrinsics file.
  writeText(d + "/camera-intrinsics.txt", "585 0 320\n0 585 240\n");
  expectFileError([&] { readDepthSequence(d); }, {"camera-intrinsics.txt", "3x3"});
  writeText(d + "/camera-intrinsics.txt", "-585 0 320\n0 585 240\n0 0 1\n");
  expectFileError([&] { readDepthSequence(d); }, {"camera-intrinsics.txt", "positive"});
  // Neither layout; no folder.
  const std::string empty = freshDir("seq_empty");
  expectFileError([&] { readDepthSequence(empty); }, {"not a depth sequence", "depth.txt",
                                                      "frame-*.depth.png"});
  expectFileError([&] { readDepthSequence(empty + "/nope"); }, {"no such folder"});
}

TEST(DepthSequence, TumLayoutWithAndWithoutIntrinsicsFile) {
  const std::string d = freshDir("seqtum");
  std::filesystem::create_directories(d + "/depth");
  writeSevenScenesDepth(d + "/depth/1.png", 5000);
  writeSevenScenesDepth(d + "/depth/2.png", 5000);
  writeText(d + "/depth.txt", "# depth maps\n100.5 depth/1.png\n100.6 depth/2.png\n");
  DepthSequence seq = readDepthSequence(d);
  EXPECT_EQ(seq.layout, "TUM RGB-D");
  ASSERT_EQ(seq.frames.size(), 2u);
  EXPECT_DOUBLE_EQ(seq.frames[1].stamp_s, 100.6);
  EXPECT_DOUBLE_EQ(seq.depth_scale_m, 1.0 / 5000.0);
  EXPECT_FALSE(seq.intrinsics.has_value());  // the user names the camera
  EXPECT_TRUE(seq.ground_truth.empty());

  writeText(d + "/groundtruth.txt", "100.49 1 2 3 0 0 0 1\n");
  writeText(d + "/intrinsics.txt", "525 526 319.5 239.5 1000\n");
  seq = readDepthSequence(d);
  ASSERT_TRUE(seq.intrinsics.has_value());
  EXPECT_DOUBLE_EQ(seq.intrinsics->fy, 526.0);
  EXPECT_DOUBLE_EQ(seq.intrinsics->cx, 319.5);
  EXPECT_DOUBLE_EQ(seq.depth_scale_m, 0.001);
  ASSERT_EQ(seq.ground_truth.size(), 1u);
  EXPECT_DOUBLE_EQ(seq.ground_truth[0].T_W_C.translation().z(), 3.0);

  writeText(d + "/intrinsics.txt", "525 526 319.5 239.5\n");
  expectFileError([&] { readDepthSequence(d); }, {"intrinsics.txt:1:", "expected 5 numbers"});
  writeText(d + "/intrinsics.txt", "525 526 319.5 239.5 0.001\n");
  expectFileError([&] { readDepthSequence(d); }, {"intrinsics.txt:1:", "units per metre"});
}

// The shared TUM sequences read through the sequence reader: every listed frame, the ground
// truth, and no intrinsics (the TUM folders do not carry them).
TEST(DepthSequence, SharedTeddyFolder) {
  DT_TEDDY_OR_SKIP(dir);
  const DepthSequence seq = readDepthSequence(dir);
  EXPECT_EQ(seq.layout, "TUM RGB-D");
  EXPECT_EQ(seq.frames.size(), readTumFrameList(dir + "/depth.txt").size());
  EXPECT_EQ(seq.ground_truth.size(), readTumTrajectory(dir + "/groundtruth.txt").size());
  EXPECT_FALSE(seq.intrinsics.has_value());
}

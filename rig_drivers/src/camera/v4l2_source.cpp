#include "rig_drivers/camera/v4l2_source.hpp"

#include <fcntl.h>
#include <linux/videodev2.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <exception>

namespace rig_drivers {

namespace dt = depth_track;

namespace {
std::string err() { return std::strerror(errno); }
/// errno values of a device that went away under an open descriptor.
bool deviceGone(int e) { return e == ENODEV || e == EIO || e == ENXIO || e == EBADF; }
}  // namespace

V4l2Source::V4l2Source(std::string device, const dt::PinholeIntrinsics& K, double device_scale_m,
                       const dt::DepthRange& range)
    : device_(std::move(device)), K_(K), scale_m_(device_scale_m), range_(range) {}

V4l2Source::~V4l2Source() { close(); }

int V4l2Source::xioctl(unsigned long request, void* arg) {
  int r;
  do r = ::ioctl(fd_, request, arg);
  while (r < 0 && errno == EINTR);
  return r;
}

bool V4l2Source::open(std::string* why) {
  close();
  fd_ = ::open(device_.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC);
  if (fd_ < 0) {
    *why = "cannot open " + device_ + ": " + err() +
           " (is the camera plugged in and this its depth node?)";
    return false;
  }
  if (!setUp(why)) {
    close();
    return false;
  }
  return true;
}

bool V4l2Source::setUp(std::string* why) {
  const std::string& d = device_;
  v4l2_capability cap{};
  if (xioctl(VIDIOC_QUERYCAP, &cap) != 0) {
    *why = d + " is not a V4L2 device (VIDIOC_QUERYCAP: " + err() + ")";
    return false;
  }
  if (!(cap.capabilities & V4L2_CAP_VIDEO_CAPTURE) || !(cap.capabilities & V4L2_CAP_STREAMING)) {
    *why = d + " is not a streaming video capture device";
    return false;
  }
  v4l2_format fmt{};
  fmt.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  fmt.fmt.pix.width = K_.width;
  fmt.fmt.pix.height = K_.height;
  fmt.fmt.pix.pixelformat = V4L2_PIX_FMT_Z16;
  fmt.fmt.pix.field = V4L2_FIELD_NONE;
  if (xioctl(VIDIOC_S_FMT, &fmt) != 0) {
    *why = d + ": VIDIOC_S_FMT Z16 failed: " + err();
    return false;
  }
  if (fmt.fmt.pix.pixelformat != V4L2_PIX_FMT_Z16 ||
      static_cast<int>(fmt.fmt.pix.width) != K_.width ||
      static_cast<int>(fmt.fmt.pix.height) != K_.height) {
    *why = d + " does not offer Z16 at " + std::to_string(K_.width) + "x" +
           std::to_string(K_.height) + " (is this the depth node of the camera?)";
    return false;
  }
  stride_ = fmt.fmt.pix.bytesperline ? fmt.fmt.pix.bytesperline : 2u * K_.width;
  v4l2_requestbuffers req{};
  req.count = 4;
  req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  req.memory = V4L2_MEMORY_MMAP;
  if (xioctl(VIDIOC_REQBUFS, &req) != 0 || req.count < 2) {
    *why = d + ": VIDIOC_REQBUFS failed: " + err();
    return false;
  }
  for (unsigned i = 0; i < req.count; ++i) {
    v4l2_buffer b{};
    b.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    b.memory = V4L2_MEMORY_MMAP;
    b.index = i;
    if (xioctl(VIDIOC_QUERYBUF, &b) != 0) {
      *why = d + ": VIDIOC_QUERYBUF failed: " + err();
      return false;
    }
    void* p = ::mmap(nullptr, b.length, PROT_READ | PROT_WRITE, MAP_SHARED, fd_, b.m.offset);
    if (p == MAP_FAILED) {
      *why = d + ": mmap failed: " + err();
      return false;
    }
    buffers_.push_back({p, b.length});
    if (xioctl(VIDIOC_QBUF, &b) != 0) {
      *why = d + ": VIDIOC_QBUF failed: " + err();
      return false;
    }
  }
  v4l2_buf_type type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (xioctl(VIDIOC_STREAMON, &type) != 0) {
    *why = d + ": VIDIOC_STREAMON failed: " + err();
    return false;
  }
  streaming_ = true;
  return true;
}

void V4l2Source::close() {
  if (fd_ >= 0 && streaming_) {
    v4l2_buf_type type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    xioctl(VIDIOC_STREAMOFF, &type);
  }
  streaming_ = false;
  for (auto& b : buffers_) ::munmap(b.first, b.second);
  buffers_.clear();
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

GrabStatus V4l2Source::grab(DepthFrame* out, std::string* why) {
  if (fd_ < 0) {
    *why = device_ + " is not open";
    return GrabStatus::kLost;
  }
  pollfd p{fd_, POLLIN, 0};
  const int n = ::poll(&p, 1, 1000);
  if (n < 0 && errno != EINTR) {
    *why = "poll on " + device_ + " failed: " + err();
    return GrabStatus::kLost;
  }
  if (n > 0 && (p.revents & (POLLERR | POLLHUP | POLLNVAL))) {
    *why = device_ + " reports an error (unplugged?)";
    return GrabStatus::kLost;
  }
  if (n <= 0) {
    *why = "no frame from " + device_ + " within 1 s";
    return GrabStatus::kNoFrame;
  }
  v4l2_buffer b{};
  b.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  b.memory = V4L2_MEMORY_MMAP;
  if (xioctl(VIDIOC_DQBUF, &b) != 0) {
    const int e = errno;
    *why = "VIDIOC_DQBUF on " + device_ + " failed: " + std::strerror(e);
    return deviceGone(e) ? GrabStatus::kLost : GrabStatus::kNoFrame;
  }
  out->stamp_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
                      std::chrono::system_clock::now().time_since_epoch())
                      .count();
  GrabStatus s = GrabStatus::kFrame;
  try {
    out->depth = dt::depthFromRaw(buffers_[b.index].first, K_.width, K_.height, stride_,
                                  dt::DepthEncoding::kU16, scale_m_, range_);
  } catch (const std::exception& e) {
    *why = device_ + ": " + e.what();
    s = GrabStatus::kNoFrame;
  }
  // A buffer that cannot be queued again means the device went; the next poll reports it.
  xioctl(VIDIOC_QBUF, &b);
  return s;
}

}  // namespace rig_drivers

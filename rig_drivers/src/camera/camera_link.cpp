#include "rig_drivers/camera/camera_link.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <exception>
#include <stdexcept>
#include <utility>

namespace rig_drivers {

namespace {
std::string seconds(double s) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3g s", s);
  return buf;
}
}  // namespace

std::vector<std::string> CameraLinkConfig::validate() const {
  std::vector<std::string> p;
  if (!(retry_period_s >= 0.01 && retry_period_s <= 60.0))
    p.push_back("retry_period_s must be in [0.01, 60] s");
  if (!(stale_timeout_s == 0.0 || (stale_timeout_s >= 0.1 && stale_timeout_s <= 600.0)))
    p.push_back("stale_timeout_s must be 0 (off) or in [0.1, 600] s");
  if (!(rate_hz > 0.0 && rate_hz <= 1000.0)) p.push_back("rate_hz must be in (0, 1000] Hz");
  return p;
}

CameraLink::CameraLink(CameraLinkConfig config, std::unique_ptr<DepthSource> source,
                       EventHandler on_event)
    : config_(std::move(config)), source_(std::move(source)), on_event_(std::move(on_event)) {
  const auto problems = config_.validate();
  if (!problems.empty()) {
    std::string msg = "invalid camera link settings:";
    for (const auto& p : problems) msg += " " + p + ";";
    throw std::invalid_argument(msg);
  }
  if (!source_) throw std::invalid_argument("camera link needs a source");
}

CameraLink::~CameraLink() { close(); }

void CameraLink::close() {
  if (open_) source_->close();
  open_ = false;
}

void CameraLink::emit(CameraEvent::Type type, const std::string& message) {
  if (on_event_) on_event_({type, message});
}

bool CameraLink::tryOpen(double now_s) {
  if (now_s < next_open_s_) return false;
  std::string why;
  bool ok = false;
  try {
    ok = source_->open(&why);
  } catch (const std::exception& e) {
    why = e.what();
  }
  if (!ok) {
    source_->close();
    ++stats_.failed_opens;
    next_open_s_ = now_s + config_.retry_period_s;
    if (why.empty()) why = "cannot open " + source_->device();
    if (why != open_why_) {  // once per reason, not once per retry
      open_why_ = why;
      emit(CameraEvent::kWaiting, "waiting for " + source_->device() + ": " + why +
                                      "; retrying every " + seconds(config_.retry_period_s));
    }
    return false;
  }
  open_ = true;
  open_why_.clear();
  last_frame_s_ = now_s;
  if (state_ == CameraState::kLost) {
    ++stats_.reconnects;
    emit(CameraEvent::kOpened,
         source_->device() + " open again " + seconds(now_s - lost_at_s_) + " after it was lost");
  } else {
    emit(CameraEvent::kOpened, source_->device() + " open");
  }
  state_ = CameraState::kStreaming;
  return true;
}

void CameraLink::lose(double now_s, const std::string& why) {
  source_->close();
  open_ = false;
  state_ = CameraState::kLost;
  ++stats_.losses;
  lost_at_s_ = now_s;
  lost_why_ = why;
  gap_pending_ = last_stamp_ns_ != 0;
  next_open_s_ = now_s + config_.retry_period_s;
  emit(CameraEvent::kLost, "lost " + source_->device() + ": " + why + "; reopening every " +
                               seconds(config_.retry_period_s));
}

void CameraLink::countGap(std::int64_t stamp_ns) {
  if (gap_pending_ && stamp_ns != 0) {
    gap_pending_ = false;
    const double gap_s = static_cast<double>(stamp_ns - last_stamp_ns_) * 1e-9;
    // Frames the camera would have delivered between the two stamps at its nominal rate.
    const long long missing = std::llround(gap_s * config_.rate_hz) - 1;
    stats_.last_gap_s = gap_s;
    if (missing > 0) stats_.gap_frames += static_cast<std::uint64_t>(missing);
    char buf[160];
    std::snprintf(buf, sizeof buf,
                  "frames again from %s: %lld frames missing (%.3f s between stamps)",
                  source_->device().c_str(), missing > 0 ? missing : 0LL, gap_s);
    emit(CameraEvent::kResumed, buf);
  }
  if (stamp_ns != 0) last_stamp_ns_ = stamp_ns;
}

bool CameraLink::step(double now_s, DepthFrame* out) {
  if (state_ == CameraState::kEnded) return false;
  if (!open_ && !tryOpen(now_s)) {
    last_problem_ = status();
    return false;
  }
  if (out == nullptr) return false;
  std::string why;
  GrabStatus s;
  try {
    s = source_->grab(out, &why);
  } catch (const std::exception& e) {  // a bad frame, not a lost device
    s = GrabStatus::kNoFrame;
    why = e.what();
  }
  switch (s) {
    case GrabStatus::kFrame:
      last_problem_.clear();
      last_frame_s_ = now_s;
      ++stats_.frames;
      countGap(out->stamp_ns);
      return true;
    case GrabStatus::kNoFrame:
      last_problem_ = why;
      if (config_.stale_timeout_s > 0.0 && now_s - last_frame_s_ > config_.stale_timeout_s)
        lose(now_s, "no frame for " + seconds(now_s - last_frame_s_) +
                        (why.empty() ? "" : " (" + why + ")"));
      if (state_ == CameraState::kLost) last_problem_ = status();
      return false;
    case GrabStatus::kLost:
      lose(now_s, why.empty() ? "device gone" : why);
      last_problem_ = status();
      return false;
    case GrabStatus::kEnded:
      close();
      state_ = CameraState::kEnded;
      end_why_ = why;
      emit(CameraEvent::kEnded, source_->device() + ": " + why);
      last_problem_ = status();
      return false;
  }
  return false;
}

double CameraLink::secondsToRetry(double now_s) const {
  if (open_ || state_ == CameraState::kEnded) return 0.0;
  return std::max(0.0, next_open_s_ - now_s);
}

std::string CameraLink::status() const {
  switch (state_) {
    case CameraState::kWaiting:
      return "waiting for " + source_->device() + (open_why_.empty() ? "" : ": " + open_why_);
    case CameraState::kStreaming:
      return "streaming from " + source_->device() + ", " + std::to_string(stats_.frames) +
             " frames";
    case CameraState::kLost:
      return "waiting for " + source_->device() + " to come back (lost: " + lost_why_ + ")" +
             (open_why_.empty() ? "" : ": " + open_why_);
    case CameraState::kEnded:
      return source_->device() + " ended: " + end_why_;
  }
  return "";
}

}  // namespace rig_drivers

#include "depth_track/core/running_stats.hpp"

#include <algorithm>
#include <cstdio>
#include <stdexcept>

namespace depth_track {

RunningStats::RunningStats(std::size_t window) : window_(window) {
  if (window < 1) throw std::invalid_argument("RunningStats: window must hold >= 1 sample");
}

void RunningStats::add(double x) {
  if (ring_.size() < window_) {
    ring_.push_back(x);
  } else {
    ring_[next_] = x;
    next_ = (next_ + 1) % window_;
  }
  if (count_ == 0) {
    min_ = max_ = x;
  } else {
    min_ = std::min(min_, x);
    max_ = std::max(max_, x);
  }
  ++count_;
  sum_ += x;
  last_ = x;
}

void RunningStats::clear() {
  ring_.clear();
  next_ = 0;
  count_ = 0;
  sum_ = min_ = max_ = last_ = 0.0;
}

double RunningStats::quantile(double q) const {
  if (ring_.empty()) return 0.0;
  if (!(q >= 0.0 && q <= 1.0))
    throw std::invalid_argument("RunningStats::quantile: q must lie in [0, 1]");
  std::vector<double> v = ring_;
  const std::size_t i =
      std::min(v.size() - 1, static_cast<std::size_t>(q * static_cast<double>(v.size() - 1) + 0.5));
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(i), v.end());
  return v[i];
}

std::string RunningStats::summary() const {
  char buf[128];
  std::snprintf(buf, sizeof(buf), "n=%zu mean=%.2f median=%.2f p95=%.2f max=%.2f", count_, mean(),
                median(), p95(), max());
  return buf;
}

}  // namespace depth_track

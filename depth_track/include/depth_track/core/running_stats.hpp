#pragma once
/// Bounded running statistics of a stream of samples (stage timings in ms, counts): count, mean,
/// min and max over every sample, quantiles over the most recent `window` samples, so memory
/// stays fixed however long a camera streams. ROS-free core; not thread-safe (one writer; guard
/// it yourself to read from another thread).
#include <chrono>
#include <cstddef>
#include <string>
#include <vector>

namespace depth_track {

class RunningStats {
 public:
  /// Keeps the last `window` samples for quantiles (>= 1; throws std::invalid_argument).
  explicit RunningStats(std::size_t window = kDefaultWindow);

  /// Adds one sample; O(1), no allocation after the window has filled.
  void add(double x);
  /// Forgets every sample (the window size stays).
  void clear();

  /// Samples added since construction or clear().
  std::size_t count() const { return count_; }
  /// Mean, minimum, maximum and last value over every sample (0 when there is none).
  double mean() const { return count_ ? sum_ / static_cast<double>(count_) : 0.0; }
  double min() const { return count_ ? min_ : 0.0; }
  double max() const { return count_ ? max_ : 0.0; }
  double last() const { return count_ ? last_ : 0.0; }
  /// Nearest-rank q-quantile (q in [0, 1]) of the samples in the window: after sorting its n
  /// samples, the one at index round(q (n - 1)); 0 when there is none. O(window).
  double quantile(double q) const;
  double median() const { return quantile(0.5); }
  double p95() const { return quantile(0.95); }
  /// Samples the quantiles are taken over: min(count(), window()).
  std::size_t windowCount() const { return ring_.size(); }
  std::size_t window() const { return window_; }
  /// "n=N mean=X median=Y p95=Z max=W" with two decimals.
  std::string summary() const;

  /// 4096 samples: more than two minutes of frames at 30 Hz, 32 KB.
  static constexpr std::size_t kDefaultWindow = 4096;

 private:
  std::size_t window_;
  std::vector<double> ring_;  ///< up to window_ samples; next_ is the oldest once it is full
  std::size_t next_ = 0;
  std::size_t count_ = 0;
  double sum_ = 0.0, min_ = 0.0, max_ = 0.0, last_ = 0.0;
};

/// Wall time since t0 in milliseconds (steady clock). Thread-safe.
inline double msSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace depth_track

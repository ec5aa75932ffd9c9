#pragma once
/// One TBB arena shared by the stages of a pipeline (prefilter, reduction, ray cast), so a
/// process with several stages caps its worker threads once instead of each call creating an
/// arena of its own. ROS-free core.
#include <functional>
#include <memory>

namespace depth_track {

class WorkerPool {
 public:
  /// At most `threads` threads (the caller included) work on a parallelFor; 1 = the caller alone,
  /// no TBB. Throws std::invalid_argument for threads < 1.
  explicit WorkerPool(int threads = 1);
  ~WorkerPool();
  WorkerPool(const WorkerPool&) = delete;
  WorkerPool& operator=(const WorkerPool&) = delete;

  int threads() const { return threads_; }
  /// Calls body(b, e) on subranges [b, e) covering [begin, end) (each at least `grain` long
  /// unless at the end) and returns when all are done; with one thread, body(begin, end) on the
  /// caller. Thread-safe: calls from several threads share the arena's workers.
  void parallelFor(int begin, int end, int grain, const std::function<void(int, int)>& body) const;

 private:
  struct Impl;
  int threads_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace depth_track

#include "depth_track/core/worker_pool.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <stdexcept>
#include <string>

namespace depth_track {

struct WorkerPool::Impl {
  explicit Impl(int threads) : arena(threads) {}
  tbb::task_arena arena;
};

WorkerPool::WorkerPool(int threads) : threads_(threads) {
  if (threads < 1)
    throw std::invalid_argument("WorkerPool: threads must be >= 1 (got " + std::to_string(threads) +
                                ")");
  if (threads > 1) impl_ = std::make_unique<Impl>(threads);
}

WorkerPool::~WorkerPool() = default;

void WorkerPool::parallelFor(int begin, int end, int grain,
                             const std::function<void(int, int)>& body) const {
  if (begin >= end) return;
  if (!impl_) {
    body(begin, end);
    return;
  }
  impl_->arena.execute([&] {
    tbb::parallel_for(tbb::blocked_range<int>(begin, end, static_cast<std::size_t>(grain)),
                      [&](const tbb::blocked_range<int>& r) { body(r.begin(), r.end()); });
  });
}

}  // namespace depth_track

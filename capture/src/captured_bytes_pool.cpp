#include "clastrace/capture/captured_bytes_pool.h"

#include <array>
#include <bit>
#include <mutex>

namespace clastrace::capture {
namespace {

// Storage is kept by the power of two below its capacity, so any vector of class c holds at
// least 2^c bytes; a request takes from the smallest class that surely fits, or two above it
// (more would waste the bigger buffers on small ranges).
constexpr size_t kClasses = 48;

struct Pool {
  std::mutex mutex;
  std::array<std::vector<std::vector<uint8_t>>, kClasses> free;
  size_t pooled = 0;
};

Pool& pool() {
  static Pool* p = new Pool;  // never destroyed: sinks and workers may outlive static teardown
  return *p;
}

size_t classBelow(size_t capacity) { return size_t(std::bit_width(capacity) - 1); }
size_t classAbove(size_t size) { return size <= 1 ? 0 : size_t(std::bit_width(size - 1)); }

}  // namespace

std::vector<uint8_t> takeCapturedBytes(size_t size) {
  Pool& p = pool();
  {
    std::lock_guard lock(p.mutex);
    const size_t first = classAbove(size);
    for (size_t c = first; c < kClasses && c <= first + 2; ++c) {
      if (p.free[c].empty()) continue;
      std::vector<uint8_t> bytes = std::move(p.free[c].back());
      p.free[c].pop_back();
      p.pooled -= bytes.capacity();
      return bytes;
    }
  }
  std::vector<uint8_t> bytes;
  bytes.reserve(size);
  return bytes;
}

void recycleCapturedBytes(std::vector<uint8_t>&& bytes) {
  const size_t capacity = bytes.capacity();
  if (capacity == 0) return;
  std::vector<uint8_t> kept = std::move(bytes);
  kept.clear();
  Pool& p = pool();
  std::lock_guard lock(p.mutex);
  if (p.pooled + capacity > kCapturedBytesPoolLimit) return;  // freed on leaving, outside the pool
  p.pooled += capacity;
  p.free[std::min(classBelow(capacity), kClasses - 1)].push_back(std::move(kept));
}

size_t capturedBytesPooled() {
  std::lock_guard lock(pool().mutex);
  return pool().pooled;
}

}  // namespace clastrace::capture

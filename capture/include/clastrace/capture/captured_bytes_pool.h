// Storage for captured ranges' bytes, handed back by the sink once a submission is written and
// taken again by the pause worker. Without it every frame's snapshot bytes (80 MB over the
// H100 bench's 120 frames) were fresh allocations in the worker's malloc arena, freed on the
// sink's thread: the arena shrank and grew again each frame, so the worker faulted in and
// zeroed new pages (and called mprotect) while the queue waited in the pause. Bounded: past
// kCapturedBytesPoolLimit of kept capacity, returned storage is freed as before.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace clastrace::capture {

inline constexpr size_t kCapturedBytesPoolLimit = size_t(64) << 20;

// Empty storage with room for at least `size` bytes (reused where the pool has some).
std::vector<uint8_t> takeCapturedBytes(size_t size);
// Gives the storage back (its contents are dropped).
void recycleCapturedBytes(std::vector<uint8_t>&& bytes);
// Capacity the pool keeps now (tests).
size_t capturedBytesPooled();

}  // namespace clastrace::capture

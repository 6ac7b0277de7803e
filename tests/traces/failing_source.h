// SPDX-License-Identifier: Apache-2.0
// Sources and allocations that fail on purpose, to drive the trace reader's read-ahead thread
// into its failure paths: a read error on the thread (or on every thread), and an allocation
// failure on the thread (failing_allocations.cpp replaces operator new in the test program).
#pragma once

#include "byte_source.h"

#include <clastrace/traces/trace_reader.h>

#include <atomic>
#include <cstdint>
#include <memory>
#include <string>
#include <thread>
#include <vector>

namespace clastrace::traces::testing {

// Which reads fail: those that touch [from, to), on threads other than the one that opened the
// reader (the read-ahead thread) or on every thread, up to `max_failures` of them.
struct ReadFailure {
    uint64_t from = 0;
    uint64_t to = UINT64_MAX;
    bool read_ahead_thread_only = true;
    uint32_t max_failures = UINT32_MAX;  // 1: a transient error, the next read succeeds
    std::atomic<uint32_t> failed{0};     // reads failed so far
};

// The message such a read leaves in ByteSource::last_error(), on the thread that read.
inline constexpr const char* kInjectedReadError = "injected read error";

// A reader of `bytes` (which must outlive it) named `name`, whose reads fail as `failure` says.
std::unique_ptr<TraceReader> open_failing(const std::vector<uint8_t>& bytes,
                                          const std::string& name,
                                          std::shared_ptr<ReadFailure> failure, TraceError* error);

// While one lives, allocations of at least `min_bytes` on any thread but the one that made it
// throw std::bad_alloc (the read-ahead thread's chunk buffers; failing_allocations.cpp).
class FailingAllocations {
public:
    explicit FailingAllocations(size_t min_bytes);
    ~FailingAllocations();
    FailingAllocations(const FailingAllocations&) = delete;
    FailingAllocations& operator=(const FailingAllocations&) = delete;
    uint32_t failed() const;  // allocations failed since it was made
};

// Threads of this process now (/proc/self/task): the reader's thread must be gone once the
// reader is.
size_t thread_count();

}  // namespace clastrace::traces::testing

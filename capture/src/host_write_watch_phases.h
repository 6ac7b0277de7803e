// SPDX-License-Identifier: Apache-2.0
// Where the host-write watch's time goes (CLASTRACE_STATS): each call of the watch (a submission,
// a pause, a wait) is timed in laps, one steady-clock read at each boundary between its phases, so
// a call's phases add up to its time inside the watch, and their lines to the watch's line of the
// cost report (a few clock reads per call, none per range). The guard's mprotect calls and
// before-image copies are counted by the page guard (page_guard.h) and printed beside them.
#pragma once

#include "page_guard.h"

#include <array>
#include <atomic>
#include <cstdint>
#include <string>
#include <vector>

namespace clastrace::capture {

enum class WatchCall : uint8_t { kSubmit, kPause, kWait, kCount };

enum class WatchPhase : uint8_t {
    kSubmitLockWait,  // blocked on the watch's lock (a pause's or a wait's call holds it)
    kSubmitLook,      // earlier submissions looked at for host writes
    kSubmitWalk,      // the cluster commands' pointer walks
    kSubmitResolve,   // the ranges found placed in their allocations
    kSubmitGuard,     // probe and mprotect (page_guard.h)
    kSubmitHash,      // ranges the guard cannot hold, hashed
    kSubmitKeep,      // the submission kept, the oldest forgotten past the bound
    kPauseLockWait,
    kPauseCompare,  // what the command read against the ranges at the submission
    kWaitLockWait,
    kWaitLook,       // the ordered submissions' written pages compared, changes reported
    kWaitUnprotect,  // their pages writable again (unwatched)
    kCount
};

// The watch's totals (atomic: a call's first lap, its wait for the watch's lock, ends unlocked).
class WatchPhaseTotals {
public:
    void add_call(WatchCall call) { calls_[size_t(call)].fetch_add(1, std::memory_order_relaxed); }
    void add(WatchPhase phase, uint64_t ns) {
        ns_[size_t(phase)].fetch_add(ns, std::memory_order_relaxed);
    }
    void add_ranges(uint64_t ranges) { ranges_found_.fetch_add(ranges, std::memory_order_relaxed); }
    // One line per phase that ran ("host-write watch phase: CALL: PHASE | calls | wall ms"), then
    // the guard's line when `guard` is given.
    std::vector<std::string> lines(const PageGuard::Counts* guard) const;

private:
    std::array<std::atomic<uint64_t>, size_t(WatchCall::kCount)> calls_{};
    std::array<std::atomic<uint64_t>, size_t(WatchPhase::kCount)> ns_{};
    std::atomic<uint64_t> ranges_found_{0};
};

// Times one call's phases: each lap ends the phase named and starts the next.
class WatchLaps {
public:
    WatchLaps(WatchPhaseTotals& totals, WatchCall call);
    void lap(WatchPhase phase);

private:
    WatchPhaseTotals& totals_;
    uint64_t last_;
};

}  // namespace clastrace::capture

// SPDX-License-Identifier: Apache-2.0
// BinarySignals: which binary semaphores hold a signal no wait has consumed yet, as far as the
// trace tells it, for VUID-vkQueueSubmit-pSignalSemaphores-00067 / VUID-vkQueueSubmit2-semaphore-03868
// (a binary semaphore must be unsignalled when a submission signals it) and for
// VUID-vkAcquireNextImageKHR-semaphore-01286 / VUID-VkAcquireNextImageInfoKHR-semaphore-01288
// (nor when an acquire is given it).
//
// Only signals the trace holds count: a semaphore first seen in a wait, or signalled outside
// the captured range, is unknown and never reported. Submission waits, presents and (since
// format 1.2) acquires are all recorded, so every consumer and producer of a known signal is
// seen, except in a trace of a range: where submissions were left out, forget_all().
#pragma once

#include <cstdint>
#include <string>
#include <unordered_map>

namespace clastrace::replay::detail {

class BinarySignals {
public:
    // Submissions missing from the trace (a gap in submission_index: a submit or frame range)
    // may have consumed any signal: forget them all rather than report a second signal.
    void forget_all() { pending_.clear(); }
    // A wait (submission or present) consumes the signal.
    void consume(uint64_t semaphore) { pending_.erase(semaphore); }
    // Records the signal; returns where the earlier, still unconsumed signal came from (empty
    // when the semaphore was unsignalled or unknown).
    std::string signal(uint64_t semaphore, std::string origin) {
        auto [it, inserted] = pending_.try_emplace(semaphore, origin);
        if (inserted) return {};
        std::string earlier = std::move(it->second);
        it->second = std::move(origin);
        return earlier;
    }

    // Where the semaphore's unconsumed signal came from; empty when it has none the trace holds.
    std::string signalled_by(uint64_t semaphore) const {
        auto it = pending_.find(semaphore);
        return it == pending_.end() ? std::string() : it->second;
    }

private:
    std::unordered_map<uint64_t, std::string> pending_;  // semaphore -> where its signal came from
};

}  // namespace clastrace::replay::detail

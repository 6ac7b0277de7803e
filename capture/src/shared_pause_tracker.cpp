// SPDX-License-Identifier: Apache-2.0
#include "clastrace/capture/shared_pause_tracker.h"

namespace clastrace::capture {

void SharedPauseTracker::expected(uint64_t queue, uint64_t release) {
    ++uses_[release][queue].pending;
}

void SharedPauseTracker::released(uint64_t queue, uint64_t release) {
    auto event = uses_.find(release);
    if (event == uses_.end()) return;
    auto use = event->second.find(queue);
    if (use == event->second.end()) return;
    if (use->second.pending) --use->second.pending;
    use->second.awaiting_reset = true;
}

void SharedPauseTracker::forget(uint64_t release) { uses_.erase(release); }

bool SharedPauseTracker::busy_elsewhere(uint64_t queue, const std::vector<uint64_t>& releases,
                                        const ReleaseIsReset& is_reset) {
    bool busy = false;
    for (uint64_t release : releases) {
        auto event = uses_.find(release);
        if (event == uses_.end()) continue;
        for (auto use = event->second.begin(); use != event->second.end();) {
            Use& u = use->second;
            // Once reset, a release stays reset until the worker sets it for a later pause, which
            // `released` would mark again: a reset seen now is final for the pauses handled so far.
            if (u.awaiting_reset && is_reset(release)) u.awaiting_reset = false;
            if (u.pending == 0 && !u.awaiting_reset) {
                use = event->second.erase(use);
                continue;
            }
            if (use->first != queue) busy = true;
            ++use;
        }
        if (event->second.empty()) uses_.erase(event);
    }
    return busy;
}

}  // namespace clastrace::capture

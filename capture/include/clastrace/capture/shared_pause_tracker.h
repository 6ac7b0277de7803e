// SPDX-License-Identifier: Apache-2.0
// Which queues still use the layer's pause events of a command buffer that may run on several
// queues at once (SIMULTANEOUS_USE, or a simultaneous-use secondary in several primaries).
//
// A pause's events live in the command buffer, so two executions of it share them: one queue
// could see the other's `release` set and run on unobserved, or the worker could reset a
// `signal` the other set. On one queue the pause barrier keeps executions apart. Across
// queues the layer instead lets a submission start only once no other queue still uses
// any of its pause events: every pause expected there has been handled, and the queue has
// executed the vkCmdResetEvent(release) after the last one (until then a new execution
// would pass its wait on the old set). This class keeps that state; the pause worker owns it.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <unordered_map>
#include <vector>

namespace clastrace::capture {

class SharedPauseTracker {
public:
    // True once the queue has executed the reset of `release` (vkGetEventStatus reads RESET).
    using ReleaseIsReset = std::function<bool(uint64_t release)>;

    // A pause with event `release` is expected on `queue` (announced at submission).
    void expected(uint64_t queue, uint64_t release);
    // The worker set `release` for one pause expected on `queue`: the queue resets it next.
    void released(uint64_t queue, uint64_t release);
    // The command buffer holding `release` was reset or freed: none of its executions is pending.
    void forget(uint64_t release);
    // Whether a queue other than `queue` still uses one of `releases` (pauses expected, or a
    // release the queue has not reset yet; resets `isReset` confirms are forgotten).
    bool busy_elsewhere(uint64_t queue, const std::vector<uint64_t>& releases,
                        const ReleaseIsReset& is_reset);
    bool empty() const { return uses_.empty(); }

private:
    struct Use {
        uint32_t pending = 0;         // pauses expected, not handled yet
        bool awaiting_reset = false;  // released by the worker, reset not yet seen
    };
    std::unordered_map<uint64_t, std::map<uint64_t, Use>> uses_;  // release event -> queue -> use
};

}  // namespace clastrace::capture

// SPDX-License-Identifier: Apache-2.0
// Host writes a submitted command can observe (capture/README.md, "Host writes"): inside
// vkQueueSubmit, before the driver sees it, the mapped ranges the submission's captured cluster
// commands read are walked and hashed (XXH3). A later host call that could have let the host
// write them safely (the wait that orders the submission) or unsafely (the next submission,
// while this one may run) hashes them again; a range whose bytes changed since the submission
// goes to the sink as a HostWriteRecord, ahead of that call's own record, so replay orders the
// write against the waits. The pause before each command hashes what the command read: a range
// that changed before the command ran is marked as read by it.
#pragma once

#include "clastrace/capture/capture_records.h"
#include "pause_worker.h"

#include <deque>
#include <functional>
#include <mutex>
#include <vector>

namespace clastrace::capture {

struct DeviceState;

class HostWriteWatch {
public:
    struct Range {
        uint64_t pause_id = 0;
        VkDeviceAddress address = 0;
        uint64_t size = 0;
        uint64_t hash = 0;          // at the submission, then at the last look
        uint64_t pause_hash = 0;    // what the command read, once its pause came
        bool read_changed = false;  // the command read bytes unlike those at the submission
    };
    struct Submission {
        uint64_t index = 0;
        uint64_t queue = 0;
        uint64_t fence = 0;
        std::vector<SemaphoreUse> signals;
        std::vector<Range> ranges;
    };

    // Inside vkQueueSubmit, before the driver call: reports host writes to the submissions still
    // watched, then watches the mapped inputs of this one's cluster pauses.
    void submitting(DeviceState& d, const SubmissionRecord& record,
                    const std::vector<const PausePoint*>& pauses);
    void submit_failed(uint64_t index);
    // The pause before a watched command, with what it read.
    void paused(uint64_t submission, uint64_t pause_id, const std::vector<CapturedRange>& inputs);
    // A host wait succeeded: reports host writes to the submissions it orders, then stops
    // watching them. `orders` says which it completed directly; earlier ones on their queues too.
    void waited(DeviceState& d, const std::function<bool(const Submission&)>& orders);

private:
    // Hashes each range again; a changed one goes to the sink as `seen`.
    void look(DeviceState& d, Submission& s, HostWriteSeen seen);
    std::mutex mutex_;
    std::deque<Submission> watched_;  // oldest first
};

}  // namespace clastrace::capture

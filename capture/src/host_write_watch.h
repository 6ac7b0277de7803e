// SPDX-License-Identifier: Apache-2.0
// Host writes a submitted command can observe (capture/README.md, "Host writes"): inside
// vkQueueSubmit, before the driver sees it, the mapped ranges the submission's captured cluster
// commands read are walked and hashed (XXH3). A later host call that could have let the host
// write them safely (the wait that orders the submission) or unsafely (the next submission,
// while this one may run) hashes them again; a range whose bytes changed since the submission
// goes to the sink as a HostWriteRecord, ahead of that call's own record, so replay orders the
// write against the waits. The pause before each command hashes what the command read: a range
// that changed before the command ran is marked as read by it. A changed range that a command
// in flight may have written (the submission's own, or another submission pending meanwhile)
// is not claimed as the host's: the layer cannot tell whose write it saw
// (host_write_device_writes.h).
//
// Guard mode (CLASTRACE_HOST_WRITES=guard, the default): the submission's walk reads only what
// leads it to the ranges, and each range's pages are write-protected instead of hashed
// (page_guard.h). A look compares only ranges on pages written since, against the pages'
// before-images; an unwritten range costs nothing. A range on a page the guard cannot hold
// (mprotect refused, a page shared with memory outside the allocation) is hashed as above.
// Pages stay read-only past the wait (page_guard.h), and a command submitted again with the
// same parameters, whose walk reads the same bytes, reuses its last walk's ranges
// (host_write_walk_cache.h).
#pragma once

#include "clastrace/capture/capture_records.h"
#include "host_write_device_writes.h"
#include "host_write_walk_cache.h"
#include "host_write_watch_phases.h"
#include "pause_worker.h"

#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

namespace clastrace::capture {

struct DeviceState;
class HostViewResolver;

class HostWriteWatch {
public:
    struct Range {
        uint64_t pause_id = 0;
        VkDeviceAddress address = 0;
        uint64_t size = 0;
        MemorySpan span;                // where it lies in device memory
        uint64_t hash = 0;              // at the submission, then at the last look
        uint64_t pause_hash = 0;        // what the command read, once its pause came
        bool read_changed = false;      // the command read bytes unlike those at the submission
        const uint8_t* host = nullptr;  // where the layer's mapping holds it
        // Its pages are write-protected (page_guard.h): `hash` is unset until a look finds one
        // of them written, compares, and hashes the range from then on.
        bool guarded = false;
    };
    // The pages a submission watches in one allocation (sorted, each once).
    struct GuardedPages {
        uint64_t memory = 0;
        std::vector<uintptr_t> pages;
    };
    struct Submission {
        uint64_t index = 0;
        uint64_t queue = 0;
        uint64_t fence = 0;
        std::vector<SemaphoreUse> signals;
        std::vector<Range> ranges;
        std::vector<GuardedPages> guarded;      // its ranges' pages, watched till it goes
        std::vector<MemorySpan> device_writes;  // what its own commands may write
        // What submissions pending beside it wrote, kept once they stopped being watched.
        std::vector<MemorySpan> others_writes;
        // Its ranges not guarded (indices into `ranges`): all a look or pause compares while no
        // page it watches was written, without going through the guarded ones.
        std::vector<uint32_t> hashed;
        // The pauses that came: the trace holds what their commands read.
        std::vector<uint64_t> paused;
    };

    // Inside vkQueueSubmit, before the driver call: reports host writes to the submissions still
    // watched, then watches the mapped inputs of this one's cluster pauses.
    // `device_writes`: what the submission's commands may write (device_writes_of).
    void submitting(DeviceState& d, const SubmissionRecord& record,
                    const std::vector<const PausePoint*>& pauses,
                    std::vector<MemorySpan> device_writes);
    void submit_failed(uint64_t index);
    // The pause before a watched command, with what it read.
    void paused(uint64_t submission, uint64_t pause_id, const std::vector<CapturedRange>& inputs);
    // A host wait succeeded: reports host writes to the submissions it orders, then stops
    // watching them. `orders` says which it completed directly; earlier ones on their queues too.
    void waited(DeviceState& d, const std::function<bool(const Submission&)>& orders);
    // vkFreeMemory, before the driver's: the ranges in `memory` are no longer watched.
    void memory_freed(uint64_t memory);
    // What CLASTRACE_STATS says of the watch: its mode and what the guard did.
    std::string mode_line();
    // What CLASTRACE_STATS says of where the watch's time went (host_write_watch_phases.h).
    std::vector<std::string> phase_lines() const;
    ~HostWriteWatch();

private:
    // Hashes each range again; a changed one goes to the sink as `seen`.
    void look(DeviceState& d, Submission& s, HostWriteSeen seen);
    // The same for one range of `s`.
    void look_at(DeviceState& d, HostViewResolver& resolver, Submission& s, Range& r,
                 HostWriteSeen seen);
    // A command of `s` or of a submission pending beside it may have written `span`.
    bool device_may_have_written(const Submission& s, const MemorySpan& span) const;
    // Stops watching the submissions `gone` picks; the others keep what those may have written.
    void forget(const std::function<bool(const Submission&)>& gone);
    // Write-protects the pages of the ranges of `group` (of the walk whose ranges start at
    // `first` in `s.ranges`) where the guard can hold them, and hashes the others; `s` keeps the
    // pages it watches.
    void guard_or_hash(HostViewResolver& resolver, const HostWriteWalkCache::Group& group,
                       size_t first, Submission& s, WatchLaps& laps);
    // Whether the guard can hold the pages of `memory`: probed at `page` the first time.
    bool probed(const TrackedMemory& memory, uintptr_t page);
    // Stops watching the pages `s` watches in the allocations `picked` picks (its ranges there
    // are about to go with it, or with their memory).
    static void unguard(Submission& s, const std::function<bool(uint64_t memory)>& picked);
    // Whether a page `s` watches was written since: if not, none of its guarded ranges changed.
    static bool wrote_any_page(const Submission& s);
    // Walks the submission's cluster pauses (or reuses an earlier walk) into `fresh.ranges`, and
    // guards (or hashes) each walk's ranges.
    void walk_pauses(DeviceState& d, HostViewResolver& resolver,
                     const std::vector<const PausePoint*>& pauses, Submission& fresh,
                     WatchLaps& laps);
    // Whether a read of a kept walk still gives its bytes.
    bool still_reads(HostViewResolver& resolver, const HostWriteWalkCache::Read& r);
    // Adds `range` (placed at `host` in the layer's mapping, hashing to `hash`) to `fresh` as a
    // hashed one.
    void add_hashed_range(Range range, const uint8_t* host, uint64_t hash, Submission& fresh);
    // Adds the ranges of a kept walk to `fresh` for pause `pause_id`; returns the first's index.
    static size_t add_kept_ranges(const HostWriteWalkCache::Ranges& kept, uint64_t pause_id,
                                  Submission& fresh);
    struct Probed {
        bool guardable = false;
        uintptr_t host_base = 0;  // the layer's mapping, forgotten by the guard when freed
        size_t size = 0;
    };
    std::mutex mutex_;
    std::deque<Submission> watched_;                   // oldest first
    uint64_t guarded_ranges_ = 0, hashed_ranges_ = 0;  // watched since the device was created
    uint64_t walks_reused_ = 0, walks_ = 0;            // guarded pauses' walks, and those reused
    std::unordered_map<uint64_t, Probed> probed_;      // allocation -> its pages can be guarded
    HostWriteWalkCache walk_cache_;
    WatchPhaseTotals phases_;
    // Where the watch copies the mapped bytes it compares and hashes (copy_host_view); mutex_
    // held. Given back past a bound after each submission and wait (trim_scratch).
    std::vector<uint8_t> scratch_;
    void trim_scratch();
};

}  // namespace clastrace::capture

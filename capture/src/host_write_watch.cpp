// SPDX-License-Identifier: Apache-2.0
#include "host_write_watch.h"

#include "clastrace/capture/capture_cost.h"
#include "clastrace/capture/cluster_input_walker.h"
#include "clastrace/capture/uncached_copy.h"
#include "layer_state.h"

#include <algorithm>
#include <cstring>
#include <map>

#define XXH_INLINE_ALL
#include <xxhash.h>

namespace clastrace::capture {
namespace {

// Submissions never waited for (an application that only waits on the device side) are dropped,
// oldest first, past this many: the watch stays bounded.
constexpr size_t kMaxWatchedSubmissions = 64;

// The host's view of mapped memory: what the host wrote is there, flushed or not.
bool read_host_view(DeviceState& d, VkDeviceAddress address, uint64_t size, CapturedBytes* out,
                    std::string& why, ResolvedRange* where = nullptr) {
    auto range = d.memory_map.resolve(address, size, why);
    if (!range) return false;
    if (!range->host) {
        why = "not mapped: the host cannot write it";
        return false;
    }
    if (where) *where = *range;
    if (!out) return true;
    uint8_t* to = out->fill(size);
    if (range->memory.property_flags & VK_MEMORY_PROPERTY_HOST_CACHED_BIT)
        std::memcpy(to, range->host, size);
    else
        copy_from_uncached(to, range->host, size);
    return true;
}

uint64_t hash_of(const CapturedBytes& bytes) { return XXH3_64bits(bytes.data(), bytes.size()); }

}  // namespace

void HostWriteWatch::submitting(DeviceState& d, const SubmissionRecord& record,
                                const std::vector<const PausePoint*>& pauses,
                                std::vector<MemorySpan> device_writes) {
    CostScope cost(CostPhase::kHostWrites);
    std::lock_guard lock(mutex_);
    for (Submission& s : watched_) look(d, s, HostWriteSeen::kAtSubmit);
    Submission fresh{
        record.index, record.queue, record.fence, {}, {}, std::move(device_writes), {}};
    for (const SubmitBatch& b : record.batches)
        fresh.signals.insert(fresh.signals.end(), b.signals.begin(), b.signals.end());
    DeviceMemoryReader host_view = [&d](VkDeviceAddress a, uint64_t size, CapturedBytes* out,
                                        std::string& why) {
        return read_host_view(d, a, size, out, why);
    };
    for (const PausePoint* pause : pauses) {
        if (!pause->parameters || pause->phase != PausePhase::kBeforeCommand) continue;
        ClusterMemoryWalk walk = walk_cluster_inputs(*pause->parameters, host_view);
        for (const CapturedRange& r : walk.ranges) {
            if (!r.address || !r.bytes.size()) continue;
            ResolvedRange where;
            std::string why;
            if (!read_host_view(d, r.address, r.bytes.size(), nullptr, why, &where)) continue;
            const VkDeviceSize at = where.buffer.memory_offset + where.offset_in_buffer;
            fresh.ranges.push_back({pause->pause_id, r.address, r.bytes.size(),
                                    MemorySpan{where.memory.handle, at, at + r.bytes.size()},
                                    hash_of(r.bytes), 0, false});
        }
    }
    // A submission that only writes is kept too: its writes may change another's inputs.
    if (fresh.ranges.empty() && fresh.device_writes.empty()) return;
    watched_.push_back(std::move(fresh));
    if (watched_.size() > kMaxWatchedSubmissions) {
        const uint64_t oldest = watched_.front().index;
        forget([oldest](const Submission& s) { return s.index == oldest; });
    }
}

void HostWriteWatch::submit_failed(uint64_t index) {
    std::lock_guard lock(mutex_);
    std::erase_if(watched_, [&](const Submission& s) { return s.index == index; });
}

void HostWriteWatch::paused(uint64_t submission, uint64_t pause_id,
                            const std::vector<CapturedRange>& inputs) {
    CostScope cost(CostPhase::kHostWrites);
    std::lock_guard lock(mutex_);
    for (Submission& s : watched_) {
        if (s.index != submission) continue;
        for (Range& r : s.ranges) {
            if (r.pause_id != pause_id) continue;
            auto read = std::find_if(inputs.begin(), inputs.end(), [&](const CapturedRange& c) {
                return c.address == r.address && c.bytes.size() == r.size;
            });
            if (read == inputs.end()) continue;
            r.paused = true;
            r.pause_hash = hash_of(read->bytes);
            r.read_changed = r.pause_hash != r.hash;
        }
    }
}

void HostWriteWatch::waited(DeviceState& d, const std::function<bool(const Submission&)>& orders) {
    CostScope cost(CostPhase::kHostWrites);
    std::lock_guard lock(mutex_);
    std::map<uint64_t, uint64_t> completed_up_to;  // queue -> newest submission ordered
    for (const Submission& s : watched_)
        if (orders(s)) completed_up_to[s.queue] = std::max(completed_up_to[s.queue], s.index + 1);
    auto ordered = [&](const Submission& s) {
        auto it = completed_up_to.find(s.queue);
        return it != completed_up_to.end() && s.index < it->second;
    };
    for (Submission& s : watched_)
        if (ordered(s)) look(d, s, HostWriteSeen::kAtWait);
    forget(ordered);
}

void HostWriteWatch::forget(const std::function<bool(const Submission&)>& gone) {
    std::vector<MemorySpan> written;
    for (const Submission& s : watched_)
        if (gone(s)) written.insert(written.end(), s.device_writes.begin(), s.device_writes.end());
    std::erase_if(watched_, gone);
    // Those submissions ran while the remaining ones were pending: a remaining one's input may
    // have changed by their writes, which its own wait only sees later.
    if (!written.empty())
        for (Submission& s : watched_)
            s.others_writes.insert(s.others_writes.end(), written.begin(), written.end());
}

bool HostWriteWatch::device_may_have_written(const Submission& s, const MemorySpan& span) const {
    if (overlaps_any(s.device_writes, span) || overlaps_any(s.others_writes, span)) return true;
    return std::any_of(watched_.begin(), watched_.end(), [&](const Submission& other) {
        return overlaps_any(other.device_writes, span);
    });
}

void HostWriteWatch::look(DeviceState& d, Submission& s, HostWriteSeen seen) {
    for (Range& r : s.ranges) {
        CapturedBytes now;
        ResolvedRange where;
        std::string why;
        if (!read_host_view(d, r.address, r.size, &now, why, &where)) continue;  // freed, unmapped
        const uint64_t hash = hash_of(now);
        if (hash == r.hash && !r.read_changed) continue;
        if (device_may_have_written(s, r.span)) {
            // Bytes the device may have changed: not claimed as a host write (a limit, in
            // capture/README.md), and the new bytes are what a later look compares with.
            r.hash = hash;
            r.read_changed = false;
            continue;
        }
        HostWriteRecord w;
        // The command read the changed bytes, or its pause has not come yet (a later submission
        // saw the write while the command waited): the pause reads the new bytes, so replay's
        // image holds them by the time it meets this record, and it counts the whole range as
        // written rather than the bytes that differ from its image.
        const bool read_new_bytes = (r.read_changed && hash == r.pause_hash) || !r.paused;
        w.seen = read_new_bytes ? HostWriteSeen::kReadByCommand : seen;
        w.memory = where.memory.handle;
        w.memory_offset = where.buffer.memory_offset + where.offset_in_buffer;
        w.buffer = where.buffer.handle;
        w.buffer_offset = where.offset_in_buffer;
        w.address = r.address;
        w.bytes.assign(now.data(), now.data() + now.size());
        w.submission_index = s.index;
        w.pause_id = r.pause_id;
        if (d.sink) d.sink->host_write_observed(w);
        r.hash = hash;
        r.read_changed = false;  // reported once
    }
}

}  // namespace clastrace::capture

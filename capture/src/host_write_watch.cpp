// SPDX-License-Identifier: Apache-2.0
#include "host_write_watch.h"

#include "clastrace/capture/capture_cost.h"
#include "clastrace/capture/cluster_input_walker.h"
#include "clastrace/capture/uncached_copy.h"
#include "layer_state.h"

#include <algorithm>
#include <cstring>
#include <map>
#include <optional>

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

uint64_t hash_of(const CapturedBytes& bytes) {
    return hash_host_memory(bytes.data(), bytes.size(), true);
}

bool host_cached(const TrackedMemory& memory) {
    return memory.property_flags & VK_MEMORY_PROPERTY_HOST_CACHED_BIT;
}

}  // namespace

// The submission's walk of its mapped inputs, on the application's thread inside vkQueueSubmit:
// a cluster build's ranges are hundreds of small pieces of a few buffers (each cluster's indices
// and vertices), so the last buffer found answers the next range without the memory map's lock
// and search, and the bytes are not copied where the host can read them in place (cached
// memory); uncached memory is copied once, with streaming loads, into blocks reused by every
// submission. The ranges' bytes are borrowed: they live until the next walk.
class SubmitWalkReader {
public:
    explicit SubmitWalkReader(DeviceState& d) : d_(d) {}

    // Where [address, address + size) is and its host pointer; false where the host cannot see it.
    bool resolve(VkDeviceAddress address, uint64_t size, ResolvedRange& where, std::string& why) {
        auto known = std::find_if(buffers_.begin(), buffers_.end(), [&](const ResolvedRange& b) {
            return inside(b.buffer, address, size);
        });
        if (known == buffers_.end()) {
            auto range = d_.memory_map.resolve(address, size, why);
            if (!range) return false;
            if (!range->host) {
                why = "not mapped: the host cannot write it";
                return false;
            }
            // As the whole buffer: the next range of it is an offset away.
            range->host -= range->offset_in_buffer;
            range->offset_in_buffer = 0;
            if (buffers_.size() == kKnownBuffers) buffers_.pop_back();
            buffers_.insert(buffers_.begin(), *range);
            known = buffers_.begin();
        }
        where = *known;
        where.offset_in_buffer = address - known->buffer.address;
        where.host = known->host + where.offset_in_buffer;
        return true;
    }

    bool read(VkDeviceAddress address, uint64_t size, CapturedBytes* out, std::string& why) {
        ResolvedRange where;
        if (!resolve(address, size, where, why)) return false;
        if (!out) return true;
        if (host_cached(where.memory)) {
            *out = CapturedBytes::borrow(where.host, size);
            return true;
        }
        uint8_t* copy = scratch(size);
        copy_from_uncached(copy, where.host, size);
        *out = CapturedBytes::borrow(copy, size);
        return true;
    }

    // Starts a walk: the bytes of the last one are no longer read. Past a bound (a walk of
    // huge uncached ranges) the blocks go back rather than staying with the watch.
    void restart() {
        constexpr uint64_t kKeptBytes = uint64_t{16} << 20;
        uint64_t held = 0;
        for (const auto& block : blocks_) held += block.size();
        if (held > kKeptBytes) blocks_.clear();
        block_ = 0;
        used_ = 0;
        buffers_.clear();
    }

private:
    // A sparse buffer maps its addresses page by page: it is resolved every time.
    static bool inside(const TrackedBuffer& b, VkDeviceAddress address, uint64_t size) {
        return !(b.flags & VK_BUFFER_CREATE_SPARSE_BINDING_BIT) && address >= b.address &&
               address - b.address <= b.size && size <= b.size - (address - b.address);
    }

    uint8_t* scratch(uint64_t size) {
        constexpr uint64_t kBlockBytes = uint64_t{1} << 20;
        while (block_ < blocks_.size() && used_ + size > blocks_[block_].size()) {
            ++block_;
            used_ = 0;
        }
        if (block_ == blocks_.size()) blocks_.emplace_back(std::max(size, kBlockBytes));
        uint8_t* at = blocks_[block_].data() + used_;
        used_ += size;
        return at;
    }

    // A build's inputs lie in a few buffers (indices, vertices, infos, ...), read in turns.
    static constexpr size_t kKnownBuffers = 8;
    DeviceState& d_;
    std::vector<ResolvedRange> buffers_;  // most recently found first
    std::vector<std::vector<uint8_t>> blocks_;
    size_t block_ = 0;
    uint64_t used_ = 0;
};

HostWriteWatch::HostWriteWatch() = default;
HostWriteWatch::~HostWriteWatch() = default;

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
    if (!reader_) reader_ = std::make_unique<SubmitWalkReader>(d);
    SubmitWalkReader& reader = *reader_;
    DeviceMemoryReader host_view = [&reader](VkDeviceAddress a, uint64_t size, CapturedBytes* out,
                                             std::string& why) {
        return reader.read(a, size, out, why);
    };
    for (const PausePoint* pause : pauses) {
        if (!pause->parameters || pause->phase != PausePhase::kBeforeCommand) continue;
        reader.restart();
        ClusterMemoryWalk walk = walk_cluster_inputs(*pause->parameters, host_view);
        fresh.ranges.reserve(fresh.ranges.size() + walk.ranges.size());
        for (const CapturedRange& r : walk.ranges) {
            if (!r.address || !r.bytes.size()) continue;
            ResolvedRange where;
            std::string why;
            if (!reader.resolve(r.address, r.bytes.size(), where, why)) continue;
            const VkDeviceSize at = where.buffer.memory_offset + where.offset_in_buffer;
            fresh.ranges.push_back({pause->pause_id, r.address, r.bytes.size(),
                                    MemorySpan{where.memory.handle, at, at + r.bytes.size()},
                                    hash_of(r.bytes), 0, false});
        }
    }
    reader.restart();  // (no view of this walk outlives it)
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
        // The pause walks the inputs as the submission did, so the range read for the next
        // watched range is usually the next one: the search starts there and wraps around.
        size_t next = 0;
        for (Range& r : s.ranges) {
            if (r.pause_id != pause_id || inputs.empty()) continue;
            const CapturedRange* read = nullptr;
            for (size_t k = 0; k < inputs.size() && !read; ++k) {
                const CapturedRange& c = inputs[(next + k) % inputs.size()];
                if (c.address == r.address && c.bytes.size() == r.size) {
                    read = &c;
                    next = (next + k + 1) % inputs.size();
                }
            }
            if (!read) continue;
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
    std::vector<TrackedMemory> memories;  // the allocations looked up so far
    for (Range& r : s.ranges) {
        // The common case, nothing written: the range is hashed where the layer maps it.
        auto memory = std::find_if(memories.begin(), memories.end(), [&](const TrackedMemory& m) {
            return m.handle == r.span.memory;
        });
        if (memory == memories.end()) {
            auto found = d.memory_map.memory(r.span.memory);
            if (!found) continue;  // freed
            memory = memories.insert(memories.end(), *found);
        }
        if (!memory->host_base || r.span.end > memory->size) continue;  // unmapped
        if (hash_host_memory(memory->host_base + r.span.begin, r.size, host_cached(*memory)) ==
                r.hash &&
            !r.read_changed)
            continue;
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

// SPDX-License-Identifier: Apache-2.0
#include "host_write_watch.h"

#include "clastrace/capture/capture_cost.h"
#include "clastrace/capture/cluster_input_walker.h"
#include "clastrace/capture/uncached_copy.h"
#include "layer_state.h"
#include "page_guard.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cstring>
#include <map>
#include <optional>

#define XXH_INLINE_ALL
#include <xxhash.h>

namespace clastrace::capture {

// Resolves the addresses of one call of the watch. A walk lists runs of ranges inside a few
// buffers (a cluster's indices, then its vertices, then the next cluster's), so the buffers found
// last answer the ranges inside them as the memory map would (the same memory, offset and
// mapping), without the map's lock and lookups each time. Plain buffers only: a sparse buffer's
// pages may lie anywhere.
class HostViewResolver {
public:
    explicit HostViewResolver(const DeviceMemoryMap& map) : map_(map) {}

    // Where [address, address + size) is; null with `why` when no buffer holds it.
    const ResolvedRange* resolve(VkDeviceAddress address, uint64_t size, std::string& why) {
        for (size_t i = 0; i < found_; ++i) {
            ResolvedRange& r = recent_[i];
            if (!plainly_holds(r.buffer, address, size)) continue;
            r.aim_at(address);
            return &r;
        }
        std::optional<ResolvedRange> r = map_.resolve(address, size, why);
        if (!r) return nullptr;
        ResolvedRange& slot = recent_[found_ < kRecent ? found_++ : replace_++ % kRecent];
        slot = std::move(*r);
        return &slot;
    }

private:
    static constexpr size_t kRecent = 4;

    const DeviceMemoryMap& map_;
    std::array<ResolvedRange, kRecent> recent_;
    size_t found_ = 0, replace_ = 0;
};

namespace {

// The watch's scratch copy is given back past this many bytes (a large range hashed once should
// not stay allocated); below it, it is kept for the next call.
constexpr size_t kScratchKept = size_t(16) << 20;

// Submissions never waited for (an application that only waits on the device side) are dropped,
// oldest first, past this many: the watch stays bounded.
constexpr size_t kMaxWatchedSubmissions = 64;

// Bytes the watch copied out of mapped memory (for CLASTRACE_STATS): on a real GPU that memory is
// uncached, and these reads are what the watch costs.
std::atomic<uint64_t> mapped_bytes_read{0};

// Where the layer's mapping holds [address, address + size); null, with `why`, when the host
// cannot write it.
const ResolvedRange* mapped_range(HostViewResolver& resolver, VkDeviceAddress address,
                                  uint64_t size, std::string& why) {
    const ResolvedRange* range = resolver.resolve(address, size, why);
    if (range && !range->host) {
        why = "not mapped: the host cannot write it";
        return nullptr;
    }
    return range;
}

void copy_mapped(const ResolvedRange& range, uint64_t size, uint8_t* to) {
    mapped_bytes_read.fetch_add(size, std::memory_order_relaxed);
    if (range.memory.property_flags & VK_MEMORY_PROPERTY_HOST_CACHED_BIT)
        std::memcpy(to, range.host, size);
    else
        copy_from_uncached(to, range.host, size);
}

// The host's view of mapped memory: what the host wrote is there, flushed or not.
bool read_host_view(HostViewResolver& resolver, VkDeviceAddress address, uint64_t size,
                    CapturedBytes* out, std::string& why) {
    const ResolvedRange* range = mapped_range(resolver, address, size, why);
    if (!range) return false;
    if (out) copy_mapped(*range, size, out->fill(size));
    return true;
}

// The same bytes for the watch's own compares and hashes, copied into `scratch`: grown as
// needed and kept between calls, so a read costs the copy alone, not an allocation and a
// zero fill of the bytes about to be overwritten. Null, with `why`, when not mapped.
const uint8_t* copy_host_view(HostViewResolver& resolver, VkDeviceAddress address, uint64_t size,
                              std::vector<uint8_t>& scratch, std::string& why,
                              ResolvedRange* where = nullptr) {
    const ResolvedRange* range = mapped_range(resolver, address, size, why);
    if (!range) return nullptr;
    if (where) *where = *range;
    if (scratch.size() < size) scratch.resize(size);
    copy_mapped(*range, size, scratch.data());
    return scratch.data();
}

uint64_t hash_of(const CapturedBytes& bytes) { return XXH3_64bits(bytes.data(), bytes.size()); }
uint64_t hash_of(const uint8_t* bytes, uint64_t size) { return XXH3_64bits(bytes, size); }

// The reader of a guarded submission's walk: it copies only what leads the walk to other ranges
// (the count and the indirect cells, 8 bytes at most, and the src infos entries, with streaming
// loads where uncached); the ranges the walk only lists become views it never reads. (With an
// INDIRECTED src infos array the entries are views too, read by the walk's plain loads.) Each copy
// goes to `reads` too, for the walk cache (host_write_walk_cache.h).
DeviceMemoryReader pointer_reader(HostViewResolver& resolver, const ClusterCommandParameters& p,
                                  std::vector<HostWriteWalkCache::Read>& reads) {
    const VkStridedDeviceAddressRegionKHR& src = p.info.srcInfosArray;
    const uint64_t entry = cluster_src_info_size(p.info.input.opType);
    const uint64_t stride = src.stride ? src.stride : entry;
    const uint64_t most = p.info.input.maxAccelerationStructureCount;
    const uint64_t span = src.size ? src.size : (most ? (most - 1) * stride + entry : 0);
    const VkDeviceAddress begin = src.deviceAddress, end = begin + span;
    return [&resolver, &reads, begin, end](VkDeviceAddress a, uint64_t size, CapturedBytes* out,
                                           std::string& why) {
        if (!out) return read_host_view(resolver, a, size, out, why);
        if (size <= sizeof(VkDeviceAddress) || (a >= begin && a < end)) {
            if (!read_host_view(resolver, a, size, out, why)) return false;
            reads.push_back({a, std::vector<uint8_t>(out->data(), out->data() + out->size())});
            return true;
        }
        const ResolvedRange* where = mapped_range(resolver, a, size, why);
        if (!where) return false;
        *out = CapturedBytes::borrow(where->host, size);
        return true;
    };
}

struct PageSpan {
    uintptr_t first = 0;
    size_t count = 0;
};

PageSpan pages_of(const uint8_t* host, uint64_t size, size_t page_size) {
    const uintptr_t begin = reinterpret_cast<uintptr_t>(host) & ~uintptr_t(page_size - 1);
    const uintptr_t last =
        (reinterpret_cast<uintptr_t>(host) + size - 1) & ~uintptr_t(page_size - 1);
    return {begin, (last - begin) / page_size + 1};
}

// Only pages wholly inside the allocation's bytes are protected: the rest of a page it only
// partly covers may be other memory (a driver's suballocation, the C heap), whose writes would
// fault too, and a system call writing there fail.
bool inside_mapping(const TrackedMemory& memory, const PageSpan& pages, size_t page_size) {
    const auto base = reinterpret_cast<uintptr_t>(memory.host_base);
    return pages.first >= base && pages.first + pages.count * page_size <= base + memory.size;
}

void append_pages(std::vector<uintptr_t>& out, const PageSpan& pages, size_t page_size) {
    for (size_t i = 0; i < pages.count; ++i) out.push_back(pages.first + i * page_size);
}

// A walk's ranges by allocation, each group with the pages the guard would hold for it.
HostWriteWalkCache::Ranges grouped(std::vector<HostWriteWalkCache::Found> found, size_t page_size) {
    HostWriteWalkCache::Ranges out;
    for (size_t i = 0; i < found.size(); ++i) {
        const HostWriteWalkCache::Found& f = found[i];
        auto group = std::find_if(out.groups.begin(), out.groups.end(), [&](const auto& g) {
            return g.memory.handle == f.memory.handle;
        });
        if (group == out.groups.end())
            group = out.groups.insert(out.groups.end(),
                                      HostWriteWalkCache::Group{f.memory, {}, {}, {}});
        const PageSpan pages = pages_of(f.host, f.size, page_size);
        if (!inside_mapping(f.memory, pages, page_size)) {
            group->hashed.push_back(uint32_t(i));
            continue;
        }
        append_pages(group->pages, pages, page_size);
        group->on_pages.push_back(uint32_t(i));
    }
    // Each page once: the walk is one watcher of it, however many of its ranges lie there.
    for (HostWriteWalkCache::Group& g : out.groups) {
        std::sort(g.pages.begin(), g.pages.end());
        g.pages.erase(std::unique(g.pages.begin(), g.pages.end()), g.pages.end());
    }
    out.found = std::move(found);
    return out;
}

bool any_page_written(const PageGuard& guard, const HostWriteWatch::Range& r) {
    const PageSpan pages = pages_of(r.host, r.size, guard.page_size());
    for (size_t i = 0; i < pages.count; ++i)
        if (guard.before_image(pages.first + i * guard.page_size())) return true;
    return false;
}

// Whether `bytes` (the range now, or as its pause read it) differ from the range at its
// submission. Pages not written since hold what they held then, so only the written ones are
// compared, against their before-images.
bool differs_from_submitted(const PageGuard& guard, const HostWriteWatch::Range& r,
                            const uint8_t* bytes) {
    const size_t page_size = guard.page_size();
    const auto begin = reinterpret_cast<uintptr_t>(r.host), end = begin + r.size;
    const PageSpan pages = pages_of(r.host, r.size, page_size);
    for (size_t i = 0; i < pages.count; ++i) {
        const uintptr_t page = pages.first + i * page_size;
        const uint8_t* before = guard.before_image(page);
        if (!before) continue;
        const uintptr_t from = std::max(begin, page), to = std::min(end, page + page_size);
        if (std::memcmp(before + (from - page), bytes + (from - begin), to - from) != 0)
            return true;
    }
    return false;
}

}  // namespace

void HostWriteWatch::guard_or_hash(HostViewResolver& resolver,
                                   const HostWriteWalkCache::Group& group, size_t first,
                                   Submission& s, WatchLaps& laps) {
    PageGuard* guard = PageGuard::instance();
    guard->set_resting(layer_config().guard_rest);
    const bool uncached = !(group.memory.property_flags & VK_MEMORY_PROPERTY_HOST_CACHED_BIT);
    const bool held = !group.on_pages.empty() && probed(group.memory, group.pages.front()) &&
                      guard->watch(group.pages, uncached);
    if (held) {
        for (uint32_t i : group.on_pages) s.ranges[first + i].guarded = true;
        guarded_ranges_ += group.on_pages.size();
        s.guarded.push_back({group.memory.handle, group.pages});
    }
    laps.lap(WatchPhase::kSubmitGuard);
    auto hash = [&](uint32_t i) {
        Range& r = s.ranges[first + i];
        std::string why;
        const uint8_t* now = copy_host_view(resolver, r.address, r.size, scratch_, why);
        r.hash = now ? hash_of(now, r.size) : hash_of(nullptr, 0);
        s.hashed.push_back(uint32_t(first + i));
        ++hashed_ranges_;
    };
    for (uint32_t i : group.hashed) hash(i);
    if (!held)
        for (uint32_t i : group.on_pages) hash(i);
    laps.lap(WatchPhase::kSubmitHash);
}

bool HostWriteWatch::probed(const TrackedMemory& memory, uintptr_t page) {
    auto it = probed_.find(memory.handle);
    if (it == probed_.end())
        it = probed_
                 .emplace(memory.handle,
                          Probed{PageGuard::instance()->probe(page),
                                 reinterpret_cast<uintptr_t>(memory.host_base), memory.size})
                 .first;
    return it->second.guardable;
}

void HostWriteWatch::unguard(Submission& s, const std::function<bool(uint64_t memory)>& picked) {
    std::erase_if(s.guarded, [&](GuardedPages& g) {
        if (!picked(g.memory)) return false;
        PageGuard::instance()->unwatch(std::move(g.pages));
        return true;
    });
}

bool HostWriteWatch::wrote_any_page(const Submission& s) {
    const PageGuard* guard = s.guarded.empty() ? nullptr : PageGuard::instance();
    for (const GuardedPages& g : s.guarded)
        for (uintptr_t page : g.pages)
            if (guard->before_image(page)) return true;
    return false;
}

bool HostWriteWatch::still_reads(HostViewResolver& resolver, const HostWriteWalkCache::Read& r) {
    std::string why;
    const uint8_t* now = copy_host_view(resolver, r.address, r.bytes.size(), scratch_, why);
    return now && std::memcmp(now, r.bytes.data(), r.bytes.size()) == 0;
}

void HostWriteWatch::add_hashed_range(Range range, const uint8_t* host, uint64_t hash,
                                      Submission& fresh) {
    range.host = host;
    range.hash = hash;
    ++hashed_ranges_;
    fresh.hashed.push_back(uint32_t(fresh.ranges.size()));
    fresh.ranges.push_back(std::move(range));
}

size_t HostWriteWatch::add_kept_ranges(const HostWriteWalkCache::Ranges& kept, uint64_t pause_id,
                                       Submission& fresh) {
    const size_t first = fresh.ranges.size();
    fresh.ranges.reserve(first + kept.found.size());
    for (const HostWriteWalkCache::Found& f : kept.found) {
        Range range{pause_id, f.address, f.size, f.span};
        range.host = f.host;
        fresh.ranges.push_back(std::move(range));
    }
    return first;
}

void HostWriteWatch::walk_pauses(DeviceState& d, HostViewResolver& resolver,
                                 const std::vector<const PausePoint*>& pauses, Submission& fresh,
                                 WatchLaps& laps) {
    const bool guarding = layer_config().host_write_guard && PageGuard::instance();
    DeviceMemoryReader host_view = [&resolver](VkDeviceAddress a, uint64_t size, CapturedBytes* out,
                                               std::string& why) {
        return read_host_view(resolver, a, size, out, why);
    };
    auto unchanged = [&](const HostWriteWalkCache::Read& r) { return still_reads(resolver, r); };
    for (const PausePoint* pause : pauses) {
        if (!pause->parameters || pause->phase != PausePhase::kBeforeCommand) continue;
        const ClusterCommandParameters& p = *pause->parameters;
        // Read before the walk: a change of the map meanwhile leaves the walk kept unfound.
        const uint64_t map_changes = d.memory_map.changes();
        const HostWriteWalkCache::Ranges* kept =
            guarding ? walk_cache_.find(p, map_changes, unchanged) : nullptr;
        HostWriteWalkCache::Ranges walked;
        if (guarding) ++walks_;
        if (kept) {
            ++walks_reused_;
            laps.lap(WatchPhase::kSubmitWalk);
        } else {
            std::vector<HostWriteWalkCache::Read> reads;
            ClusterMemoryWalk walk =
                walk_cluster_inputs(p, guarding ? pointer_reader(resolver, p, reads) : host_view);
            laps.lap(WatchPhase::kSubmitWalk);
            for (const CapturedRange& r : walk.ranges) {
                if (!r.address || !r.bytes.size()) continue;
                std::string why;
                const ResolvedRange* where = resolver.resolve(r.address, r.bytes.size(), why);
                if (!where || !where->host) continue;
                const VkDeviceSize at = where->buffer.memory_offset + where->offset_in_buffer;
                const MemorySpan span{where->memory.handle, at, at + r.bytes.size()};
                if (guarding) {
                    walked.found.push_back(
                        {r.address, r.bytes.size(), span, where->host, where->memory});
                    continue;
                }
                add_hashed_range({pause->pause_id, r.address, r.bytes.size(), span}, where->host,
                                 hash_of(r.bytes), fresh);
            }
            if (!guarding) {
                laps.lap(WatchPhase::kSubmitHash);
                continue;
            }
            walked = grouped(std::move(walked.found), PageGuard::instance()->page_size());
            kept = HostWriteWalkCache::keepable(p)
                       ? &walk_cache_.keep(p, map_changes, std::move(reads), std::move(walked))
                       : &walked;
        }
        const size_t first = add_kept_ranges(*kept, pause->pause_id, fresh);
        laps.lap(WatchPhase::kSubmitResolve);
        for (const HostWriteWalkCache::Group& group : kept->groups)
            guard_or_hash(resolver, group, first, fresh, laps);
    }
}

void HostWriteWatch::submitting(DeviceState& d, const SubmissionRecord& record,
                                const std::vector<const PausePoint*>& pauses,
                                std::vector<MemorySpan> device_writes) {
    CostScope cost(CostPhase::kHostWrites, true);  // on-CPU against wall: what waits
    WatchLaps laps(phases_, WatchCall::kSubmit);
    std::lock_guard lock(mutex_);
    laps.lap(WatchPhase::kSubmitLockWait);
    for (Submission& s : watched_) look(d, s, HostWriteSeen::kAtSubmit);
    laps.lap(WatchPhase::kSubmitLook);
    Submission fresh{
        record.index, record.queue, record.fence, {}, {}, {}, std::move(device_writes), {}, {}, {}};
    for (const SubmitBatch& b : record.batches)
        fresh.signals.insert(fresh.signals.end(), b.signals.begin(), b.signals.end());
    HostViewResolver resolver(d.memory_map);
    walk_pauses(d, resolver, pauses, fresh, laps);
    trim_scratch();
    phases_.add_ranges(fresh.ranges.size());
    // A submission that only writes is kept too: its writes may change another's inputs.
    if (fresh.ranges.empty() && fresh.device_writes.empty()) return;
    watched_.push_back(std::move(fresh));
    if (watched_.size() > kMaxWatchedSubmissions) {
        const uint64_t oldest = watched_.front().index;
        forget([oldest](const Submission& s) { return s.index == oldest; });
    }
    laps.lap(WatchPhase::kSubmitKeep);
}

void HostWriteWatch::trim_scratch() {
    if (scratch_.capacity() <= kScratchKept) return;
    scratch_.clear();
    scratch_.shrink_to_fit();
}

void HostWriteWatch::submit_failed(uint64_t index) {
    std::lock_guard lock(mutex_);
    forget([&](const Submission& s) { return s.index == index; });
}

void HostWriteWatch::memory_freed(uint64_t memory) {
    std::lock_guard lock(mutex_);
    for (Submission& s : watched_) {
        unguard(s, [memory](uint64_t m) { return m == memory; });
        std::erase_if(s.ranges, [&](const Range& r) { return r.span.memory == memory; });
        s.hashed.clear();
        for (size_t i = 0; i < s.ranges.size(); ++i)
            if (!s.ranges[i].guarded) s.hashed.push_back(uint32_t(i));
    }
    // Its pages left read-only past their watchers: writable again before the mapping goes.
    auto it = probed_.find(memory);
    if (it == probed_.end()) return;
    if (it->second.guardable && PageGuard::instance())
        PageGuard::instance()->forget_memory(it->second.host_base, it->second.size);
    probed_.erase(it);
}

HostWriteWatch::~HostWriteWatch() {
    for (Submission& s : watched_) unguard(s, [](uint64_t) { return true; });
    for (const auto& [memory, p] : probed_)
        if (p.guardable) PageGuard::instance()->forget_memory(p.host_base, p.size);
}

std::string HostWriteWatch::mode_line() {
    std::lock_guard lock(mutex_);
    const std::string read =
        std::to_string(mapped_bytes_read.load(std::memory_order_relaxed)) + " bytes read";
    if (!layer_config().host_write_guard) return "host-write watch: hash: " + read;
    PageGuard* guard = PageGuard::instance();
    if (!guard) return "host-write watch: hash (the page guard could not start): " + read;
    const PageGuard::Counts counts = guard->counts();
    return "host-write watch: guard: " + std::to_string(guarded_ranges_) +
           " ranges write-protected, " + std::to_string(hashed_ranges_) + " hashed (" +
           std::to_string(counts.refused) + " refused by mprotect), " +
           std::to_string(counts.faults) + " pages written while protected (" +
           std::to_string(counts.resting_faults) + " more after their waits), " + read +
           " besides those pages, " + std::to_string(walks_reused_) + " of " +
           std::to_string(walks_) + " walks reused";
}

std::vector<std::string> HostWriteWatch::phase_lines() const {
    PageGuard* guard = layer_config().host_write_guard ? PageGuard::instance() : nullptr;
    if (!guard) return phases_.lines(nullptr);
    const PageGuard::Counts counts = guard->counts();
    return phases_.lines(&counts);
}

void HostWriteWatch::paused(uint64_t submission, uint64_t pause_id,
                            const std::vector<CapturedRange>& inputs) {
    CostScope cost(CostPhase::kHostWrites, true);  // on-CPU against wall: what waits
    WatchLaps laps(phases_, WatchCall::kPause);
    std::lock_guard lock(mutex_);
    laps.lap(WatchPhase::kPauseLockWait);
    // The submission's walk and the pause's list the ranges in one order, so each range's read is
    // searched for from just past the last one found (equal address and size hold equal bytes:
    // one pause reads them at one time).
    size_t next = 0;
    auto read_of = [&](const Range& r) -> const CapturedRange* {
        for (size_t k = 0; k < inputs.size(); ++k) {
            const size_t i = (next + k) % inputs.size();
            if (inputs[i].address != r.address || inputs[i].bytes.size() != r.size) continue;
            next = i + 1;
            return &inputs[i];
        }
        return nullptr;
    };
    auto compare = [&](Range& r) {
        if (r.pause_id != pause_id) return;
        const CapturedRange* read = read_of(r);
        if (!read) return;
        if (r.guarded) {  // compared only where its pages were written
            r.read_changed = differs_from_submitted(*PageGuard::instance(), r, read->bytes.data());
            if (r.read_changed) r.pause_hash = hash_of(read->bytes);
            return;
        }
        r.pause_hash = hash_of(read->bytes);
        r.read_changed = r.pause_hash != r.hash;
    };
    for (Submission& s : watched_) {
        if (s.index != submission) continue;
        s.paused.push_back(pause_id);
        // No page written: the guarded ranges hold what they held at the submission, and only
        // the hashed ones are compared.
        if (wrote_any_page(s))
            for (Range& r : s.ranges) compare(r);
        else
            for (uint32_t i : s.hashed) compare(s.ranges[i]);
    }
    laps.lap(WatchPhase::kPauseCompare);
}

void HostWriteWatch::waited(DeviceState& d, const std::function<bool(const Submission&)>& orders) {
    CostScope cost(CostPhase::kHostWrites, true);  // on-CPU against wall: what waits
    WatchLaps laps(phases_, WatchCall::kWait);
    std::lock_guard lock(mutex_);
    laps.lap(WatchPhase::kWaitLockWait);
    std::map<uint64_t, uint64_t> completed_up_to;  // queue -> newest submission ordered
    for (const Submission& s : watched_)
        if (orders(s)) completed_up_to[s.queue] = std::max(completed_up_to[s.queue], s.index + 1);
    auto ordered = [&](const Submission& s) {
        auto it = completed_up_to.find(s.queue);
        return it != completed_up_to.end() && s.index < it->second;
    };
    for (Submission& s : watched_)
        if (ordered(s)) look(d, s, HostWriteSeen::kAtWait);
    laps.lap(WatchPhase::kWaitLook);
    forget(ordered);
    trim_scratch();
    laps.lap(WatchPhase::kWaitUnprotect);
}

void HostWriteWatch::forget(const std::function<bool(const Submission&)>& gone) {
    std::vector<MemorySpan> written;
    for (Submission& s : watched_) {
        if (!gone(s)) continue;
        written.insert(written.end(), s.device_writes.begin(), s.device_writes.end());
        unguard(s, [](uint64_t) { return true; });
    }
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
    HostViewResolver resolver(d.memory_map);
    if (!wrote_any_page(s)) {  // the guarded ranges hold what they held at the submission
        for (uint32_t i : s.hashed) look_at(d, resolver, s, s.ranges[i], seen);
        return;
    }
    for (uint32_t i = 0; i < s.ranges.size(); ++i) {
        Range& r = s.ranges[i];
        // A guarded range none of whose pages was written holds what it held at the submission.
        if (r.guarded && !any_page_written(*PageGuard::instance(), r)) continue;
        if (r.guarded) s.hashed.push_back(i);  // hashed from now on (look_at)
        look_at(d, resolver, s, r, seen);
    }
}

void HostWriteWatch::look_at(DeviceState& d, HostViewResolver& resolver, Submission& s, Range& r,
                             HostWriteSeen seen) {
    ResolvedRange where;
    std::string why;
    const uint8_t* now = copy_host_view(resolver, r.address, r.size, scratch_, why, &where);
    if (!now) return;  // freed, unmapped
    const uint64_t hash = hash_of(now, r.size);
    bool changed = hash != r.hash;
    if (r.guarded) {  // hashed from now on (its pages stay watched till the submission goes)
        changed = differs_from_submitted(*PageGuard::instance(), r, now);
        r.guarded = false;
    }
    if (!changed && !r.read_changed) {
        r.hash = hash;
        return;
    }
    if (device_may_have_written(s, r.span)) {
        // Bytes the device may have changed: not claimed as a host write (a limit, in
        // capture/README.md), and the new bytes are what a later look compares with.
        r.hash = hash;
        r.read_changed = false;
        return;
    }
    HostWriteRecord w;
    // The command read the changed bytes, or its pause has not come yet (a later submission
    // saw the write while the command waited): the pause reads the new bytes, so replay's
    // image holds them by the time it meets this record, and it counts the whole range as
    // written rather than the bytes that differ from its image.
    const bool paused = std::find(s.paused.begin(), s.paused.end(), r.pause_id) != s.paused.end();
    const bool read_new_bytes = (r.read_changed && hash == r.pause_hash) || !paused;
    w.seen = read_new_bytes ? HostWriteSeen::kReadByCommand : seen;
    w.memory = where.memory.handle;
    w.memory_offset = where.buffer.memory_offset + where.offset_in_buffer;
    w.buffer = where.buffer.handle;
    w.buffer_offset = where.offset_in_buffer;
    w.address = r.address;
    w.bytes.assign(now, now + r.size);
    w.submission_index = s.index;
    w.pause_id = r.pause_id;
    if (d.sink) d.sink->host_write_observed(w);
    r.hash = hash;
    r.read_changed = false;  // reported once
}

}  // namespace clastrace::capture

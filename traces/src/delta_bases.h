// SPDX-License-Identifier: Apache-2.0
// The real bytes of delta contents' bases, shared by the trace reader's thread and its read-ahead
// task: the buffers (pooled, so a frame loop costs no fresh pages) and the caches of recent contents
// by key, with their byte budgets.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <unordered_map>
#include <vector>

namespace clastrace::traces::reader {

// The real bytes of one content. Filled once, then only read: the reader's base cache, the
// read-ahead task's and the chunk the task decoded share them across the two threads.
struct RealBytes {
    std::unique_ptr<uint8_t[]> data;
    size_t size = 0;
    size_t capacity = 0;
};
using SharedBytes = std::shared_ptr<const RealBytes>;

// Buffers of RealBytes that no cache holds any more, handed out again: a content of a frame
// loop costs no fresh pages (first touches of new pages cost about as much as a copy).
class BytesPool : public std::enable_shared_from_this<BytesPool> {
public:
    // A buffer of n bytes whose contents are undefined; it comes back here once dropped.
    std::shared_ptr<RealBytes> take(size_t n) {
        std::unique_ptr<RealBytes> b;
        {
            std::lock_guard lock(mutex_);
            auto best = free_.end();  // the smallest that fits
            for (auto it = free_.begin(); it != free_.end(); ++it)
                if ((*it)->capacity >= n &&
                    (best == free_.end() || (*it)->capacity < (*best)->capacity))
                    best = it;
            if (best != free_.end()) {
                b = std::move(*best);
                free_.erase(best);
                free_bytes_ -= b->capacity;
            }
        }
        if (!b) {
            b = std::make_unique<RealBytes>();
            b->data.reset(new uint8_t[std::max<size_t>(n, 1)]);
            b->capacity = n;
            allocated_bytes_ += n;
        }
        b->size = n;
        return std::shared_ptr<RealBytes>(b.release(), [pool = shared_from_this()](RealBytes* r) {
            pool->give(r);
        });
    }

    // TraceReadStats::real_bytes_allocated.
    uint64_t allocated_bytes() const { return allocated_bytes_.load(); }

private:
    static constexpr size_t kMaxFree = 8;
    static constexpr size_t kMaxFreeBytes = size_t{32} << 20;
    void give(RealBytes* r) {
        std::unique_ptr<RealBytes> b(r);
        std::lock_guard lock(mutex_);
        if (free_.size() < kMaxFree && free_bytes_ + b->capacity <= kMaxFreeBytes) {
            free_bytes_ += b->capacity;
            free_.push_back(std::move(b));
        }
    }
    std::mutex mutex_;
    std::vector<std::unique_ptr<RealBytes>> free_;
    size_t free_bytes_ = 0;
    std::atomic<uint64_t> allocated_bytes_{0};
};

// The real bytes of the contents a scan passed last, up to a byte budget (the oldest go
// first), so that a delta's base costs a lookup rather than a walk back through its chain.
// A hash keeps the bytes it was first given: the reader compares them by identity with those
// the read-ahead task decoded against.
//
// A base that a delta has used is usually done with: the writer's next delta of that range
// names the new contents. Such bases move to a small second budget and go first, so that their
// buffers come back to the pool within a few frames instead of after 64 MiB of fresh pages
// (a page's first touch costs about what a copy of it does). A base used twice (two ranges
// that held the same bytes) is still found while it is among the used ones kept, and else
// read again through its chain.
struct RealBytesCache {
    static constexpr uint64_t kBudgetBytes = uint64_t{64} << 20;
    static constexpr uint64_t kUsedBudgetBytes = uint64_t{4} << 20;
    explicit RealBytesCache(uint64_t budget = kBudgetBytes) : budget_bytes(budget) {}
    // What this cache may hold; a content above a quarter of it is never kept.
    uint64_t budget_bytes;
    struct Entry {
        SharedBytes bytes;
        uint64_t sequence;  // when it was kept or last moved, to tell stale queue places
        bool used;
    };
    struct Place {
        uint64_t hash, sequence;
    };
    std::unordered_map<uint64_t, Entry> by_hash;
    std::deque<Place> oldest_first, oldest_used_first;  // places of entries gone are skipped
    uint64_t bytes_held = 0, used_bytes_held = 0;
    uint64_t next_sequence = 0;

    SharedBytes find(uint64_t hash) const {
        auto it = by_hash.find(hash);
        return it == by_hash.end() ? nullptr : it->second.bytes;
    }
    void keep(uint64_t hash, SharedBytes bytes) {
        const size_t n = bytes->size;
        if (n > budget_bytes / 4 || by_hash.count(hash)) return;
        while (bytes_held + n > budget_bytes && evict_oldest()) {}
        by_hash.emplace(hash, Entry{std::move(bytes), next_sequence, false});
        oldest_first.push_back({hash, next_sequence++});
        bytes_held += n;
    }
    // The bytes kept for `hash` no longer answer for it (another record defines it again).
    void forget(uint64_t hash) {
        auto it = by_hash.find(hash);
        if (it == by_hash.end()) return;
        bytes_held -= it->second.bytes->size;
        if (it->second.used) used_bytes_held -= it->second.bytes->size;
        by_hash.erase(it);  // its queue places are no longer live, and are skipped
    }
    // A delta was decoded against `hash`: it goes among the used bases.
    void note_used(uint64_t hash) {
        auto it = by_hash.find(hash);
        if (it == by_hash.end() || it->second.used) return;
        it->second.used = true;
        it->second.sequence = next_sequence;
        oldest_used_first.push_back({hash, next_sequence++});
        used_bytes_held += it->second.bytes->size;
        while (used_bytes_held > kUsedBudgetBytes && evict_from(oldest_used_first, true)) {}
        if (oldest_first.size() > 2 * by_hash.size() + 64) drop_stale(oldest_first, false);
    }

private:
    bool live(const Place& p, bool used) const {
        auto it = by_hash.find(p.hash);
        return it != by_hash.end() && it->second.sequence == p.sequence && it->second.used == used;
    }
    // Places of entries that moved or went, dropped at once so the queue stays near the map's size.
    void drop_stale(std::deque<Place>& queue, bool used) {
        std::erase_if(queue, [&](const Place& p) { return !live(p, used); });
    }
    bool evict_oldest() {
        return evict_from(oldest_used_first, true) || evict_from(oldest_first, false);
    }
    // Drops the oldest live entry of `queue` (true), or finds none (false).
    bool evict_from(std::deque<Place>& queue, bool used) {
        while (!queue.empty()) {
            const Place p = queue.front();
            queue.pop_front();
            if (!live(p, used)) continue;
            auto it = by_hash.find(p.hash);
            const size_t n = it->second.bytes->size;
            bytes_held -= n;
            if (used) used_bytes_held -= n;
            by_hash.erase(it);
            return true;
        }
        return false;
    }
};

}  // namespace clastrace::traces::reader

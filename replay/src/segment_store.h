// SPDX-License-Identifier: Apache-2.0
// SegmentStore: disjoint address segments [begin, end), each owning a Body, kept as one sorted
// array of small entries plus a pool of bodies. It replaces a std::map keyed by begin: the
// search runs over a few KB of contiguous keys instead of large tree nodes, splits and merges
// cost one move of trivially copyable entries, and freed bodies go back to the pool with their
// heap capacity (a body's read list) kept for the next segment.
//
// The search for an address runs over a separate array of the segments' ends (8 bytes a
// segment), branch-free: a command's accesses jump between its arrays, so neither a cached
// "last segment" nor the search's branches predict well.
//
// Body needs a default constructor, copy assignment and clear(). Internal to replay; a
// template only so that tests can check it against a per-byte reference with a plain body.
#pragma once

#include <clastrace/common/debug_assert.h>

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace clastrace::replay::detail {

// Tests only: reaches into a store to break it on purpose (segment_store_invariants_test.cpp).
template <class Body>
struct SegmentStoreTestAccess;

template <class Body>
class SegmentStore {
public:
    struct Entry {
        uint64_t begin;
        uint64_t end;
        uint32_t body;
    };

    std::size_t size() const { return entries_.size(); }

    // Visits [begin, end) in address order: segments straddling either end are split first
    // (one piece keeps the body, the other gets a copy of it), gaps become new
    // segments handed to fresh(Body&, begin, end), and existing ones go to
    // touch(Body&, begin, end). With `merge`, the segments inside [begin, end) then become one,
    // keeping the first one's body (the caller made them all equal).
    template <class Fresh, class Touch>
    void update(uint64_t begin, uint64_t end, bool merge, Fresh&& fresh, Touch&& touch) {
        if (end <= begin) return;
        const std::size_t first = first_ending_after(begin);
        std::size_t next = first;  // entries[next..] are not yet consumed
        pieces_.clear();
        uint64_t cursor = begin;
        bool have_carry = false;  // a copy split off the straddling entry, not yet in pieces_
        Entry carry{};
        if (next < entries_.size() && entries_[next].begin < begin) {
            const Entry e = entries_[next++];
            pieces_.push_back({e.begin, begin, e.body});
            carry = {begin, e.end, copy_of(e.body)};
            have_carry = true;
        }
        std::size_t inside_from = pieces_.size();
        while (cursor < end) {
            const bool have = have_carry || next < entries_.size();
            const Entry seg_peek =
                have_carry ? carry : (next < entries_.size() ? entries_[next] : Entry{});
            if (!have || seg_peek.begin > cursor) {
                const uint64_t gap_end = have ? std::min(end, seg_peek.begin) : end;
                const uint32_t b = allocate();
                fresh(bodies_[b], cursor, gap_end);
                pieces_.push_back({cursor, gap_end, b});
                cursor = gap_end;
                continue;
            }
            Entry seg = seg_peek;
            if (have_carry)
                have_carry = false;
            else
                ++next;
            bool has_tail = false;
            Entry tail{};
            if (seg.end > end) {
                tail = {end, seg.end, copy_of(seg.body)};
                seg.end = end;
                has_tail = true;
            }
            touch(bodies_[seg.body], seg.begin, seg.end);
            pieces_.push_back(seg);
            cursor = seg.end;
            if (has_tail) pieces_.push_back(tail);
        }
        if (merge) {
            // Pieces inside [begin, end): from inside_from up to a tail (which begins at end).
            std::size_t inside_to = pieces_.size();
            if (inside_to > inside_from && pieces_[inside_to - 1].begin >= end) --inside_to;
            if (inside_to - inside_from > 1) {
                for (std::size_t k = inside_from + 1; k < inside_to; ++k) release(pieces_[k].body);
                pieces_[inside_from].end = end;
                pieces_.erase(pieces_.begin() + std::ptrdiff_t(inside_from + 1),
                              pieces_.begin() + std::ptrdiff_t(inside_to));
            }
        }
        splice(first, next, pieces_);
        CLASTRACE_DEBUG_ASSERT(entries_hold(first, first + pieces_.size()));
    }

    // Makes `at` a segment boundary if a segment straddles it.
    void split_at(uint64_t at) {
        const std::size_t i = first_ending_after(at);
        if (i >= entries_.size() || entries_[i].begin >= at) return;
        const Entry e = entries_[i];
        const Entry tail{at, e.end, copy_of(e.body)};
        entries_[i].end = at;
        entries_.insert(entries_.begin() + std::ptrdiff_t(i + 1), tail);
        ends_[i] = at;
        ends_.insert(ends_.begin() + std::ptrdiff_t(i + 1), tail.end);
        CLASTRACE_DEBUG_ASSERT(entries_hold(i, i + 2));
    }

    // Calls fn(Body&, begin, end) on every segment meeting [lo, hi), in address order.
    template <class Fn>
    void for_each(Fn&& fn, uint64_t lo = 0, uint64_t hi = UINT64_MAX) {
        for (std::size_t i = first_ending_after(lo); i < entries_.size() && entries_[i].begin < hi;
             ++i)
            fn(bodies_[entries_[i].body], entries_[i].begin, entries_[i].end);
    }
    template <class Fn>
    void for_each(Fn&& fn) const {
        for (const Entry& e : entries_) fn(bodies_[e.body], e.begin, e.end);
    }

    // Drops the segments meeting [lo, hi) for which drop(Body&, begin, end) says so (it may
    // also edit the body of those it keeps), in one pass.
    template <class Drop>
    void erase_if(Drop&& drop, uint64_t lo = 0, uint64_t hi = UINT64_MAX) {
        std::size_t out = first_ending_after(lo), in = out;
        for (; in < entries_.size() && entries_[in].begin < hi; ++in) {
            const Entry e = entries_[in];
            if (drop(bodies_[e.body], e.begin, e.end)) {
                release(e.body);
            } else {
                ends_[out] = e.end;
                entries_[out++] = e;
            }
        }
        if (out != in) {
            entries_.erase(entries_.begin() + std::ptrdiff_t(out),
                           entries_.begin() + std::ptrdiff_t(in));
            ends_.erase(ends_.begin() + std::ptrdiff_t(out), ends_.begin() + std::ptrdiff_t(in));
        }
        CLASTRACE_DEBUG_ASSERT(entries_hold(out, out));
    }

    // Bytes held: entries, bodies (pooled ones too) and whatever body_heap_bytes says a body
    // holds on the heap.
    template <class HeapBytes>
    std::size_t memory_bytes(HeapBytes&& body_heap_bytes) const {
        std::size_t bytes =
            entries_.capacity() * sizeof(Entry) + ends_.capacity() * sizeof(uint64_t) +
            bodies_.capacity() * sizeof(Body) + free_.capacity() * sizeof(uint32_t) +
            pieces_.capacity() * sizeof(Entry);
        for (const Body& b : bodies_) bytes += body_heap_bytes(b);
        return bytes;
    }

    // Every segment non-empty, sorted and disjoint, its end mirrored in the search array, and
    // its body its own (no two segments share one, none is in the free pool). O(segments):
    // for tests; the mutations check only the entries they wrote.
    bool invariants_hold() const {
        if (!entries_hold(0, entries_.size())) return false;
        std::vector<bool> used(bodies_.size(), false);
        for (uint32_t b : free_) {
            if (b >= used.size() || used[b]) return false;
            used[b] = true;
        }
        for (const Entry& e : entries_) {
            if (used[e.body]) return false;
            used[e.body] = true;
        }
        return true;
    }

private:
    friend struct SegmentStoreTestAccess<Body>;

    // Entries [from, to) are non-empty, mirrored in ends_ and own a body in range, and the
    // entries from `from - 1` to `to` are sorted and disjoint (so the range meets its neighbours).
    bool entries_hold(std::size_t from, std::size_t to) const {
        if (ends_.size() != entries_.size() || to > entries_.size()) return false;
        for (std::size_t k = from; k < to; ++k) {
            const Entry& e = entries_[k];
            if (e.begin >= e.end || ends_[k] != e.end || e.body >= bodies_.size()) return false;
        }
        const std::size_t last = std::min(to + 1, entries_.size());
        for (std::size_t k = std::max<std::size_t>(from, 1); k < last; ++k)
            if (entries_[k - 1].end > entries_[k].begin) return false;
        return true;
    }

    // Index of the first entry whose end lies past `at` (the one holding `at`, or the next).
    std::size_t first_ending_after(uint64_t at) const {
        // Entries are disjoint and sorted, so their ends are sorted too.
        const std::size_t n = ends_.size();
        if (n == 0) return 0;
        const uint64_t* base = ends_.data();
        std::size_t len = n;
        while (len > 1) {
            const std::size_t half = len / 2;
            base = base[half - 1] <= at ? base + half : base;
            len -= half;
        }
        return std::size_t(base - ends_.data()) + (*base <= at ? 1 : 0);
    }

    uint32_t allocate() {
        if (!free_.empty()) {
            const uint32_t b = free_.back();
            free_.pop_back();
            return b;
        }
        bodies_.emplace_back();
        return uint32_t(bodies_.size() - 1);
    }
    uint32_t copy_of(uint32_t source) {
        const uint32_t b = allocate();
        bodies_[b] = bodies_[source];
        return b;
    }
    void release(uint32_t b) {
        bodies_[b].clear();  // keeps its heap capacity for the next segment
        free_.push_back(b);
    }

    // entries_[from, to) become `with`.
    void splice(std::size_t from, std::size_t to, const std::vector<Entry>& with) {
        const std::size_t old = to - from;
        if (with.size() > old) {
            entries_.insert(entries_.begin() + std::ptrdiff_t(to), with.size() - old, Entry{});
            ends_.insert(ends_.begin() + std::ptrdiff_t(to), with.size() - old, 0);
        } else if (with.size() < old) {
            entries_.erase(entries_.begin() + std::ptrdiff_t(from + with.size()),
                           entries_.begin() + std::ptrdiff_t(to));
            ends_.erase(ends_.begin() + std::ptrdiff_t(from + with.size()),
                        ends_.begin() + std::ptrdiff_t(to));
        }
        std::copy(with.begin(), with.end(), entries_.begin() + std::ptrdiff_t(from));
        for (std::size_t k = 0; k < with.size(); ++k) ends_[from + k] = with[k].end;
    }

    std::vector<Entry> entries_;  // sorted by begin, disjoint
    std::vector<uint64_t> ends_;  // entries_[i].end, for the search
    std::vector<Body> bodies_;
    std::vector<uint32_t> free_;  // released bodies, cleared
    std::vector<Entry> pieces_;   // update's working list
};

}  // namespace clastrace::replay::detail

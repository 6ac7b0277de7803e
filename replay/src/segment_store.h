// SPDX-License-Identifier: Apache-2.0
// SegmentStore: disjoint address segments [begin, end), each owning a Body, kept as one sorted
// array of small entries plus a pool of bodies. It replaces a std::map keyed by begin: the
// search runs over a few KB of contiguous keys instead of large tree nodes, splits and merges
// cost one move of trivially copyable entries, and freed bodies go back to the pool with their
// heap capacity (a body's read list) kept for the next segment.
//
// The search for an address runs over a separate array of the segments' ends (8 bytes a
// segment), branch-free: a command's accesses jump between its arrays, so neither a cached
// "last segment" nor the search's branches predict well. A command's disjoint accesses sorted by
// address go through in one walk (begin_sorted): each search starts where the last range ended,
// and the entries are rewritten by one splice for them all.
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

    std::size_t size() const {
        if (batch_from_ == kNoBatch) return entries_.size();
        return batch_from_ + out_.size() + (have_pending_ ? 1 : 0) + (entries_.size() - next_);
    }

    // Visits [begin, end) in address order: segments straddling either end are split first
    // (one piece keeps the body, the other gets a copy of it), gaps become new
    // segments handed to fresh(Body&, begin, end), and existing ones go to
    // touch(Body&, begin, end). With `merge`, the segments inside [begin, end) then become one,
    // keeping the first one's body (the caller made them all equal).
    template <class Fresh, class Touch>
    void update(uint64_t begin, uint64_t end, bool merge, Fresh&& fresh, Touch&& touch) {
        update_in_batch(begin, end, merge, fresh, touch);
        if (!batching_) finish_batch();
    }

    // Between begin_sorted() and end_sorted(), update() takes ranges in ascending order, each
    // beginning at or after the end of the one before (a command's disjoint accesses sorted by
    // address): the store is then walked once, forward from the first range, and rewritten
    // with one splice at end_sorted(), instead of a search and a splice per range. Nothing but
    // update() and size() may be called in between.
    void begin_sorted() {
        CLASTRACE_DEBUG_ASSERT(!batching_);
        batching_ = true;
        last_end_ = 0;
    }
    void end_sorted() {
        CLASTRACE_DEBUG_ASSERT(batching_);
        batching_ = false;
        finish_batch();
    }

    // Makes `at` a segment boundary if a segment straddles it.
    void split_at(uint64_t at) {
        CLASTRACE_DEBUG_ASSERT(batch_from_ == kNoBatch);
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
        CLASTRACE_DEBUG_ASSERT(batch_from_ == kNoBatch);
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
        std::size_t bytes = entries_.capacity() * sizeof(Entry) +
                            ends_.capacity() * sizeof(uint64_t) +
                            bodies_.capacity() * sizeof(Body) +
                            free_.capacity() * sizeof(uint32_t) + out_.capacity() * sizeof(Entry);
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

    // update()'s walk. The entries it has passed, rewritten, are in out_ (they replace
    // entries_[batch_from_, next_)); the input still to come is pending_ (a tail split off the
    // last segment touched, when there is one) and then entries_[next_..].
    template <class Fresh, class Touch>
    void update_in_batch(uint64_t begin, uint64_t end, bool merge, Fresh& fresh, Touch& touch) {
        if (end <= begin) return;
        CLASTRACE_DEBUG_ASSERT(!batching_ || begin >= last_end_);
        last_end_ = end;
        if (batch_from_ != kNoBatch) {  // what lies before `begin` passes unchanged
            if (have_pending_ && pending_.end <= begin) {
                out_.push_back(pending_);
                have_pending_ = false;
            }
            if (!have_pending_) {
                // Near the last range (within kCopiedAcross entries), the search needs only
                // that window; otherwise the store changes before the search that counts.
                const std::size_t last = next_ + kCopiedAcross;
                const bool far = last < ends_.size() && ends_[last] <= begin;
                const std::size_t window = std::min(last + 1, ends_.size());
                if (far) {
                    // Far from the last range: a splice here moves less than copying the
                    // entries between, twice.
                    const std::size_t resume = batch_from_ + out_.size();
                    finish_batch();
                    batch_from_ = next_ = first_ending_after(begin, resume);
                    out_.clear();
                } else {
                    const std::size_t first = first_ending_after(begin, next_, window);
                    out_.insert(out_.end(), entries_.begin() + std::ptrdiff_t(next_),
                                entries_.begin() + std::ptrdiff_t(first));
                    next_ = first;
                }
            }
        } else {
            batch_from_ = next_ = first_ending_after(begin, 0);
            out_.clear();
        }
        auto have_input = [&] { return have_pending_ || next_ < entries_.size(); };
        auto peek = [&] { return have_pending_ ? pending_ : entries_[next_]; };
        auto consume = [&] {
            if (have_pending_)
                have_pending_ = false;
            else
                ++next_;
        };
        if (have_input() && peek().begin < begin) {  // straddles `begin`
            const Entry e = peek();
            consume();
            out_.push_back({e.begin, begin, e.body});
            pending_ = {begin, e.end, copy_of(e.body)};
            have_pending_ = true;
        }
        const std::size_t inside_from = out_.size();
        uint64_t cursor = begin;
        while (cursor < end) {
            if (!have_input() || peek().begin > cursor) {
                const uint64_t gap_end = have_input() ? std::min(end, peek().begin) : end;
                const uint32_t b = allocate();
                fresh(bodies_[b], cursor, gap_end);
                out_.push_back({cursor, gap_end, b});
                cursor = gap_end;
                continue;
            }
            Entry seg = peek();
            consume();
            if (seg.end > end) {  // straddles `end`: the tail is input for the next range
                pending_ = {end, seg.end, copy_of(seg.body)};
                have_pending_ = true;
                seg.end = end;
            }
            touch(bodies_[seg.body], seg.begin, seg.end);
            out_.push_back(seg);
            cursor = seg.end;
        }
        if (merge && out_.size() - inside_from > 1) {
            for (std::size_t k = inside_from + 1; k < out_.size(); ++k) release(out_[k].body);
            out_[inside_from].end = end;
            out_.resize(inside_from + 1);
        }
    }

    // The rewritten entries replace those the walk passed.
    void finish_batch() {
        if (batch_from_ == kNoBatch) return;
        if (have_pending_) {
            out_.push_back(pending_);
            have_pending_ = false;
        }
        const std::size_t from = batch_from_;
        splice(from, next_, out_);
        batch_from_ = kNoBatch;
        CLASTRACE_DEBUG_ASSERT(entries_hold(from, from + out_.size()));
    }

    // Index of the first entry in [from, to) whose end lies past `at` (the one holding `at`,
    // or the next); `to` (all entries by default) when there is none.
    std::size_t first_ending_after(uint64_t at, std::size_t from = 0,
                                   std::size_t to = SIZE_MAX) const {
        // Entries are disjoint and sorted, so their ends are sorted too.
        const std::size_t n = std::min(to, ends_.size());
        if (from >= n) return n;
        if (ends_[from] > at) return from;  // a sorted walk's next range is often right there
        const uint64_t* base = ends_.data() + from;
        std::size_t len = n - from;
        while (len > 1) {
            const std::size_t half = len / 2;
            base +=
                half * std::size_t(base[half - 1] <= at);  // arithmetic: GCC made the ?: a branch
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
    // update()'s walk (update_in_batch): see there.
    static constexpr std::size_t kNoBatch = SIZE_MAX;
    static constexpr std::size_t kCopiedAcross = 16;  // untouched entries a walk copies, at most
    std::vector<Entry> out_;
    std::size_t batch_from_ = kNoBatch, next_ = 0;
    Entry pending_{};
    bool have_pending_ = false;
    bool batching_ = false;  // between begin_sorted() and end_sorted()
    uint64_t last_end_ = 0;  // the last range's end (ranges in a batch must not go back)
};

}  // namespace clastrace::replay::detail

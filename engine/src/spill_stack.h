// SPDX-License-Identifier: Apache-2.0
// The stack of a tree walk: N entries in place, deeper (hostile but checked) trees spill into
// a vector. The walk owns the entries and the vector and the stack holds pointers to them, so
// that it is three scalars whose address never leaves the walk and its size stays in a
// register (with the entries inside, the size was stored and loaded at every push and pop).
#pragma once

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <vector>

namespace clastrace::engine {

template <class Entry, uint32_t N>
class SpillStack {
public:
    static constexpr uint32_t kSize = N;
    SpillStack(Entry (&entries)[N], std::vector<Entry>* overflow)
        : stack_(entries), overflow_(overflow) {}
    // Inlined into the walks (an out-of-line push cost 4% of a wide walk's instructions); the
    // spill to the vector stays out of line.
    [[gnu::always_inline]] void push(Entry e) {
        if (__builtin_expect(size_ < N, 1))
            stack_[size_] = e;
        else
            spill(overflow_, e);
        ++size_;
    }
    [[gnu::always_inline]] bool empty() const { return size_ == 0; }
    // The entry pushed last (the stack is not empty). One test of the size on the common path
    // (the vector is looked at only past N). Entries go in and out by value, so that the walk
    // keeps the one it visits in registers.
    [[gnu::always_inline]] Entry pop() {
        --size_;
        if (__builtin_expect(size_ < N, 1)) return stack_[size_];
        return unspill(overflow_);
    }
    // Room for `n` entries on top of the fixed part (nullptr where it has less): the caller
    // writes them there in place and then pushes them with grow(n).
    [[gnu::always_inline]] Entry* room(uint32_t n) {
        return __builtin_expect(size_ + n <= N, 1) ? stack_ + size_ : nullptr;
    }
    [[gnu::always_inline]] void grow(uint32_t n) { size_ += n; }

private:
    [[gnu::noinline]] static void spill(std::vector<Entry>* overflow, Entry e) {
        overflow->push_back(e);
    }
    [[gnu::noinline]] static Entry unspill(std::vector<Entry>* overflow) {
        const Entry e = overflow->back();
        overflow->pop_back();
        return e;
    }
    Entry* stack_;
    uint32_t size_ = 0;
    std::vector<Entry>* overflow_;
};

// The stack of a walk whose pushes come in bursts of at most `Burst` entries (a wide node's
// children): room for a burst is made once, before it (make_room), so that a push is a store
// and a pointer bump and a pop a comparison, a decrement and a load (SpillStack's size checks
// on every push and pop were about 15% of the wide walk's own instructions). Past N entries
// the older half of the fixed part moves to the end of the vector, and comes back when the
// fixed part runs empty, so deep (hostile but checked) trees keep their order.
template <class Entry, uint32_t N, uint32_t Burst>
class BurstStack {
    static_assert(Burst <= N / 2);

public:
    static constexpr uint32_t kSize = N;
    BurstStack(Entry (&entries)[N], std::vector<Entry>* overflow)
        : base_(entries), top_(entries), overflow_(overflow) {}
    // Room for Burst more entries above top().
    [[gnu::always_inline]] void make_room() {
        if (__builtin_expect(top_ + Burst > base_ + N, 0)) spill();
    }
    [[gnu::always_inline]] void push(Entry e) { *top_++ = e; }
    // Where the next push goes: the caller may write up to Burst entries there (after
    // make_room) and then push them with grow(n).
    [[gnu::always_inline]] Entry* top() { return top_; }
    [[gnu::always_inline]] void grow(uint32_t n) { top_ += n; }
    // The entry pushed last into `e`; false when the stack is empty. (An empty vector is
    // seen here: every walk ends on an empty stack, and the call to refill cost 12
    // instructions a walk.)
    [[gnu::always_inline]] bool pop(Entry* e) {
        if (__builtin_expect(top_ == base_, 0) && (overflow_->empty() || !refill())) return false;
        *e = *--top_;
        return true;
    }

private:
    [[gnu::noinline]] void spill() {
        constexpr uint32_t kHalf = N / 2;
        overflow_->insert(overflow_->end(), base_, base_ + kHalf);
        std::memmove(base_, base_ + kHalf, size_t(top_ - base_ - kHalf) * sizeof(Entry));
        top_ -= kHalf;
    }
    [[gnu::noinline]] bool refill() {
        if (overflow_->empty()) return false;
        const size_t n = std::min<size_t>(N / 2, overflow_->size());
        std::memcpy(base_, overflow_->data() + overflow_->size() - n, n * sizeof(Entry));
        overflow_->resize(overflow_->size() - n);
        top_ = base_ + n;
        return true;
    }
    Entry* base_;
    Entry* top_;
    std::vector<Entry>* overflow_;
};

}  // namespace clastrace::engine

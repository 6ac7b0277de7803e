// SPDX-License-Identifier: Apache-2.0
// The stack of a tree walk: N entries in place, deeper (hostile but checked) trees spill into
// a vector. The walk owns the entries and the vector and the stack holds pointers to them, so
// that it is three scalars whose address never leaves the walk and its size stays in a
// register (with the entries inside, the size was stored and loaded at every push and pop).
#pragma once

#include <cstdint>
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

}  // namespace clastrace::engine

// SPDX-License-Identifier: Apache-2.0
// The contents laid into replay memory by their first byte, for the exact lookups every captured
// snapshot makes (ReplayMemory::holds_laid_content, lay_in). ReplayMemory keeps the same ranges
// in an ordered map for the overlap walks a write needs; there a lookup was a tree descent of
// ~80 instructions and a dependent load a level. Here it is one multiply and, mostly, one slot:
// open addressing with linear probing, erased by shifting the entries after back (no tombstones,
// so a long replay's lay-ins and erasures never lengthen the probes).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace clastrace::replay::detail {

class LaidIndex {
    static constexpr uint64_t kEmpty = ~0ull;

public:
    LaidIndex() : slots_(64) {}

    struct Entry {
        uint64_t begin = kEmpty;
        uint64_t end = 0;
        uint64_t hash = 0;
    };

    // The entry laid at `begin`, or null.
    const Entry* find(uint64_t begin) const {
        if (begin == kEmpty) return nullptr;
        for (size_t at = home(begin);; at = (at + 1) & mask_) {
            const Entry& e = slots_[at];
            if (e.begin == begin) return &e;
            if (e.begin == kEmpty) return nullptr;
        }
    }

    // Sets the entry at `begin` (replacing one there).
    void insert(uint64_t begin, uint64_t end, uint64_t hash) {
        if (begin == kEmpty) return;  // (no range begins at the last byte: find answers none)
        if ((size_ + 1) * 4 > slots_.size() * 3) grow();
        size_t at = home(begin);
        while (slots_[at].begin != kEmpty && slots_[at].begin != begin) at = (at + 1) & mask_;
        if (slots_[at].begin == kEmpty) ++size_;
        slots_[at] = Entry{begin, end, hash};
    }

    void erase(uint64_t begin);
    size_t size() const { return size_; }

private:
    // Fibonacci hashing: laid addresses share their low bits (aligned buffers and offsets).
    size_t home(uint64_t begin) const {
        return static_cast<size_t>((begin * 0x9E3779B97F4A7C15ull) >> shift_);
    }
    void grow();

    std::vector<Entry> slots_;
    size_t mask_ = 63;
    unsigned shift_ = 58;  // 64 - log2(slots_.size())
    size_t size_ = 0;
};

}  // namespace clastrace::replay::detail

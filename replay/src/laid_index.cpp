// SPDX-License-Identifier: Apache-2.0
#include "laid_index.h"

#include <utility>

namespace clastrace::replay::detail {

void LaidIndex::erase(uint64_t begin) {
    if (begin == kEmpty) return;
    size_t at = home(begin);
    while (slots_[at].begin != begin) {
        if (slots_[at].begin == kEmpty) return;
        at = (at + 1) & mask_;
    }
    // Moves back each later entry of the run whose home is not between the hole and it, so
    // every entry stays reachable from its home without a gap.
    size_t hole = at;
    for (size_t next = (hole + 1) & mask_; slots_[next].begin != kEmpty;
         next = (next + 1) & mask_) {
        const size_t want = home(slots_[next].begin);
        const bool stays =
            hole <= next ? (hole < want && want <= next) : (hole < want || want <= next);
        if (stays) continue;
        slots_[hole] = slots_[next];
        hole = next;
    }
    slots_[hole] = Entry{};
    --size_;
}

void LaidIndex::grow() {
    std::vector<Entry> old(slots_.size() * 2);
    old.swap(slots_);
    mask_ = slots_.size() - 1;
    --shift_;
    size_ = 0;
    for (const Entry& e : old)
        if (e.begin != kEmpty) insert(e.begin, e.end, e.hash);
}

}  // namespace clastrace::replay::detail

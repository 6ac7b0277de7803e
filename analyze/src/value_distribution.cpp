// SPDX-License-Identifier: Apache-2.0
#include "clastrace/analyze/value_distribution.h"

#include <bit>

namespace clastrace::analyze {

int ValueDistribution::log2_bin(uint64_t value) { return value == 0 ? 0 : std::bit_width(value); }

uint64_t ValueDistribution::fold_key(uint64_t value) {
    // Keep the top 7 significant bits: values below 128 stay exact.
    int width = std::bit_width(value);
    if (width <= 7) return value;
    int drop = width - 7;
    return (value >> drop) << drop;
}

void ValueDistribution::add(uint64_t value, uint64_t times) {
    if (times == 0) return;
    count_ += times;
    uint64_t add = value * times;
    bool overflow = value != 0 && add / value != times;
    sum_ = (overflow || sum_ + add < sum_) ? UINT64_MAX : sum_ + add;
    if (value < min_) min_ = value;
    if (value > max_) max_ = value;
    bins_[log2_bin(value)] += times;
    counts_[folded_ ? fold_key(value) : value] += times;
    if (!folded_ && counts_.size() > kMaxDistinct) fold();
}

void ValueDistribution::fold() {
    std::map<uint64_t, uint64_t> folded;
    for (auto [value, n] : counts_) folded[fold_key(value)] += n;
    counts_.swap(folded);
    folded_ = true;
}

uint64_t ValueDistribution::median() const {
    if (count_ == 0) return 0;
    uint64_t rank = (count_ + 1) / 2, seen = 0;
    for (auto [value, n] : counts_) {
        seen += n;
        if (seen >= rank) return value;
    }
    return max_;
}

}  // namespace clastrace::analyze

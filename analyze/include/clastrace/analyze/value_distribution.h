// SPDX-License-Identifier: Apache-2.0
// Streaming distribution of non-negative integers (object bytes, triangles): count, sum,
// min, max, a median and a fixed log2 histogram, in memory bounded by kMaxDistinct.
//
// Why not a reservoir or a t-digest: both are approximate and (the reservoir) random, so a
// golden test or a CI diff of two runs could not rely on the median. Object sizes take few
// distinct values (the engine and drivers align them), so counting distinct values gives the
// exact median in practice. When more than kMaxDistinct values are seen, values are folded
// into log-linear buckets keeping 7 significant bits (relative error below 1/128) and the
// median is flagged inexact; min, max, count, sum and the log2 histogram stay exact.
#pragma once

#include <array>
#include <cstdint>
#include <map>

namespace clastrace::analyze {

class ValueDistribution {
public:
    static constexpr std::size_t kMaxDistinct = 4096;
    static constexpr int kLog2Bins = 65;  // bin 0: value 0; bin k>0: [2^(k-1), 2^k)

    void add(uint64_t value, uint64_t times = 1);

    uint64_t count() const { return count_; }
    uint64_t sum() const { return sum_; }  // saturates at 2^64-1
    uint64_t min() const { return count_ ? min_ : 0; }
    uint64_t max() const { return max_; }
    // Lower median: the value of rank ceil(count/2), so it is always a value that was seen
    // (or, when inexact, the low end of its bucket). 0 when empty.
    uint64_t median() const;
    bool median_exact() const { return !folded_; }
    const std::array<uint64_t, kLog2Bins>& log2_bins() const { return bins_; }

    static int log2_bin(uint64_t value);
    static uint64_t bin_low(int bin) { return bin == 0 ? 0 : uint64_t{1} << (bin - 1); }

private:
    void fold();
    static uint64_t fold_key(uint64_t value);

    uint64_t count_ = 0, sum_ = 0, min_ = UINT64_MAX, max_ = 0;
    bool folded_ = false;
    std::map<uint64_t, uint64_t> counts_;  // value (or folded bucket low end) -> count
    std::array<uint64_t, kLog2Bins> bins_{};
};

}  // namespace clastrace::analyze

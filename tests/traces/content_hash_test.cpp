// SPDX-License-Identifier: Apache-2.0
// The writer's content hashing (traces/src/content_hash.h): every kernel this CPU runs gives
// XXH3's own values for the pieces' concatenation, however it is cut, at every length class of
// XXH3 (0, 1-3, 4-8, 9-16, 17-128, 129-240, long, across its 1 KiB stripes' blocks).
#include "content_hash.h"

#include <gtest/gtest.h>
#include <xxhash.h>

#include <cstdint>
#include <random>
#include <vector>

namespace clastrace::traces {
namespace {

std::vector<ContentPiece> cut(const std::vector<uint8_t>& bytes, std::mt19937& random) {
    std::vector<ContentPiece> pieces;
    size_t at = 0;
    while (at < bytes.size()) {
        const size_t n = std::min<size_t>(bytes.size() - at,
                                          std::uniform_int_distribution<size_t>(0, 700)(random));
        pieces.push_back({bytes.data() + at, n});  // an empty piece now and then
        at += n;
    }
    return pieces;
}

TEST(ContentHash, EveryKernelGivesXxh3sValuesForTheConcatenation) {
    size_t count = 0;
    const ContentHashKernel* kernels = content_hash_kernels(&count);
    ASSERT_GE(count, 1u);
    EXPECT_STREQ(kernels[0].isa, "baseline");
    std::mt19937 random(7);
    std::vector<uint8_t> all(300000);
    for (uint8_t& b : all) b = uint8_t(random());
    std::vector<size_t> sizes;
    for (size_t n = 0; n <= 300; ++n) sizes.push_back(n);
    for (size_t n : {1023, 1024, 1025, 4096, 65537, 300000}) sizes.push_back(n);
    for (size_t k = 0; k < count; ++k) {
        SCOPED_TRACE(kernels[k].isa);
        for (size_t size : sizes) {
            const std::vector<uint8_t> bytes(all.begin(), all.begin() + size);
            const XXH128_hash_t wide = XXH3_128bits(bytes.data(), size);
            const uint64_t key = XXH3_64bits(bytes.data(), size);
            for (int cuts = 0; cuts < 3; ++cuts) {
                const std::vector<ContentPiece> pieces =
                    cuts == 0 ? std::vector<ContentPiece>{{bytes.data(), size}}
                              : cut(bytes, random);
                const ContentHashes got = kernels[k].hash(pieces.data(), pieces.size());
                ASSERT_EQ(got.fingerprint_low, wide.low64) << "size " << size;
                ASSERT_EQ(got.fingerprint_high, wide.high64) << "size " << size;
                ASSERT_EQ(got.key_seed0, key) << "size " << size;
                ASSERT_EQ(kernels[k].key(pieces.data(), pieces.size(), 5),
                          XXH3_64bits_withSeed(bytes.data(), size, 5))
                    << "size " << size;
            }
        }
    }
    // What the writer calls is one of them.
    const ContentPiece one{all.data(), 5000};
    EXPECT_EQ(hash_content(&one, 1).key_seed0, XXH3_64bits(all.data(), 5000));
    EXPECT_EQ(content_key_of(&one, 1, 9), XXH3_64bits_withSeed(all.data(), 5000, 9));
}

}  // namespace
}  // namespace clastrace::traces

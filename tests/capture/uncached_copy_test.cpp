// SPDX-License-Identifier: Apache-2.0
// copyFromUncached (streaming loads for write-combined memory) gives exactly memcpy's bytes for
// every size and source/destination alignment around its 16-byte and 64-byte steps.
#include <clastrace/capture/uncached_copy.h>
#include <gtest/gtest.h>

#include <vector>

namespace {

TEST(UncachedCopy, EqualsMemcpyAtEverySizeAndAlignment) {
    std::vector<uint8_t> source(5000);
    for (size_t i = 0; i < source.size(); ++i) source[i] = uint8_t(i * 131 + (i >> 8));
    for (size_t sourceOffset = 0; sourceOffset < 17; ++sourceOffset)
        for (size_t destinationOffset : {0, 1, 8, 15})
            for (size_t size : {0, 1, 15, 16, 63, 64, 255, 256, 257, 300, 1023, 1024, 4096, 4900}) {
                std::vector<uint8_t> destination(size + 32, 0xEE);
                clastrace::capture::copy_from_uncached(destination.data() + destinationOffset,
                                                       source.data() + sourceOffset, size);
                for (size_t i = 0; i < destinationOffset; ++i)
                    ASSERT_EQ(destination[i], 0xEE) << "wrote before the start";
                ASSERT_TRUE(std::equal(source.begin() + sourceOffset,
                                       source.begin() + sourceOffset + size,
                                       destination.begin() + destinationOffset))
                    << "size " << size << " source offset " << sourceOffset
                    << " destination offset " << destinationOffset;
                for (size_t i = destinationOffset + size; i < destination.size(); ++i)
                    ASSERT_EQ(destination[i], 0xEE) << "wrote past the end";
            }
}

}  // namespace

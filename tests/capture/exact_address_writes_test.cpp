// SPDX-License-Identifier: Apache-2.0
// CLASTRACE_DEVICE_ADDRESS_WRITES=exact, without a GPU: what the pause worker keeps of a
// dispatch's writes from the copies before and after it. Exact to the byte; bytes rewritten with
// the value they had are not seen (the documented limit); buffers that were not there before,
// or moved, are not compared.
#include "clastrace/capture/exact_address_writes.h"

#include <gtest/gtest.h>

#include <vector>

namespace {

using namespace clastrace::capture;

ServedBuffer host_buffer(uint64_t handle, VkDeviceAddress address, std::vector<uint8_t>& bytes) {
    ServedBuffer b;
    b.buffer = handle;
    b.address = address;
    b.size = bytes.size();
    b.host = bytes.data();
    return b;
}

TEST(ExactAddressWrites, ChangedRunsAreExactToTheByte) {
    std::vector<uint8_t> then(64, 0), now(64, 0);
    now[3] = 1;                                   // one byte inside the first word
    now[8] = now[9] = now[10] = 7;                // a run of three
    now[12] = 7;                                  // an unchanged byte apart: a run of its own
    for (int i = 30; i < 50; ++i) now[i] = 0xAB;  // a run across words
    const auto runs = changed_runs(then, now);
    const std::vector<std::pair<uint64_t, uint64_t>> expected{{3, 4}, {8, 11}, {12, 13}, {30, 50}};
    EXPECT_EQ(runs, expected);
    EXPECT_TRUE(changed_runs(then, then).empty());
}

TEST(ExactAddressWrites, ABytesUnchangedWriteIsNotSeen) {
    std::vector<uint8_t> then(16, 5), now(16, 5);
    now[4] = 5;  // "written" with the value it had: nothing to compare
    EXPECT_TRUE(changed_runs(then, now).empty());
}

TEST(ExactAddressWrites, TheChangedRangesOfEachBufferWithTheirNewBytes) {
    std::vector<uint8_t> infos(256, 0xEE), other(64, 0);
    const ExactAddressWrites::Key key{7, 42, 0};
    ExactAddressWrites exact;
    const std::vector<ServedBuffer> buffers{host_buffer(0xb1, 0x10000, infos),
                                            host_buffer(0xb2, 0x20000, other)};
    exact.before(key, buffers);
    for (int i = 16; i < 48; ++i) infos[i] = uint8_t(i);  // the dispatch writes 32 bytes
    other[0] = 1;
    const AddressWriteComparison c = exact.after(key, buffers);
    EXPECT_EQ(c.compared_bytes, 256u + 64u);
    ASSERT_EQ(c.changed.size(), 2u);
    EXPECT_EQ(c.changed[0].address, 0x10000u + 16);
    EXPECT_EQ(c.changed[0].buffer, 0xb1u);
    EXPECT_EQ(c.changed[0].buffer_offset, 16u);
    ASSERT_EQ(c.changed[0].bytes.size(), 32u);
    EXPECT_EQ(c.changed[0].bytes.data()[0], 16);
    EXPECT_EQ(c.changed[0].bytes.data()[31], 47);
    EXPECT_EQ(c.changed[1].address, 0x20000u);
    EXPECT_EQ(c.changed[1].bytes.size(), 1u);
    // The copies are forgotten: a second comparison under the key sees nothing.
    EXPECT_TRUE(exact.after(key, buffers).changed.empty());
}

TEST(ExactAddressWrites, ABufferNotCopiedBeforeIsNotCompared) {
    std::vector<uint8_t> first(32, 0), created(32, 0);
    const ExactAddressWrites::Key key{1, 1, 0};
    ExactAddressWrites exact;
    exact.before(key, std::vector<ServedBuffer>{host_buffer(0xb1, 0x1000, first)});
    created[0] = 9;
    const AddressWriteComparison c =
        exact.after(key, std::vector<ServedBuffer>{host_buffer(0xb1, 0x1000, first),
                                                   host_buffer(0xb9, 0x9000, created)});
    EXPECT_TRUE(c.changed.empty());
    EXPECT_EQ(c.compared_bytes, 32u);
}

TEST(ExactAddressWrites, ExecutionsAreKeptApart) {
    std::vector<uint8_t> bytes(16, 0);
    ExactAddressWrites exact;
    const std::vector<ServedBuffer> buffers{host_buffer(0xb1, 0x1000, bytes)};
    exact.before({1, 5, 0}, buffers);
    bytes[0] = 1;
    exact.before({1, 5, 1}, buffers);  // the second execution starts from what the first wrote
    bytes[1] = 2;
    EXPECT_EQ(exact.after({1, 5, 1}, buffers).changed.size(), 1u);
    EXPECT_EQ(exact.after({1, 5, 0}, buffers).changed.size(), 1u);  // bytes 0..1, one run
}

}  // namespace

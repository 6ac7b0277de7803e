// SPDX-License-Identifier: Apache-2.0
#include "clastrace/capture/device_memory_map.h"

#include <gtest/gtest.h>

using namespace clastrace::capture;

namespace {

struct MapWithOneBuffer : ::testing::Test {
    std::vector<uint8_t> hostMemory = std::vector<uint8_t>(4096);
    DeviceMemoryMap map;
    void SetUp() override {
        for (size_t i = 0; i < hostMemory.size(); ++i) hostMemory[i] = uint8_t(i * 7);
        map.add_memory({0x10, 4096, 1,
                        VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT,
                        hostMemory.data()});
        map.add_buffer({0x20, 1024, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, 0, 0, 0, 0});
        map.bind_buffer(0x20, 0x10, 512);
        map.set_buffer_address(0x20, 0x100000);
    }
};

}  // namespace

TEST_F(MapWithOneBuffer, ResolvesAddressToBufferOffsetAndHostBytes) {
    std::string why;
    auto r = map.resolve(0x100010, 16, why);
    ASSERT_TRUE(r) << why;
    EXPECT_EQ(r->buffer.handle, 0x20u);
    EXPECT_EQ(r->offset_in_buffer, 0x10u);
    EXPECT_EQ(r->memory.handle, 0x10u);
    EXPECT_EQ(r->host, hostMemory.data() + 512 + 16);
    std::vector<uint8_t> bytes;
    ASSERT_TRUE(map.read(0x100010, 4, bytes, why));
    EXPECT_EQ(bytes, (std::vector<uint8_t>{uint8_t(528 * 7), uint8_t(529 * 7), uint8_t(530 * 7),
                                           uint8_t(531 * 7)}));
}

TEST_F(MapWithOneBuffer, RangeEndingAtBufferEndIsInsideOnePastIsNot) {
    std::string why;
    EXPECT_TRUE(map.resolve(0x100000 + 1020, 4, why));
    EXPECT_FALSE(map.resolve(0x100000 + 1020, 5, why));
    EXPECT_NE(why.find("runs past the end"), std::string::npos) << why;
}

TEST_F(MapWithOneBuffer, UnknownAndWrappingAddressesNameTheAddress) {
    std::string why;
    EXPECT_FALSE(map.resolve(0xFFFFF, 1, why));
    EXPECT_NE(why.find("0xfffff"), std::string::npos) << why;
    EXPECT_FALSE(map.resolve(UINT64_MAX - 2, 8, why));
    EXPECT_NE(why.find("wraps"), std::string::npos) << why;
}

TEST_F(MapWithOneBuffer, DestroyedBufferAndFreedMemoryStopResolving) {
    std::string why;
    map.remove_memory(0x10);
    EXPECT_FALSE(map.resolve(0x100000, 4, why));
    map.add_memory({0x10, 4096, 1, VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT, hostMemory.data()});
    EXPECT_TRUE(map.resolve(0x100000, 4, why));
    map.remove_buffer(0x20);
    EXPECT_FALSE(map.resolve(0x100000, 4, why));
}

TEST_F(MapWithOneBuffer, AliasingBuffersAnyHoldingTheWholeRangeAnswers) {
    // A small buffer aliasing the start of the big one: a range beyond it still resolves.
    map.add_buffer({0x21, 64, 0, 0, 0, 0, 0});
    map.bind_buffer(0x21, 0x10, 512);
    map.set_buffer_address(0x21, 0x100000);
    std::string why;
    auto r = map.resolve(0x100000, 512, why);
    ASSERT_TRUE(r) << why;
    EXPECT_EQ(r->buffer.handle, 0x20u);
    auto small = map.resolve(0x100000 + 8, 8, why);
    ASSERT_TRUE(small);
    EXPECT_EQ(small->host, hostMemory.data() + 520);
}

TEST_F(MapWithOneBuffer, NonHostVisibleMemoryIsReportedNotRead) {
    map.add_memory({0x11, 4096, 0, VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT, nullptr});
    map.add_buffer({0x22, 256, 0, 0, 0, 0, 0});
    map.bind_buffer(0x22, 0x11, 0);
    map.set_buffer_address(0x22, 0x200000);
    std::string why;
    std::vector<uint8_t> bytes;
    EXPECT_FALSE(map.read(0x200000, 4, bytes, why));
    EXPECT_NE(why.find("not host visible"), std::string::npos) << why;
}

// A sparse buffer of two 1 KiB pages over the fixture's memory: page 0 bound at memory offset
// 2048, page 1 at 1024 (out of order), so the buffer's addresses map piecewise to the memory.
struct MapWithSparseBuffer : MapWithOneBuffer {
    void SetUp() override {
        MapWithOneBuffer::SetUp();
        map.add_buffer({0x30, 2048, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
                        VK_BUFFER_CREATE_SPARSE_BINDING_BIT, 0, 0, 0});
        map.set_buffer_address(0x30, 0x200000);
    }
};

TEST_F(MapWithSparseBuffer, AddressesResolveToTheMemoryBoundUnderEachPage) {
    std::string why;
    EXPECT_FALSE(map.resolve(0x200000, 16, why));  // nothing bound yet
    EXPECT_NE(why.find("sparse buffer 0x30"), std::string::npos) << why;
    map.bind_sparse(0x30, 0, 1024, 0x10, 2048);
    map.bind_sparse(0x30, 1024, 1024, 0x10, 1024);
    auto first = map.resolve(0x200010, 16, why);
    ASSERT_TRUE(first) << why;
    EXPECT_EQ(first->host, hostMemory.data() + 2048 + 16);
    auto second = map.resolve(0x200400 + 8, 16, why);
    ASSERT_TRUE(second) << why;
    EXPECT_EQ(second->host, hostMemory.data() + 1024 + 8);
    EXPECT_EQ(second->buffer.memory_offset + second->offset_in_buffer, 1024u + 8);
    // Across the page boundary the memory is not contiguous: refused, with the reason.
    EXPECT_FALSE(map.resolve(0x200400 - 8, 16, why));
    EXPECT_NE(why.find("not bound contiguously"), std::string::npos) << why;
}

TEST_F(MapWithSparseBuffer, RebindReplacesAndUnbindRemovesThePages) {
    std::string why;
    map.bind_sparse(0x30, 0, 2048, 0x10, 0);  // contiguous: one read across both pages
    ASSERT_TRUE(map.resolve(0x200400 - 8, 16, why)) << why;
    map.bind_sparse(0x30, 1024, 1024, 0x10, 3072);  // a rebind of page 1 elsewhere
    auto rebound = map.resolve(0x200400, 4, why);
    ASSERT_TRUE(rebound) << why;
    EXPECT_EQ(rebound->host, hostMemory.data() + 3072);
    EXPECT_TRUE(map.resolve(0x200000, 1024, why));  // page 0 kept its memory
    map.bind_sparse(0x30, 0, 1024, 0, 0);           // unbind page 0
    EXPECT_FALSE(map.resolve(0x200000, 4, why));
    EXPECT_TRUE(map.resolve_buffer(0x30, 1024, 16, why)) << why;
    EXPECT_FALSE(map.resolve_buffer(0x30, 0, 16, why));
}

// A served build touches what host_addressed_buffers() lists: a sparse buffer is listed as the
// runs of its bound pages, each at its own addresses over the memory bound there, so the engine's
// outputs reach that memory; pages bound one after another in one allocation are one run.
TEST_F(MapWithSparseBuffer, ServedBuffersAreTheBoundRunsOfASparseBuffer) {
    auto sparseEntries = [&] {
        std::vector<ResolvedRange> runs;
        for (const ResolvedRange& r : map.host_addressed_buffers())
            if (r.buffer.handle == 0x30) runs.push_back(r);
        return runs;
    };
    EXPECT_TRUE(sparseEntries().empty());  // nothing bound
    map.bind_sparse(0x30, 0, 1024, 0x10, 1024);
    map.bind_sparse(0x30, 1024, 1024, 0x10, 2048);  // follows page 0 in the memory: one run
    auto whole = sparseEntries();
    ASSERT_EQ(whole.size(), 1u);
    EXPECT_EQ(whole[0].buffer.address, 0x200000u);
    EXPECT_EQ(whole[0].buffer.size, 2048u);
    EXPECT_EQ(whole[0].host, hostMemory.data() + 1024);
    EXPECT_EQ(whole[0].memory.handle, 0x10u);

    map.bind_sparse(0x30, 0, 1024, 0x10, 3072);  // page 0 moves: two runs, in buffer order
    map.bind_sparse(0x30, 1024, 512, 0, 0);      // and the first half of page 1 is unbound
    auto runs = sparseEntries();
    ASSERT_EQ(runs.size(), 2u);
    EXPECT_EQ(runs[0].buffer.address, 0x200000u);
    EXPECT_EQ(runs[0].buffer.size, 1024u);
    EXPECT_EQ(runs[0].host, hostMemory.data() + 3072);
    EXPECT_EQ(runs[1].buffer.address, 0x200000u + 1536);
    EXPECT_EQ(runs[1].buffer.size, 512u);
    EXPECT_EQ(runs[1].host, hostMemory.data() + 2048 + 512);
}

// What freeing a memory takes away (pre-range state drops the cluster objects there): the
// addresses of each buffer bound to it, and of each sparse page bound to it, nothing else.
TEST_F(MapWithSparseBuffer, AddressRangesInAMemoryAreItsBuffersAndSparsePages) {
    using Ranges = std::vector<std::pair<VkDeviceAddress, VkDeviceAddress>>;
    EXPECT_EQ(map.address_ranges_in(0x10), (Ranges{{0x100000, 0x100400}}));
    map.add_memory({0x11, 4096, 1, 0, nullptr});
    map.bind_sparse(0x30, 0, 1024, 0x11, 0);
    map.bind_sparse(0x30, 1024, 1024, 0x10, 2048);
    EXPECT_EQ(map.address_ranges_in(0x10), (Ranges{{0x100000, 0x100400}, {0x200400, 0x200800}}));
    EXPECT_EQ(map.address_ranges_in(0x11), (Ranges{{0x200000, 0x200400}}));
    EXPECT_TRUE(map.address_ranges_in(0x12).empty());
}

// resolve() remembers the buffer it last landed in (walks resolve runs of addresses inside one
// buffer); what it answers must stay the walk's answer: a buffer that starts later but still at
// or below the address is taken first, and a buffer destroyed and replaced at the same address
// (other memory) is the new one.
TEST_F(MapWithOneBuffer, TheLastBufferResolvedNeverHidesANewerAnswer) {
    std::string why;
    ASSERT_TRUE(map.resolve(0x100010, 4, why)) << why;
    map.add_buffer({0x21, 256, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, 0, 0, 0, 0});
    map.bind_buffer(0x21, 0x10, 2048);
    map.set_buffer_address(0x21, 0x100080);  // inside 0x20's range, starting after it
    auto r = map.resolve(0x100090, 4, why);
    ASSERT_TRUE(r) << why;
    EXPECT_EQ(r->buffer.handle, 0x21u);
    EXPECT_EQ(r->host, hostMemory.data() + 2048 + 0x10);
    r = map.resolve(0x100010, 4, why);  // below 0x21: still 0x20
    ASSERT_TRUE(r) << why;
    EXPECT_EQ(r->buffer.handle, 0x20u);
    map.remove_buffer(0x20);
    map.add_buffer({0x22, 1024, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, 0, 0, 0, 0});
    map.bind_buffer(0x22, 0x10, 0);
    map.set_buffer_address(0x22, 0x100000);
    r = map.resolve(0x100010, 4, why);
    ASSERT_TRUE(r) << why;
    EXPECT_EQ(r->buffer.handle, 0x22u);
    EXPECT_EQ(r->host, hostMemory.data() + 0x10);
    map.remove_buffer(0x22);
    EXPECT_FALSE(map.resolve(0x100010, 4, why));
}

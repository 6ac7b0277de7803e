// SPDX-License-Identifier: Apache-2.0
// The KHR build input walker without a GPU (lavapipe 25 has no indirect builds): the ranges an
// indirect build read turned into build ranges, and the memory each geometry then reads.
#include "clastrace/capture/khr_input_walker.h"

#include <gtest/gtest.h>

#include <cstring>

using namespace clastrace::capture;

namespace {

// Device memory at kBase..kBase+size, readable by address.
struct KhrWalkerMemory : ::testing::Test {
    static constexpr VkDeviceAddress kBase = 0x10000;
    std::vector<uint8_t> bytes = std::vector<uint8_t>(8192);
    std::vector<std::pair<VkDeviceAddress, uint64_t>> reads;  // every read, in order
    void SetUp() override {
        for (size_t i = 0; i < bytes.size(); ++i) bytes[i] = uint8_t(i * 7);
    }
    DeviceMemoryReader reader() {
        return
            [this](VkDeviceAddress address, uint64_t size, CapturedBytes* out, std::string& why) {
                if (address < kBase || address + size > kBase + bytes.size()) {
                    why = "outside memory";
                    return false;
                }
                reads.emplace_back(address, size);
                if (out) out->assign(&bytes[address - kBase], &bytes[address - kBase] + size);
                return true;
            };
    }
    BufferMemoryReader no_buffers() {
        return [](uint64_t, VkDeviceSize, uint64_t, CapturedBytes*, std::string& why) {
            why = "no buffers";
            return false;
        };
    }
    template <class T>
    void put(VkDeviceAddress address, const T& value) {
        std::memcpy(&bytes[address - kBase], &value, sizeof value);
    }
    const CapturedRange* find(const ClusterMemoryWalk& walk, MemoryRole role,
                              VkDeviceAddress address) {
        for (const CapturedRange& r : walk.ranges)
            if (r.role == role && r.address == address) return &r;
        return nullptr;
    }
};

VkAccelerationStructureGeometryKHR indexed_triangles(VkDeviceAddress vertices,
                                                     VkDeviceAddress indices) {
    VkAccelerationStructureGeometryKHR g{};
    g.geometryType = VK_GEOMETRY_TYPE_TRIANGLES_KHR;
    auto& t = g.geometry.triangles;
    t.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    t.vertexData.deviceAddress = vertices;
    t.vertexStride = 16;
    t.maxVertex = 5;
    t.indexType = VK_INDEX_TYPE_UINT16;
    t.indexData.deviceAddress = indices;
    return g;
}

}  // namespace

TEST(KhrIndirectRanges, TightlyPackedAndStridedRangesComeBackAsWritten) {
    const VkAccelerationStructureBuildRangeInfoKHR written[2] = {{3, 16, 2, 48}, {7, 0, 1, 0}};
    std::vector<uint8_t> packed(32);
    std::memcpy(packed.data(), written, 32);
    std::vector<VkAccelerationStructureBuildRangeInfoKHR> ranges;
    std::string why;
    ASSERT_TRUE(khr_ranges_from_indirect_bytes(packed.data(), packed.size(), 2, 0, ranges, why));
    ASSERT_EQ(ranges.size(), 2u);
    EXPECT_EQ(ranges[0].primitiveCount, 3u);
    EXPECT_EQ(ranges[0].primitiveOffset, 16u);
    EXPECT_EQ(ranges[0].firstVertex, 2u);
    EXPECT_EQ(ranges[0].transformOffset, 48u);
    EXPECT_EQ(ranges[1].primitiveCount, 7u);

    std::vector<uint8_t> strided(48, 0xee);  // stride 32: geometry 1 at byte 32
    std::memcpy(strided.data(), &written[0], 16);
    std::memcpy(strided.data() + 32, &written[1], 16);
    ASSERT_TRUE(khr_ranges_from_indirect_bytes(strided.data(), strided.size(), 2, 32, ranges, why));
    EXPECT_EQ(ranges[1].primitiveCount, 7u);
    EXPECT_EQ(ranges[1].firstVertex, 1u);
}

TEST(KhrIndirectRanges, TooFewBytesAreRefusedWithTheReason) {
    std::vector<uint8_t> bytes(40);
    std::vector<VkAccelerationStructureBuildRangeInfoKHR> ranges;
    std::string why;
    EXPECT_FALSE(khr_ranges_from_indirect_bytes(bytes.data(), bytes.size(), 2, 32, ranges, why));
    EXPECT_EQ(why, "2 build ranges at stride 32 need 48 bytes; 40 were read");
}

// The build reads the ranges at execution, then the indices and vertices those ranges name.
TEST_F(KhrWalkerMemory, IndirectBuildReadsItsRangesThenTheGeometryTheyName) {
    const VkDeviceAddress ranges_at = kBase + 4096, vertices = kBase + 256, indices = kBase + 1024;
    put(ranges_at, VkAccelerationStructureBuildRangeInfoKHR{2, 8, 1, 0});
    BuildAccelerationStructuresKHRCommand c;
    c.indirect = true;
    KhrBuildInfo info;
    info.info.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR;
    info.geometries.push_back(indexed_triangles(vertices, indices));
    info.indirect_address = ranges_at;
    info.indirect_stride = 16;
    info.max_primitive_counts = {100};
    c.infos.push_back(info);
    std::vector<std::vector<VkAccelerationStructureBuildRangeInfoKHR>> read_ranges;
    ClusterMemoryWalk walk =
        walk_build_acceleration_structures_khr_inputs(c, reader(), no_buffers(), read_ranges);
    EXPECT_TRUE(walk.issues.empty());
    ASSERT_EQ(read_ranges.size(), 1u);
    ASSERT_EQ(read_ranges[0].size(), 1u);
    EXPECT_EQ(read_ranges[0][0].primitiveCount, 2u);
    ASSERT_NE(find(walk, MemoryRole::kBuildRanges, ranges_at), nullptr);
    // 2 triangles of 16-bit indices at indexData + primitiveOffset (8): 12 bytes, not the 100
    // of maxPrimitiveCounts.
    const CapturedRange* index_range = find(walk, MemoryRole::kIndexBuffer, indices + 8);
    ASSERT_NE(index_range, nullptr);
    EXPECT_EQ(index_range->bytes.size(), 12u);
    // Vertices firstVertex (1) .. firstVertex + maxVertex (5), 16 bytes apart, 12 each.
    const CapturedRange* vertex_range = find(walk, MemoryRole::kVertexBuffer, vertices + 16);
    ASSERT_NE(vertex_range, nullptr);
    EXPECT_EQ(vertex_range->bytes.size(), 5u * 16 + 12);
    EXPECT_EQ(std::vector<uint8_t>(vertex_range->bytes.data(), vertex_range->bytes.data() + 4),
              std::vector<uint8_t>(&bytes[256 + 16], &bytes[256 + 20]));
}

// Ranges that cannot be read: the build's geometry is not walked, and the issue names why.
TEST_F(KhrWalkerMemory, UnreadableIndirectRangesAreAnIssue) {
    BuildAccelerationStructuresKHRCommand c;
    c.indirect = true;
    KhrBuildInfo info;
    info.geometries.push_back(indexed_triangles(kBase, kBase + 512));
    info.indirect_address = 0x999999999;
    c.infos.push_back(info);
    std::vector<std::vector<VkAccelerationStructureBuildRangeInfoKHR>> read_ranges;
    ClusterMemoryWalk walk =
        walk_build_acceleration_structures_khr_inputs(c, reader(), no_buffers(), read_ranges);
    EXPECT_TRUE(walk.ranges.empty());
    ASSERT_EQ(walk.issues.size(), 1u);
    EXPECT_NE(walk.issues[0].rule.find("outside memory"), std::string::npos);
}

// An array of pointers: the pointer array, then each instance it points at.
TEST_F(KhrWalkerMemory, ArrayOfPointersCapturesThePointersAndEachInstance) {
    const VkDeviceAddress pointers = kBase + 2048;
    const VkDeviceAddress first = kBase + 3000, second = kBase + 128;
    put(pointers, first);
    put(pointers + 8, second);
    BuildAccelerationStructuresKHRCommand c;
    KhrBuildInfo info;
    info.info.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR;
    VkAccelerationStructureGeometryKHR g{};
    g.geometryType = VK_GEOMETRY_TYPE_INSTANCES_KHR;
    g.geometry.instances.arrayOfPointers = VK_TRUE;
    g.geometry.instances.data.deviceAddress = pointers;
    info.geometries.push_back(g);
    info.ranges.push_back({2, 0, 0, 0});
    c.infos.push_back(info);
    std::vector<std::vector<VkAccelerationStructureBuildRangeInfoKHR>> unused;
    ClusterMemoryWalk walk =
        walk_build_acceleration_structures_khr_inputs(c, reader(), no_buffers(), unused);
    EXPECT_TRUE(walk.issues.empty());
    const CapturedRange* array = find(walk, MemoryRole::kInstancePointers, pointers);
    ASSERT_NE(array, nullptr);
    EXPECT_EQ(array->bytes.size(), 16u);
    for (VkDeviceAddress instance : {first, second}) {
        const CapturedRange* r = find(walk, MemoryRole::kInstances, instance);
        ASSERT_NE(r, nullptr) << instance;
        EXPECT_EQ(r->bytes.size(), kKhrInstanceBytes);
    }
}

// Optional vertex formats a driver may report the acceleration-structure vertex feature for are
// captured by their size (here 8-byte R16G16B16A16_UNORM), as the engine decodes them.
TEST_F(KhrWalkerMemory, OptionalVertexFormatsAreCapturedByTheirSize) {
    const VkDeviceAddress vertices = kBase + 256, indices = kBase + 1024;
    BuildAccelerationStructuresKHRCommand c;
    KhrBuildInfo info;
    info.info.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR;
    info.geometries.push_back(indexed_triangles(vertices, indices));
    info.geometries[0].geometry.triangles.vertexFormat = VK_FORMAT_R16G16B16A16_UNORM;
    info.ranges = {VkAccelerationStructureBuildRangeInfoKHR{2, 0, 0, 0}};
    c.infos.push_back(info);
    std::vector<std::vector<VkAccelerationStructureBuildRangeInfoKHR>> read_ranges;
    ClusterMemoryWalk walk =
        walk_build_acceleration_structures_khr_inputs(c, reader(), no_buffers(), read_ranges);
    EXPECT_TRUE(walk.issues.empty()) << walk.issues[0].rule;
    const CapturedRange* vertex_range = find(walk, MemoryRole::kVertexBuffer, vertices);
    ASSERT_NE(vertex_range, nullptr);
    EXPECT_EQ(vertex_range->bytes.size(), 5u * 16 + 8);  // vertices 0..maxVertex (5)
}

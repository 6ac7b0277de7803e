// SPDX-License-Identifier: Apache-2.0
#include "clastrace/capture/acceleration_structure_walker.h"
#include "clastrace/capture/device_memory_map.h"

#include <gtest/gtest.h>

#include <cstring>

using namespace clastrace::capture;

namespace {

// Two buffers in one host-visible allocation, read through the same map the layer uses.
struct TwoBuffers : ::testing::Test {
    std::vector<uint8_t> host = std::vector<uint8_t>(8192);
    DeviceMemoryMap map;
    static constexpr uint64_t kGeometry = 0x21, kInstances = 0x22;
    void SetUp() override {
        for (size_t i = 0; i < host.size(); ++i) host[i] = uint8_t(i);
        map.add_memory({0x10, 8192, 0, VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT, host.data()});
        map.add_buffer({kGeometry, 4096, 0, 0, 0, 0, 0});
        map.bind_buffer(kGeometry, 0x10, 0);
        map.add_buffer({kInstances, 1024, 0, 0, 0, 0, 0});
        map.bind_buffer(kInstances, 0x10, 4096);
    }
    BufferMemoryReader reader() {
        return [this](uint64_t buffer, VkDeviceSize offset, uint64_t size, CapturedBytes* out,
                      std::string& why) {
            auto r = map.resolve_buffer(buffer, offset, size, why);
            if (!r) return false;
            if (out) out->assign(r->host, r->host + size);
            return true;
        };
    }
};

VkGeometryNV triangles(uint64_t buffer) {
    VkGeometryNV g{};
    g.geometryType = VK_GEOMETRY_TYPE_TRIANGLES_NV;
    auto& t = g.geometry.triangles;
    t.vertexData = (VkBuffer)buffer;
    t.vertexOffset = 100;
    t.vertexCount = 3;
    t.vertexStride = 16;
    t.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    t.indexData = (VkBuffer)buffer;
    t.indexOffset = 1000;
    t.indexCount = 6;
    t.indexType = VK_INDEX_TYPE_UINT16;
    t.transformData = (VkBuffer)buffer;
    t.transformOffset = 2000;
    return g;
}

}  // namespace

TEST_F(TwoBuffers, NVBuildCapturesVerticesIndicesTransformsAndInstances) {
    BuildAccelerationStructureNVCommand c;
    c.type =
        VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV;  // instances and geometry together only for the test
    c.geometries = {triangles(kGeometry)};
    VkGeometryNV boxes{};
    boxes.geometryType = VK_GEOMETRY_TYPE_AABBS_NV;
    boxes.geometry.aabbs.aabbData = (VkBuffer)kGeometry;
    boxes.geometry.aabbs.numAABBs = 2;
    boxes.geometry.aabbs.stride = 32;
    boxes.geometry.aabbs.offset = 3000;
    c.geometries.push_back(boxes);
    c.instance_data = kInstances;
    c.instance_offset = 64;
    c.instance_count = 2;
    ClusterMemoryWalk walk = walk_build_acceleration_structure_nv_inputs(c, reader());
    ASSERT_TRUE(walk.issues.empty()) << walk.issues[0].rule;
    ASSERT_EQ(walk.ranges.size(), 5u);
    EXPECT_EQ(walk.ranges[0].role, MemoryRole::kVertexBuffer);
    EXPECT_EQ(walk.ranges[0].buffer_offset, 100u);
    EXPECT_EQ(walk.ranges[0].bytes.size(), 2u * 16 + 12);
    EXPECT_EQ(walk.ranges[0].bytes[0], 100);
    EXPECT_EQ(walk.ranges[1].role, MemoryRole::kIndexBuffer);
    EXPECT_EQ(walk.ranges[1].bytes.size(), 12u);
    EXPECT_EQ(walk.ranges[2].role, MemoryRole::kTransformData);
    EXPECT_EQ(walk.ranges[2].bytes.size(), 48u);
    EXPECT_EQ(walk.ranges[3].role, MemoryRole::kAabbs);
    EXPECT_EQ(walk.ranges[3].bytes.size(), 32u + 24);
    EXPECT_EQ(walk.ranges[4].role, MemoryRole::kInstances);
    EXPECT_EQ(walk.ranges[4].buffer, kInstances);
    EXPECT_EQ(walk.ranges[4].bytes.size(), 128u);
    EXPECT_EQ(walk.ranges[4].bytes[0], uint8_t(4096 + 64));
}

TEST_F(TwoBuffers, NVBuildRangesPastTheBufferAreIssues) {
    BuildAccelerationStructureNVCommand c;
    c.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
    VkGeometryNV g = triangles(kGeometry);
    g.geometry.triangles.vertexCount = 1000000;  // runs past the 4 KiB buffer
    g.geometry.triangles.indexType = VK_INDEX_TYPE_NONE_NV;
    g.geometry.triangles.transformData = VK_NULL_HANDLE;
    c.geometries = {g};
    ClusterMemoryWalk walk = walk_build_acceleration_structure_nv_inputs(c, reader());
    ASSERT_EQ(walk.issues.size(), 1u);
    EXPECT_NE(walk.issues[0].rule.find("runs past the end of buffer 0x21"), std::string::npos)
        << walk.issues[0].rule;
    EXPECT_TRUE(walk.ranges.empty());
}

TEST(AccelerationStructureWalker, CopyMemoryReadsTheSizeTheHeaderStates) {
    std::vector<uint8_t> serialized(512, 0xAB);
    const uint64_t total = 300;
    std::memcpy(serialized.data() + 2 * VK_UUID_SIZE, &total, 8);
    DeviceMemoryReader read = [&](VkDeviceAddress a, uint64_t size, CapturedBytes* out,
                                  std::string& why) {
        if (a != 0x1000 || size > serialized.size()) {
            why = "outside";
            return false;
        }
        if (out) out->assign(serialized.begin(), serialized.begin() + size);
        return true;
    };
    CopyMemoryToAccelerationStructureCommand c;
    c.src = 0x1000;
    ClusterMemoryWalk walk = walk_copy_memory_to_acceleration_structure_inputs(c, read);
    ASSERT_TRUE(walk.issues.empty());
    ASSERT_EQ(walk.ranges.size(), 1u);
    EXPECT_EQ(walk.ranges[0].bytes.size(), 300u);

    const uint64_t hostile = uint64_t(1) << 62;
    std::memcpy(serialized.data() + 2 * VK_UUID_SIZE, &hostile, 8);
    walk = walk_copy_memory_to_acceleration_structure_inputs(c, read);
    ASSERT_EQ(walk.issues.size(), 1u);
    EXPECT_NE(walk.issues[0].rule.find("claims"), std::string::npos);
    ASSERT_EQ(walk.ranges.size(), 1u);
    EXPECT_EQ(walk.ranges[0].bytes.size(), 2u * VK_UUID_SIZE + 8);  // the header alone
}

// VUID-VkGeometryTrianglesNV-vertexFormat-02430 allows the 16-bit three-component formats: their
// vertices are captured by their 6 bytes, not reported as unknown.
TEST_F(TwoBuffers, NVBuildCapturesSixByteVertexFormats) {
    for (VkFormat format : {VK_FORMAT_R16G16B16_SFLOAT, VK_FORMAT_R16G16B16_SNORM}) {
        BuildAccelerationStructureNVCommand c;
        c.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_NV;
        VkGeometryNV g = triangles(kGeometry);
        g.geometry.triangles.vertexFormat = format;
        c.geometries = {g};
        ClusterMemoryWalk walk = walk_build_acceleration_structure_nv_inputs(c, reader());
        ASSERT_TRUE(walk.issues.empty()) << walk.issues[0].rule;
        ASSERT_EQ(walk.ranges[0].role, MemoryRole::kVertexBuffer);
        EXPECT_EQ(walk.ranges[0].bytes.size(), 2u * 16 + 6) << "format " << format;
    }
}

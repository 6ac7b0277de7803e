// SPDX-License-Identifier: Apache-2.0
#include "clastrace/capture/cluster_input_walker.h"

#include <gtest/gtest.h>

#include <cstring>
#include <map>
#include <random>

using namespace clastrace::capture;

namespace {

// Device memory as a few disjoint regions; reads must fall inside one region.
struct FakeDeviceMemory {
    std::map<VkDeviceAddress, std::vector<uint8_t>> regions;
    uint64_t bytesRead = 0;

    uint8_t* region(VkDeviceAddress base, size_t size) {
        auto& bytes = regions[base];
        bytes.assign(size, 0);
        return bytes.data();
    }
    template <typename T>
    void put(VkDeviceAddress address, const T& value) {
        auto it = std::prev(regions.upper_bound(address));
        std::memcpy(it->second.data() + (address - it->first), &value, sizeof value);
    }
    DeviceMemoryReader reader() {
        return [this](VkDeviceAddress a, uint64_t size, CapturedBytes* out, std::string& why) {
            auto it = regions.upper_bound(a);
            if (it == regions.begin()) {
                why = "unmapped";
                return false;
            }
            --it;
            const uint64_t offset = a - it->first;
            if (offset > it->second.size() || size > it->second.size() - offset) {
                why = "outside";
                return false;
            }
            if (out) {
                out->assign(it->second.begin() + offset, it->second.begin() + offset + size);
                bytesRead += size;
            }
            return true;
        };
    }
};

constexpr VkDeviceAddress kInfos = 0x10000, kCount = 0x20000, kIndices = 0x30000,
                          kVertices = 0x40000, kGeometry = 0x50000, kRefs = 0x60000, kDst = 0x70000,
                          kSizes = 0x80000, kObjects = 0x90000;

ClusterCommandParameters triangleBuild(uint32_t max_count, uint64_t stride, uint64_t size) {
    VkClusterAccelerationStructureTriangleClusterInputNV input{};
    input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    input.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    VkClusterAccelerationStructureCommandsInfoNV info{};
    info.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    info.input.maxAccelerationStructureCount = max_count;
    info.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
    info.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    info.input.opInput.pTriangleClusters = &input;
    info.srcInfosArray = {kInfos, stride, size};
    info.srcInfosCount = kCount;
    info.dstAddressesArray = {kDst, 0, 0};
    info.dstSizesArray = {kSizes, 0, 0};
    return ClusterCommandParameters::copy_of(info);
}

std::vector<const CapturedRange*> rangesOf(const ClusterMemoryWalk& walk, MemoryRole role) {
    std::vector<const CapturedRange*> out;
    for (const auto& r : walk.ranges)
        if (r.role == role) out.push_back(&r);
    return out;
}

struct TwoClusters : ::testing::Test {
    FakeDeviceMemory memory;
    VkClusterAccelerationStructureBuildTriangleClusterInfoNV cluster[2]{};
    void SetUp() override {
        memory.region(kInfos, 4096);
        memory.region(kCount, 16);
        memory.region(kIndices, 4096);
        memory.region(kVertices, 4096);
        memory.region(kGeometry, 256);
        uint8_t* idx = memory.regions[kIndices].data();
        for (int i = 0; i < 4096; ++i) idx[i] = uint8_t(i);
        memory.put(kCount, uint32_t(2));
        cluster[0].triangleCount = 2;
        cluster[0].vertexCount = 4;
        cluster[0].indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_16BIT_NV;
        cluster[0].indexBuffer = kIndices;
        cluster[0].vertexBuffer = kVertices;
        cluster[0].geometryIndexAndFlagsBuffer = kGeometry;
        cluster[1].triangleCount = 1;
        cluster[1].vertexCount = 3;
        cluster[1].indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV;
        cluster[1].indexBufferStride = 8;
        cluster[1].vertexBufferStride = 16;
        cluster[1].indexBuffer = kIndices + 100;
        cluster[1].vertexBuffer = kVertices + 256;
        memory.put(kInfos, cluster[0]);
        memory.put(kInfos + 96, cluster[1]);
    }
};

}  // namespace

TEST_F(TwoClusters, FollowsEveryPointerWithExactRanges) {
    ClusterMemoryWalk walk = walk_cluster_inputs(triangleBuild(3, 96, 3 * 96), memory.reader());
    EXPECT_TRUE(walk.issues.empty()) << walk.issues[0].rule;
    EXPECT_EQ(walk.executed_count, 2u);

    auto count = rangesOf(walk, MemoryRole::kSrcInfosCount);
    ASSERT_EQ(count.size(), 1u);
    EXPECT_EQ(count[0]->bytes, (std::vector<uint8_t>{2, 0, 0, 0}));

    auto infos = rangesOf(walk, MemoryRole::kSrcInfos);  // stride 96 > 64: one range per entry
    ASSERT_EQ(infos.size(), 2u);
    EXPECT_EQ(infos[0]->address, kInfos);
    EXPECT_EQ(infos[1]->address, kInfos + 96);
    EXPECT_EQ(infos[1]->bytes.size(), 64u);
    EXPECT_EQ(0, std::memcmp(infos[1]->bytes.data(), &cluster[1], 64));

    auto indices = rangesOf(walk, MemoryRole::kIndexBuffer);
    ASSERT_EQ(indices.size(), 4u);  // cluster 0 packed (1 range), cluster 1 strided (3 ranges)
    EXPECT_EQ(indices[0]->address, kIndices);
    EXPECT_EQ(indices[0]->bytes.size(), 12u);  // 2 triangles * 3 * 2 bytes
    EXPECT_EQ(indices[0]->bytes[11], 11);
    EXPECT_EQ(indices[1]->entry, 1u);
    EXPECT_EQ(indices[2]->address, kIndices + 108);
    EXPECT_EQ(indices[3]->bytes, (std::vector<uint8_t>{116, 117, 118, 119}));

    auto vertices = rangesOf(walk, MemoryRole::kVertexBuffer);
    ASSERT_EQ(vertices.size(), 4u);
    EXPECT_EQ(vertices[0]->bytes.size(), 48u);
    EXPECT_EQ(vertices[3]->address, kVertices + 256 + 32);
    EXPECT_EQ(vertices[3]->bytes.size(), 12u);

    auto geometry = rangesOf(walk, MemoryRole::kGeometryIndexAndFlags);
    ASSERT_EQ(geometry.size(), 1u);
    EXPECT_EQ(geometry[0]->bytes.size(), 8u);
}

TEST_F(TwoClusters, CountIsTheMinimumOfMemoryAndMaximum) {
    ClusterMemoryWalk walk = walk_cluster_inputs(triangleBuild(1, 96, 0), memory.reader());
    EXPECT_EQ(walk.executed_count, 1u);
    ASSERT_EQ(walk.issues.size(), 1u);
    EXPECT_NE(walk.issues[0].rule.find(
                  "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-10453"),
              std::string::npos);
    EXPECT_EQ(rangesOf(walk, MemoryRole::kSrcInfos).size(), 1u);
}

TEST_F(TwoClusters, NullCountAddressMeansTheMaximum) {
    ClusterCommandParameters p = triangleBuild(2, 96, 0);
    p.info.srcInfosCount = 0;
    ClusterMemoryWalk walk = walk_cluster_inputs(p, memory.reader());
    EXPECT_EQ(walk.executed_count, 2u);
    EXPECT_TRUE(rangesOf(walk, MemoryRole::kSrcInfosCount).empty());
}

TEST_F(TwoClusters, TooSmallSrcInfosArrayIsReportedAndClamped) {
    ClusterMemoryWalk walk = walk_cluster_inputs(triangleBuild(3, 96, 96), memory.reader());
    EXPECT_EQ(walk.executed_count, 1u);
    ASSERT_FALSE(walk.issues.empty());
    EXPECT_NE(walk.issues[0].rule.find("pCommandInfos-10454"), std::string::npos)
        << walk.issues[0].rule;
}

TEST_F(TwoClusters, BadIndexTypeAndUnmappedVerticesAreIssuesNotCrashes) {
    cluster[1].indexType = 3;  // two bits
    cluster[1].vertexBuffer = 0xDEAD0000;
    memory.put(kInfos + 96, cluster[1]);
    ClusterMemoryWalk walk = walk_cluster_inputs(triangleBuild(3, 96, 0), memory.reader());
    ASSERT_EQ(walk.issues.size(), 2u);
    EXPECT_NE(walk.issues[0].rule.find("indexType 3"), std::string::npos) << walk.issues[0].rule;
    EXPECT_NE(walk.issues[1].rule.find("vertexBuffer"), std::string::npos) << walk.issues[1].rule;
    EXPECT_EQ(walk.issues[1].address, 0xDEAD0000u);
    EXPECT_EQ(rangesOf(walk, MemoryRole::kIndexBuffer).size(), 1u);  // cluster 0's are still there
}

TEST_F(TwoClusters, HostileCountDoesNotReadPastMemory) {
    memory.put(kCount, uint32_t(0xFFFFFFFF));
    ClusterMemoryWalk walk = walk_cluster_inputs(triangleBuild(0xFFFFFFFF, 0, 0), memory.reader());
    EXPECT_FALSE(walk.issues.empty());
    EXPECT_LT(memory.bytesRead, 1u << 20);
}

TEST_F(TwoClusters, IndirectCountIsFollowedThroughItsAddress) {
    memory.region(0xA0000, 8);
    memory.put(0xA0000, VkDeviceAddress(kCount));
    ClusterCommandParameters p = triangleBuild(3, 96, 0);
    p.info.srcInfosCount = 0xA0000;
    p.info.addressResolutionFlags =
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_COUNT_BIT_NV;
    ClusterMemoryWalk walk = walk_cluster_inputs(p, memory.reader());
    EXPECT_EQ(walk.executed_count, 2u);
    EXPECT_EQ(rangesOf(walk, MemoryRole::kIndirectAddress).size(), 1u);
}

// INDIRECTED_SRC_INFOS_ARRAY: the cell holds srcInfosArray.deviceAddress alone (8 bytes); the
// stride and size stay the command's (docs/spec-readings.md). The cell's region is 8 bytes, so
// reading a whole 24-byte region through it fails.
TEST_F(TwoClusters, IndirectSrcInfosCellHoldsTheAddressOnly) {
    memory.region(0xA0000, 8);
    memory.put(0xA0000, VkDeviceAddress(kInfos));
    ClusterCommandParameters p = triangleBuild(3, 96, 3 * 96);
    p.info.srcInfosArray.deviceAddress = 0xA0000;
    p.info.addressResolutionFlags =
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_ARRAY_BIT_NV;
    ClusterMemoryWalk walk = walk_cluster_inputs(p, memory.reader());
    EXPECT_TRUE(walk.issues.empty()) << walk.issues[0].rule;
    EXPECT_EQ(walk.executed_count, 2u);
    auto cells = rangesOf(walk, MemoryRole::kIndirectAddress);
    ASSERT_EQ(cells.size(), 1u);
    EXPECT_EQ(cells[0]->bytes.size(), 8u);
    auto infos = rangesOf(walk, MemoryRole::kSrcInfos);  // the command's stride 96
    ASSERT_EQ(infos.size(), 2u);
    EXPECT_EQ(infos[1]->address, kInfos + 96);
}

// INDIRECTED_DST_ADDRESS_ARRAY in explicit mode: the addresses the command reads are behind the
// cell, and the cell is captured too (replay reads it again). The sizes array is read too.
TEST_F(TwoClusters, ExplicitDstAddressesAreReadThroughTheirCell) {
    memory.region(0xA0000, 8);
    memory.put(0xA0000, VkDeviceAddress(kDst));
    memory.region(kDst, 64);
    memory.put(kDst, VkDeviceAddress(kObjects));
    memory.put(kDst + 8, VkDeviceAddress(kObjects + 1024));
    memory.region(kSizes, 64);
    ClusterCommandParameters p = triangleBuild(3, 96, 0);
    p.info.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
    p.info.dstAddressesArray = {0xA0000, 8, 0};
    p.info.addressResolutionFlags =
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_ADDRESS_ARRAY_BIT_NV;
    ClusterMemoryWalk walk = walk_cluster_inputs(p, memory.reader());
    EXPECT_TRUE(walk.issues.empty()) << walk.issues[0].rule;
    auto addresses = rangesOf(walk, MemoryRole::kDstAddresses);
    ASSERT_EQ(addresses.size(), 1u);
    EXPECT_EQ(addresses[0]->address, kDst);
    EXPECT_EQ(addresses[0]->bytes.size(), 16u);
    auto sizes = rangesOf(walk, MemoryRole::kDstSizes);
    ASSERT_EQ(sizes.size(), 1u);
    EXPECT_EQ(sizes[0]->address, kSizes);
    EXPECT_EQ(sizes[0]->bytes.size(), 8u);
    EXPECT_EQ(rangesOf(walk, MemoryRole::kIndirectAddress).size(), 1u);
}

// Implicit outputs behind INDIRECTED_DST_ADDRESS_ARRAY and INDIRECTED_DST_SIZES_ARRAY: the outputs
// walk follows both cells, keeps the arrays and objects, and leaves the cells to the inputs walk.
TEST(ClusterInputWalker, OutputsAreFollowedThroughIndirectCells) {
    FakeDeviceMemory memory;
    memory.region(0xA0000, 16);
    memory.put(0xA0000, VkDeviceAddress(kDst));
    memory.put(0xA0008, VkDeviceAddress(kSizes));
    memory.region(kDst, 64);
    memory.region(kSizes, 64);
    memory.region(kObjects, 4096);
    memory.put(kDst, VkDeviceAddress(kObjects));
    memory.put(kSizes, uint32_t(256));
    ClusterCommandParameters p = triangleBuild(1, 0, 0);
    p.info.dstAddressesArray = {0xA0000, 0, 0};
    p.info.dstSizesArray = {0xA0008, 0, 0};
    p.info.addressResolutionFlags =
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_ADDRESS_ARRAY_BIT_NV |
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_SIZES_ARRAY_BIT_NV;
    ClusterMemoryWalk walk = walk_cluster_outputs(p, 1, memory.reader());
    EXPECT_TRUE(walk.issues.empty()) << walk.issues[0].rule;
    EXPECT_TRUE(rangesOf(walk, MemoryRole::kIndirectAddress).empty());
    ASSERT_EQ(rangesOf(walk, MemoryRole::kDstSizes).size(), 1u);
    EXPECT_EQ(rangesOf(walk, MemoryRole::kDstSizes)[0]->address, kSizes);
    auto objects = rangesOf(walk, MemoryRole::kDstObject);
    ASSERT_EQ(objects.size(), 1u);
    EXPECT_EQ(objects[0]->address, kObjects);
    EXPECT_EQ(objects[0]->bytes.size(), 256u);
}

// A bad indexType is its info struct's indexType rule (10491; 10500 for templates), not the
// vertex-stride rule 10495.
TEST_F(TwoClusters, BadIndexTypeNamesTheIndexTypeRule) {
    cluster[1].indexType = 3;
    memory.put(kInfos + 96, cluster[1]);
    ClusterMemoryWalk walk = walk_cluster_inputs(triangleBuild(3, 96, 0), memory.reader());
    ASSERT_FALSE(walk.issues.empty());
    EXPECT_EQ(walk.issues[0].rule.rfind(
                  "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-indexType-10491: ",
                  0),
              0u)
        << walk.issues[0].rule;
}

TEST(ClusterInputWalker, TemplateBoundsAndBottomLevelReferences) {
    FakeDeviceMemory memory;
    memory.region(kInfos, 1024);
    memory.region(kRefs, 1024);
    memory.region(kIndices, 64);
    memory.region(0xB0000, 64);
    VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV tmpl{};
    tmpl.triangleCount = 1;
    tmpl.vertexCount = 3;
    tmpl.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_8BIT_NV;
    tmpl.indexBuffer = kIndices;
    tmpl.instantiationBoundingBoxLimit = 0xB0000;  // no vertex buffer: allowed for templates
    memory.put(kInfos, tmpl);
    ClusterCommandParameters p = triangleBuild(1, 0, 0);
    p.info.input.opType =
        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV;
    p.info.srcInfosCount = 0;
    ClusterMemoryWalk walk = walk_cluster_inputs(p, memory.reader());
    EXPECT_TRUE(walk.issues.empty());
    EXPECT_EQ(rangesOf(walk, MemoryRole::kSrcInfos)[0]->bytes.size(), 72u);
    ASSERT_EQ(rangesOf(walk, MemoryRole::kInstantiationBoundingBox).size(), 1u);
    EXPECT_EQ(rangesOf(walk, MemoryRole::kInstantiationBoundingBox)[0]->bytes.size(), 24u);
    EXPECT_EQ(rangesOf(walk, MemoryRole::kIndexBuffer)[0]->bytes.size(), 3u);
    EXPECT_TRUE(rangesOf(walk, MemoryRole::kVertexBuffer).empty());

    VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV blas{3, 16, kRefs};
    memory.put(kInfos, blas);
    ClusterCommandParameters b = triangleBuild(1, 0, 0);
    b.info.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV;
    b.info.srcInfosCount = 0;
    walk = walk_cluster_inputs(b, memory.reader());
    auto refs = rangesOf(walk, MemoryRole::kClusterReferences);
    ASSERT_EQ(refs.size(), 3u);
    EXPECT_EQ(refs[2]->address, kRefs + 32);
    EXPECT_EQ(refs[2]->bytes.size(), 8u);
}

// An instantiation reads as many vertices as its template has: the count comes from the
// template's build (walkClusterInputs reports it per entry), looked up by template address.
TEST(ClusterInputWalker, InstantiationVerticesAreSizedByTheirTemplate) {
    FakeDeviceMemory memory;
    memory.region(kInfos, 1024);
    memory.region(kIndices, 64);
    memory.region(kVertices, 1024);
    VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV tmpl[2]{};
    for (uint32_t i = 0; i < 2; ++i) {
        tmpl[i].triangleCount = 1;
        tmpl[i].vertexCount = 3 + 2 * i;
        tmpl[i].indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_8BIT_NV;
        tmpl[i].indexBuffer = kIndices;
    }
    memory.put(kInfos, tmpl[0]);
    memory.put(kInfos + sizeof tmpl[0], tmpl[1]);
    ClusterCommandParameters t = triangleBuild(2, 0, 0);
    t.info.input.opType =
        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV;
    t.info.srcInfosCount = 0;
    EXPECT_EQ(walk_cluster_inputs(t, memory.reader()).template_vertex_counts,
              (std::vector<uint32_t>{3, 5}));

    // Two instantiations of template 0xA000 (5 vertices): packed, and 32 bytes apart.
    VkClusterAccelerationStructureInstantiateClusterInfoNV instance[2]{};
    instance[0].clusterTemplateAddress = 0xA000;
    instance[0].vertexBuffer = {kVertices, 12};
    instance[1].clusterTemplateAddress = 0xA000;
    instance[1].vertexBuffer = {kVertices + 512, 32};
    memory.put(kInfos, instance[0]);
    memory.put(kInfos + sizeof instance[0], instance[1]);
    ClusterCommandParameters p = triangleBuild(2, 0, 0);
    p.info.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV;
    p.info.srcInfosCount = 0;
    std::vector<VkDeviceAddress> asked;
    ClusterMemoryWalk walk =
        walk_cluster_inputs(p, memory.reader(), [&](VkDeviceAddress a, uint32_t* vertices) {
            asked.push_back(a);
            if (a != 0xA000) return false;
            *vertices = 5;
            return true;
        });
    EXPECT_TRUE(walk.issues.empty());
    EXPECT_EQ(asked, (std::vector<VkDeviceAddress>{0xA000, 0xA000}));
    auto vertices = rangesOf(walk, MemoryRole::kVertexBuffer);
    ASSERT_EQ(vertices.size(), 6u);  // one packed span, then five 12-byte elements 32 apart
    EXPECT_EQ(vertices[0]->address, kVertices);
    EXPECT_EQ(vertices[0]->bytes.size(), 60u);
    EXPECT_EQ(vertices[5]->address, kVertices + 512 + 4 * 32);
    EXPECT_EQ(vertices[5]->bytes.size(), 12u);
    EXPECT_EQ(vertices[5]->entry, 1u);

    // A template the layer never saw built: an issue naming the entry, no guessed length.
    walk =
        walk_cluster_inputs(p, memory.reader(), [](VkDeviceAddress, uint32_t*) { return false; });
    EXPECT_TRUE(rangesOf(walk, MemoryRole::kVertexBuffer).empty());
    ASSERT_EQ(walk.issues.size(), 2u);
    EXPECT_NE(walk.issues[0].rule.find("vertexBuffer of srcInfosArray entry 0 not captured"),
              std::string::npos)
        << walk.issues[0].rule;
}

TEST(ClusterInputWalker, OutputsReadAddressesSizesAndTheObjects) {
    FakeDeviceMemory memory;
    memory.region(kDst, 64);
    memory.region(kSizes, 64);
    memory.region(kObjects, 4096);
    memory.put(kDst, VkDeviceAddress(kObjects));
    memory.put(kDst + 8, VkDeviceAddress(kObjects + 1024));
    memory.put(kSizes, uint32_t(256));
    memory.put(kSizes + 4, uint32_t(512));
    ClusterMemoryWalk walk = walk_cluster_outputs(triangleBuild(2, 0, 0), 2, memory.reader());
    EXPECT_TRUE(walk.issues.empty());
    auto objects = rangesOf(walk, MemoryRole::kDstObject);
    ASSERT_EQ(objects.size(), 2u);
    EXPECT_EQ(objects[1]->address, kObjects + 1024);
    EXPECT_EQ(objects[1]->bytes.size(), 512u);
    EXPECT_EQ(rangesOf(walk, MemoryRole::kDstAddresses)[0]->bytes.size(), 16u);
}

// Deterministic random mutation of the entries: the walker must neither crash nor read more
// than the regions hold, whatever the GPU-side bytes say.
TEST(ClusterInputWalker, RandomEntriesNeverEscapeTheRegions) {
    std::mt19937_64 random(12345);
    FakeDeviceMemory memory;
    memory.region(kInfos, 8192);
    memory.region(kCount, 8);
    memory.region(kIndices, 4096);
    memory.region(kVertices, 4096);
    const VkClusterAccelerationStructureOpTypeNV ops[] = {
        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV,
        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV,
        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV,
        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV,
        VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV,
        (VkClusterAccelerationStructureOpTypeNV)77};
    for (int iteration = 0; iteration < 500; ++iteration) {
        auto& infos = memory.regions[kInfos];
        for (size_t i = 0; i < infos.size(); i += 8) {
            uint64_t word = random();
            // Half the pointers land inside the regions so the walk goes deep.
            if (random() % 2) word = (random() % 2 ? kIndices : kVertices) + random() % 4200;
            std::memcpy(infos.data() + i, &word, 8);
        }
        memory.put(kCount, uint32_t(random() % 200));
        ClusterCommandParameters p =
            triangleBuild(uint32_t(random() % 300), (random() % 4) * 32, random() % 2 ? 0 : 8192);
        p.info.input.opType = ops[random() % 6];
        ClusterMemoryWalk walk = walk_cluster_inputs(p, memory.reader());
        uint64_t total = 0;
        for (const auto& r : walk.ranges) total += r.bytes.size();
        EXPECT_LE(total, kMaxCapturedBytesPerCommand);
        for (const auto& r : walk.ranges) {
            auto it = std::prev(memory.regions.upper_bound(r.address));
            ASSERT_LE(r.address - it->first + r.bytes.size(), it->second.size());
        }
    }
}

// Every vertex format the engine decodes (VUID-...-vertexFormat-10439 allows any with the
// acceleration-structure vertex feature) is captured by its own size, not only the float ones.
TEST_F(TwoClusters, EveryDecodedVertexFormatIsCapturedByItsSize) {
    const std::pair<VkFormat, uint64_t> formats[] = {{VK_FORMAT_R32G32_SFLOAT, 8},
                                                     {VK_FORMAT_R16G16_SNORM, 4},
                                                     {VK_FORMAT_R16G16_UNORM, 4},
                                                     {VK_FORMAT_R16G16B16A16_UNORM, 8},
                                                     {VK_FORMAT_R8G8_SNORM, 2},
                                                     {VK_FORMAT_R8G8B8A8_UNORM, 4},
                                                     {VK_FORMAT_A2B10G10R10_UNORM_PACK32, 4},
                                                     {VK_FORMAT_R32G32B32A32_SFLOAT, 16}};
    for (const auto& [format, size] : formats) {
        ClusterCommandParameters p = triangleBuild(3, 96, 3 * 96);
        p.triangle_cluster_input.vertexFormat = format;
        ClusterMemoryWalk walk = walk_cluster_inputs(p, memory.reader());
        EXPECT_TRUE(walk.issues.empty()) << "format " << format << ": " << walk.issues[0].rule;
        auto vertices = rangesOf(walk, MemoryRole::kVertexBuffer);
        ASSERT_FALSE(vertices.empty()) << "format " << format;
        EXPECT_EQ(vertices[0]->bytes.size(), 4 * size) << "format " << format;  // 4 packed
    }
}

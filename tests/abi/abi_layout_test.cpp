// SPDX-License-Identifier: Apache-2.0
// The structs the GPU reads through srcInfosArray must have the exact bit pattern the
// spec describes; sizes and offsets are static_asserts in the header, bit-fields are here.
#include "clastrace/vk_cluster_abi.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <cstring>

namespace {

template <typename T>
uint32_t word_at(const T& s, size_t offset) {
    uint32_t w = 0;
    std::memcpy(&w, reinterpret_cast<const unsigned char*>(&s) + offset, sizeof w);
    return w;
}

template <typename Info>
void expect_triangle_bitfields() {
    Info info{};
    info.triangleCount = 0x1FF;
    EXPECT_EQ(word_at(info, 8), 0x1FFu) << "triangleCount: 9 least significant bits";
    info = Info{};
    info.vertexCount = 0x1FF;
    EXPECT_EQ(word_at(info, 8), 0x1FFu << 9) << "vertexCount: next 9 bits";
    info = Info{};
    info.positionTruncateBitCount = 0x3F;
    EXPECT_EQ(word_at(info, 8), 0x3Fu << 18) << "positionTruncateBitCount: next 6 bits";
    info = Info{};
    info.indexType = 0xF;
    EXPECT_EQ(word_at(info, 8), 0xFu << 24) << "indexType: next 4 bits";
    info = Info{};
    info.opacityMicromapIndexType = 0xF;
    EXPECT_EQ(word_at(info, 8), 0xFu << 28) << "opacityMicromapIndexType: 4 most significant bits";
}

TEST(AbiLayout, TriangleClusterInfoBitfields) {
    expect_triangle_bitfields<VkClusterAccelerationStructureBuildTriangleClusterInfoNV>();
}

TEST(AbiLayout, TriangleClusterTemplateInfoBitfields) {
    expect_triangle_bitfields<VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV>();
}

TEST(AbiLayout, GeometryIndexAndFlagsBitfields) {
    VkClusterAccelerationStructureGeometryIndexAndGeometryFlagsNV g{};
    g.geometryIndex = 0xABCDEF;
    EXPECT_EQ(word_at(g, 0), 0xABCDEFu);
    g = {};
    g.reserved = 0x1F;
    EXPECT_EQ(word_at(g, 0), 0x1Fu << 24);
    g = {};
    g.geometryFlags = VK_CLUSTER_ACCELERATION_STRUCTURE_GEOMETRY_OPAQUE_BIT_NV;
    EXPECT_EQ(word_at(g, 0), 4u << 29);
}

TEST(AbiLayout, InstantiateInfoBitfields) {
    VkClusterAccelerationStructureInstantiateClusterInfoNV info{};
    info.geometryIndexOffset = 0xFFFFFF;
    EXPECT_EQ(word_at(info, 4), 0xFFFFFFu);
    info = {};
    info.reserved = 0xFF;
    EXPECT_EQ(word_at(info, 4), 0xFFu << 24);
}

TEST(AbiLayout, EnumValuesMatchRegistry) {
    EXPECT_EQ(VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV, 1000569006);
    EXPECT_EQ(VK_STRUCTURE_TYPE_RAY_TRACING_PIPELINE_CLUSTER_ACCELERATION_STRUCTURE_CREATE_INFO_NV,
              1000569007);
    EXPECT_EQ(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV, 5);
    EXPECT_EQ(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV, 2);
    EXPECT_EQ(
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_COUNT_BIT_NV,
        0x20);
    EXPECT_EQ(VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV, 4);
    EXPECT_EQ(static_cast<int>(
                  VK_BUILD_ACCELERATION_STRUCTURE_ALLOW_CLUSTER_OPACITY_MICROMAPS_BIT_NV),
              0x1000);
    EXPECT_EQ(static_cast<int>(
                  VK_OPACITY_MICROMAP_SPECIAL_INDEX_CLUSTER_GEOMETRY_DISABLE_OPACITY_MICROMAP_NV),
              -5);
}

}  // namespace

// SPDX-License-Identifier: Apache-2.0
// VK_KHR_acceleration_structure build structs -> trace records -> structs
// (traces/khr_conversions.h): every field comes back through the packed bytes, geometries given
// by pGeometries and by ppGeometries alike.
#include <clastrace/traces/khr_conversions.h>

#include <clastrace/common/enum_bits.h>

#include <gtest/gtest.h>

#include <cstdint>
#include <cstring>
#include <limits>
#include <vector>

namespace clastrace::traces {
namespace {

constexpr uint32_t kMax32 = std::numeric_limits<uint32_t>::max();
constexpr uint64_t kMax64 = std::numeric_limits<uint64_t>::max();

const fbs::AccelerationStructureBuildInfoKHR& packed(
    const fbs::AccelerationStructureBuildInfoKHRT& object, flatbuffers::FlatBufferBuilder& fbb) {
    fbb.Finish(fbs::AccelerationStructureBuildInfoKHR::Pack(fbb, &object));
    return *flatbuffers::GetRoot<fbs::AccelerationStructureBuildInfoKHR>(fbb.GetBufferPointer());
}

std::vector<VkAccelerationStructureGeometryKHR> three_geometries(uint64_t value) {
    std::vector<VkAccelerationStructureGeometryKHR> g(3);
    for (auto& geometry : g) geometry.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR;
    g[0].geometryType = VK_GEOMETRY_TYPE_TRIANGLES_KHR;
    g[0].flags = uint32_t(value) & 3;
    auto& t = g[0].geometry.triangles;
    t.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_TRIANGLES_DATA_KHR;
    common::set_enum_bits(t.vertexFormat, uint32_t(value));
    t.vertexData.deviceAddress = value;
    t.vertexStride = value ^ 1;
    t.maxVertex = uint32_t(value ^ 2);
    common::set_enum_bits(t.indexType, uint32_t(value));
    t.indexData.deviceAddress = value ^ 3;
    t.transformData.deviceAddress = value ^ 4;
    g[1].geometryType = VK_GEOMETRY_TYPE_AABBS_KHR;
    g[1].geometry.aabbs.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_AABBS_DATA_KHR;
    g[1].geometry.aabbs.data.deviceAddress = value ^ 5;
    g[1].geometry.aabbs.stride = value ^ 6;
    g[2].geometryType = VK_GEOMETRY_TYPE_INSTANCES_KHR;
    g[2].geometry.instances.sType =
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_INSTANCES_DATA_KHR;
    g[2].geometry.instances.arrayOfPointers = VK_TRUE;
    g[2].geometry.instances.data.deviceAddress = value ^ 7;
    return g;
}

void expect_same(const VkAccelerationStructureGeometryKHR& a,
                 const VkAccelerationStructureGeometryKHR& b) {
    EXPECT_EQ(a.geometryType, b.geometryType);
    EXPECT_EQ(a.flags, b.flags);
    // The union member geometryType names, byte for byte (its sType included).
    const size_t size =
        a.geometryType == VK_GEOMETRY_TYPE_TRIANGLES_KHR ? sizeof a.geometry.triangles
        : a.geometryType == VK_GEOMETRY_TYPE_AABBS_KHR   ? sizeof a.geometry.aabbs
                                                         : sizeof a.geometry.instances;
    EXPECT_EQ(std::memcmp(&a.geometry, &b.geometry, size), 0) << a.geometryType;
}

void round_trip(uint64_t value, bool pointers) {
    std::vector<VkAccelerationStructureGeometryKHR> geometries = three_geometries(value);
    std::vector<const VkAccelerationStructureGeometryKHR*> pointer_list;
    for (const auto& g : geometries) pointer_list.push_back(&g);
    const VkAccelerationStructureBuildRangeInfoKHR ranges[3] = {
        {uint32_t(value), uint32_t(value ^ 1), uint32_t(value ^ 2), uint32_t(value ^ 3)},
        {1, 2, 3, 4},
        {kMax32, 0, kMax32, 0}};
    VkAccelerationStructureBuildGeometryInfoKHR info{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_GEOMETRY_INFO_KHR};
    info.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR;
    info.flags = uint32_t(value) & 0x1f;
    info.mode = VK_BUILD_ACCELERATION_STRUCTURE_MODE_UPDATE_KHR;
    info.srcAccelerationStructure = reinterpret_cast<VkAccelerationStructureKHR>(value ^ 8);
    info.dstAccelerationStructure = reinterpret_cast<VkAccelerationStructureKHR>(value ^ 9);
    info.geometryCount = 3;
    if (pointers)
        info.ppGeometries = pointer_list.data();
    else
        info.pGeometries = geometries.data();
    info.scratchData.deviceAddress = value ^ 10;
    VkBaseInStructure chained{VkStructureType(1000150020), nullptr};
    info.pNext = &chained;

    auto record = khr_build_info_to_record(info, ranges);
    EXPECT_EQ(record->unrecorded_next_stypes, std::vector<uint32_t>{1000150020});
    flatbuffers::FlatBufferBuilder fbb;
    std::vector<VkAccelerationStructureGeometryKHR> back_geometries;
    std::vector<VkAccelerationStructureBuildRangeInfoKHR> back_ranges;
    const auto back =
        khr_build_info_from_record(packed(*record, fbb), back_geometries, back_ranges);
    EXPECT_EQ(back.type, info.type);
    EXPECT_EQ(back.flags, info.flags);
    EXPECT_EQ(back.mode, info.mode);
    EXPECT_EQ(back.srcAccelerationStructure, info.srcAccelerationStructure);
    EXPECT_EQ(back.dstAccelerationStructure, info.dstAccelerationStructure);
    EXPECT_EQ(back.scratchData.deviceAddress, info.scratchData.deviceAddress);
    EXPECT_EQ(back.pNext, nullptr);
    EXPECT_EQ(back.ppGeometries, nullptr);
    ASSERT_EQ(back.geometryCount, 3u);
    ASSERT_EQ(back.pGeometries, back_geometries.data());
    for (size_t g = 0; g < 3; ++g) expect_same(geometries[g], back_geometries[g]);
    ASSERT_EQ(back_ranges.size(), 3u);
    for (size_t r = 0; r < 3; ++r)
        EXPECT_EQ(std::memcmp(&back_ranges[r], &ranges[r], sizeof ranges[r]), 0) << r;
}

TEST(KhrConversions, BuildInfoRoundTripsAtZeroAndAtTheMaximum) {
    for (uint64_t value : {uint64_t(0), kMax64, uint64_t(0x123456789abcdef0)}) {
        round_trip(value, false);
        round_trip(value, true);
    }
}

// An indirect build's info carries no ranges of its own (they are read at execution).
TEST(KhrConversions, NoRangesGivenMeansNoneRecorded) {
    std::vector<VkAccelerationStructureGeometryKHR> geometries = three_geometries(5);
    VkAccelerationStructureBuildGeometryInfoKHR info{
        VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_GEOMETRY_INFO_KHR};
    info.geometryCount = 3;
    info.pGeometries = geometries.data();
    auto record = khr_build_info_to_record(info, nullptr);
    EXPECT_EQ(record->geometries.size(), 3u);
    EXPECT_TRUE(record->ranges.empty());
}

}  // namespace
}  // namespace clastrace::traces

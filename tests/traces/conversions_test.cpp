// SPDX-License-Identifier: Apache-2.0
// Vulkan structs -> trace records -> Vulkan structs (traces/cluster_conversions.h,
// traces/nv_conversions.h): every field comes back, at zero, at its maximum and with every flag
// bit set, through the bytes a trace stores (each record is packed and read back).
#include <clastrace/traces/cluster_conversions.h>
#include <clastrace/traces/nv_conversions.h>

#include <clastrace/common/enum_bits.h>

#include <gtest/gtest.h>

#include <cstdint>
#include <limits>
#include <type_traits>
#include <vector>

namespace clastrace::traces {
namespace {

using common::enum_bits;
using common::set_enum_bits;

constexpr uint32_t kMax32 = std::numeric_limits<uint32_t>::max();
constexpr uint64_t kMax64 = std::numeric_limits<uint64_t>::max();

// Packs an object-API record the way the writer does and keeps the bytes for the reader view.
template <class Table, class Object>
const Table& packed(const Object& object, flatbuffers::FlatBufferBuilder& fbb) {
    fbb.Finish(Table::Pack(fbb, &object));
    return *flatbuffers::GetRoot<Table>(fbb.GetBufferPointer());
}

VkClusterAccelerationStructureTriangleClusterInputNV triangle_limits(uint32_t value) {
    VkClusterAccelerationStructureTriangleClusterInputNV t{};
    t.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    set_enum_bits(t.vertexFormat, value);  // kMax32 is past VkFormat's range
    t.maxGeometryIndexValue = value;
    t.maxClusterUniqueGeometryCount = value ^ 1;
    t.maxClusterTriangleCount = value ^ 2;
    t.maxClusterVertexCount = value ^ 3;
    t.maxTotalTriangleCount = value ^ 4;
    t.maxTotalVertexCount = value ^ 5;
    t.minPositionTruncateBitCount = value ^ 6;
    return t;
}

void expect_equal(const VkClusterAccelerationStructureTriangleClusterInputNV& a,
                  const VkClusterAccelerationStructureTriangleClusterInputNV& b) {
    EXPECT_EQ(a.sType, b.sType);
    EXPECT_EQ(enum_bits(a.vertexFormat), enum_bits(b.vertexFormat));
    EXPECT_EQ(a.maxGeometryIndexValue, b.maxGeometryIndexValue);
    EXPECT_EQ(a.maxClusterUniqueGeometryCount, b.maxClusterUniqueGeometryCount);
    EXPECT_EQ(a.maxClusterTriangleCount, b.maxClusterTriangleCount);
    EXPECT_EQ(a.maxClusterVertexCount, b.maxClusterVertexCount);
    EXPECT_EQ(a.maxTotalTriangleCount, b.maxTotalTriangleCount);
    EXPECT_EQ(a.maxTotalVertexCount, b.maxTotalVertexCount);
    EXPECT_EQ(a.minPositionTruncateBitCount, b.minPositionTruncateBitCount);
}

void expect_equal(const VkStridedDeviceAddressRegionKHR& a,
                  const VkStridedDeviceAddressRegionKHR& b) {
    EXPECT_EQ(a.deviceAddress, b.deviceAddress);
    EXPECT_EQ(a.stride, b.stride);
    EXPECT_EQ(a.size, b.size);
}

void expect_equal_header(const VkClusterAccelerationStructureInputInfoNV& a,
                         const VkClusterAccelerationStructureInputInfoNV& b) {
    EXPECT_EQ(a.sType, b.sType);
    EXPECT_EQ(a.pNext, nullptr);
    EXPECT_EQ(a.maxAccelerationStructureCount, b.maxAccelerationStructureCount);
    EXPECT_EQ(a.flags, b.flags);
    EXPECT_EQ(enum_bits(a.opType), enum_bits(b.opType));
    EXPECT_EQ(enum_bits(a.opMode), enum_bits(b.opMode));
}

VkClusterAccelerationStructureInputInfoNV input_info(VkClusterAccelerationStructureOpTypeNV type,
                                                     uint32_t value) {
    VkClusterAccelerationStructureInputInfoNV in{};
    in.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    in.maxAccelerationStructureCount = value;
    in.flags = value;
    in.opType = type;
    in.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV;
    return in;
}

// The input info as replay sees it: packed, read back, decoded.
VkClusterAccelerationStructureInputInfoNV round_trip(
    const VkClusterAccelerationStructureInputInfoNV& in, ClusterOpInputStorage& storage,
    flatbuffers::FlatBufferBuilder& fbb) {
    const auto record = cluster_input_to_record(in);
    return cluster_input_from_record(&packed<fbs::ClusterInputInfo>(*record, fbb), storage);
}

TEST(ClusterConversions, TriangleClusterInputOfEveryTriangleOpTypeRoundTrips) {
    for (auto type : {VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV,
                      VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV})
        for (uint32_t value : {0u, 7u, kMax32}) {
            SCOPED_TRACE(testing::Message() << "op type " << type << ", value " << value);
            const auto limits = triangle_limits(value);
            auto in = input_info(type, value);
            in.opInput.pTriangleClusters =
                const_cast<VkClusterAccelerationStructureTriangleClusterInputNV*>(&limits);
            ClusterOpInputStorage storage;
            flatbuffers::FlatBufferBuilder fbb;
            const auto out = round_trip(in, storage, fbb);
            expect_equal_header(out, in);
            ASSERT_EQ(out.opInput.pTriangleClusters, &storage.triangle_cluster);
            expect_equal(*out.opInput.pTriangleClusters, limits);
        }
}

TEST(ClusterConversions, BottomLevelInputRoundTrips) {
    for (uint32_t value : {0u, kMax32}) {
        VkClusterAccelerationStructureClustersBottomLevelInputNV bottom{};
        bottom.sType =
            VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_CLUSTERS_BOTTOM_LEVEL_INPUT_NV;
        bottom.maxTotalClusterCount = value;
        bottom.maxClusterCountPerAccelerationStructure = value ^ 9;
        auto in =
            input_info(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV,
                       value);
        in.opInput.pClustersBottomLevel = &bottom;
        ClusterOpInputStorage storage;
        flatbuffers::FlatBufferBuilder fbb;
        const auto out = round_trip(in, storage, fbb);
        expect_equal_header(out, in);
        ASSERT_EQ(out.opInput.pClustersBottomLevel, &storage.bottom_level);
        EXPECT_EQ(out.opInput.pClustersBottomLevel->sType, bottom.sType);
        EXPECT_EQ(out.opInput.pClustersBottomLevel->maxTotalClusterCount,
                  bottom.maxTotalClusterCount);
        EXPECT_EQ(out.opInput.pClustersBottomLevel->maxClusterCountPerAccelerationStructure,
                  bottom.maxClusterCountPerAccelerationStructure);
    }
}

TEST(ClusterConversions, MoveObjectsInputRoundTrips) {
    for (VkBool32 overlap : {VK_FALSE, VK_TRUE})
        for (uint64_t bytes : {uint64_t(0), kMax64}) {
            VkClusterAccelerationStructureMoveObjectsInputNV move{};
            move.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_MOVE_OBJECTS_INPUT_NV;
            move.type = VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_TEMPLATE_NV;
            move.noMoveOverlap = overlap;
            move.maxMovedBytes = bytes;
            auto in = input_info(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV, 3);
            in.opInput.pMoveObjects = &move;
            ClusterOpInputStorage storage;
            flatbuffers::FlatBufferBuilder fbb;
            const auto out = round_trip(in, storage, fbb);
            expect_equal_header(out, in);
            ASSERT_EQ(out.opInput.pMoveObjects, &storage.move_objects);
            EXPECT_EQ(out.opInput.pMoveObjects->sType, move.sType);
            EXPECT_EQ(out.opInput.pMoveObjects->type, move.type);
            EXPECT_EQ(out.opInput.pMoveObjects->noMoveOverlap, move.noMoveOverlap);
            EXPECT_EQ(out.opInput.pMoveObjects->maxMovedBytes, move.maxMovedBytes);
        }
}

TEST(ClusterConversions, NoOpInputIsRecordedForANullPointerOrAnUnknownOpType) {
    const auto limits = triangle_limits(5);
    auto unknown = input_info(static_cast<VkClusterAccelerationStructureOpTypeNV>(0x7fff), 1);
    unknown.opInput.pTriangleClusters =
        const_cast<VkClusterAccelerationStructureTriangleClusterInputNV*>(&limits);
    const auto null_input =
        input_info(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV, 1);
    for (const auto& in : {unknown, null_input}) {
        EXPECT_EQ(cluster_input_to_record(in)->op_input.type, fbs::ClusterOpInput::NONE);
        ClusterOpInputStorage storage;
        flatbuffers::FlatBufferBuilder fbb;
        const auto out = round_trip(in, storage, fbb);
        expect_equal_header(out, in);
        EXPECT_EQ(out.opInput.pTriangleClusters, nullptr);
    }
}

// An application or a hostile trace may hold any 32 bits in an enum field; Vulkan's enums only
// have values up to 0x7FFFFFFF, so the conversions carry these fields by their bits (under
// UBSan, loading 0xFFFFFFFF as the enum stops the test).
TEST(ClusterConversions, EnumFieldsPastTheEnumsRangeRoundTripAsTheirBits) {
    VkClusterAccelerationStructureMoveObjectsInputNV move{};
    move.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_MOVE_OBJECTS_INPUT_NV;
    set_enum_bits(move.type, 0xfffffffeu);
    auto in = input_info(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV, 1);
    in.opInput.pMoveObjects = &move;
    set_enum_bits(in.opMode, 0x80000000u);
    const auto record = cluster_input_to_record(in);
    EXPECT_EQ(record->op_mode, 0x80000000u);
    ASSERT_NE(record->op_input.AsMoveObjectsInput(), nullptr);
    EXPECT_EQ(record->op_input.AsMoveObjectsInput()->type, 0xfffffffeu);
    ClusterOpInputStorage storage;
    flatbuffers::FlatBufferBuilder fbb;
    const auto out = round_trip(in, storage, fbb);
    expect_equal_header(out, in);
    ASSERT_EQ(out.opInput.pMoveObjects, &storage.move_objects);
    EXPECT_EQ(enum_bits(out.opInput.pMoveObjects->type), 0xfffffffeu);
    // An op type past the range names no input: none is recorded, and the type comes back.
    set_enum_bits(in.opType, kMax32);
    EXPECT_EQ(cluster_input_to_record(in)->op_type, kMax32);
    EXPECT_EQ(cluster_input_to_record(in)->op_input.type, fbs::ClusterOpInput::NONE);
    flatbuffers::FlatBufferBuilder fbb2;
    EXPECT_EQ(enum_bits(round_trip(in, storage, fbb2).opType), kMax32);
}

// A record whose union holds another member than its opType names (a hostile trace; session 16's
// replay_built_trace fuzzing under ASan): readers follow opType, so handing them the member it
// holds had the size-query key read a triangle input past the end of a move input's storage.
TEST(ClusterConversions, AnOpInputOtherThanTheOpTypeNamesIsDropped) {
    fbs::ClusterInputInfoT record;
    record.op_type = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
    record.max_acceleration_structure_count = 7;
    fbs::MoveObjectsInputT move;
    move.max_moved_bytes = 64;
    record.op_input.Set(std::move(move));
    ClusterOpInputStorage storage;
    flatbuffers::FlatBufferBuilder fbb;
    const auto out =
        cluster_input_from_record(&packed<fbs::ClusterInputInfo>(record, fbb), storage);
    EXPECT_EQ(out.opType, VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV);
    EXPECT_EQ(out.maxAccelerationStructureCount, 7u);
    EXPECT_EQ(out.opInput.pTriangleClusters, nullptr);
    // The member the op type names still comes back.
    record.op_type = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV;
    flatbuffers::FlatBufferBuilder fbb2;
    const auto moved =
        cluster_input_from_record(&packed<fbs::ClusterInputInfo>(record, fbb2), storage);
    ASSERT_EQ(moved.opInput.pMoveObjects, &storage.move_objects);
    EXPECT_EQ(moved.opInput.pMoveObjects->maxMovedBytes, 64u);
}

TEST(ClusterConversions, MissingRecordsReadAsZeroedStructs) {
    ClusterOpInputStorage storage;
    const auto in = cluster_input_from_record(nullptr, storage);
    EXPECT_EQ(in.sType, VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV);
    EXPECT_EQ(in.maxAccelerationStructureCount, 0u);
    EXPECT_EQ(in.opInput.pTriangleClusters, nullptr);
    expect_equal(strided_region_from_record(nullptr), VkStridedDeviceAddressRegionKHR{0, 0, 0});
}

TEST(ClusterConversions, CommandsInfoRoundTripsWithEveryField) {
    for (uint64_t value : {uint64_t(0), uint64_t(0x1234'5678'9abc), kMax64}) {
        SCOPED_TRACE(testing::Message() << "value " << value);
        const auto limits = triangle_limits(uint32_t(value));
        VkClusterAccelerationStructureCommandsInfoNV info{};
        info.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
        info.input = input_info(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV,
                                uint32_t(value));
        info.input.opInput.pTriangleClusters =
            const_cast<VkClusterAccelerationStructureTriangleClusterInputNV*>(&limits);
        info.dstImplicitData = value;
        info.scratchData = value ^ 1;
        info.dstAddressesArray = {value ^ 2, value ^ 3, value ^ 4};
        info.dstSizesArray = {value ^ 5, value ^ 6, value ^ 7};
        info.srcInfosArray = {value ^ 8, value ^ 9, value ^ 10};
        info.srcInfosCount = value ^ 11;
        info.addressResolutionFlags = uint32_t(value) ^ 12;
        const auto record = cluster_commands_to_record(0xcb, info);
        EXPECT_EQ(record.command_buffer, 0xcbu);
        flatbuffers::FlatBufferBuilder fbb;
        ClusterOpInputStorage storage;
        const auto out = cluster_commands_from_record(
            packed<fbs::CmdBuildClusterAccelerationStructureIndirect>(record, fbb), storage);
        EXPECT_EQ(out.sType, info.sType);
        EXPECT_EQ(out.pNext, nullptr);
        expect_equal_header(out.input, info.input);
        ASSERT_NE(out.input.opInput.pTriangleClusters, nullptr);
        expect_equal(*out.input.opInput.pTriangleClusters, limits);
        EXPECT_EQ(out.dstImplicitData, info.dstImplicitData);
        EXPECT_EQ(out.scratchData, info.scratchData);
        expect_equal(out.dstAddressesArray, info.dstAddressesArray);
        expect_equal(out.dstSizesArray, info.dstSizesArray);
        expect_equal(out.srcInfosArray, info.srcInfosArray);
        EXPECT_EQ(out.srcInfosCount, info.srcInfosCount);
        EXPECT_EQ(out.addressResolutionFlags, info.addressResolutionFlags);
    }
}

template <class Handle>
Handle handle(uint64_t value) {
    if constexpr (std::is_pointer_v<Handle>)
        return reinterpret_cast<Handle>(uintptr_t(value));
    else
        return Handle(value);
}

VkGeometryNV geometry(VkGeometryTypeNV type, uint64_t value) {
    VkGeometryNV g{};
    g.sType = VK_STRUCTURE_TYPE_GEOMETRY_NV;
    g.geometryType = type;
    g.flags = VkGeometryFlagsNV(value);
    auto& t = g.geometry.triangles;
    t.sType = VK_STRUCTURE_TYPE_GEOMETRY_TRIANGLES_NV;
    t.vertexData = handle<VkBuffer>(value ^ 1);
    t.vertexOffset = value ^ 2;
    t.vertexCount = uint32_t(value ^ 3);
    t.vertexStride = value ^ 4;
    set_enum_bits(t.vertexFormat, uint32_t(value ^ 5));
    t.indexData = handle<VkBuffer>(value ^ 6);
    t.indexOffset = value ^ 7;
    t.indexCount = uint32_t(value ^ 8);
    set_enum_bits(t.indexType, uint32_t(value ^ 9));
    t.transformData = handle<VkBuffer>(value ^ 10);
    t.transformOffset = value ^ 11;
    auto& a = g.geometry.aabbs;
    a.sType = VK_STRUCTURE_TYPE_GEOMETRY_AABB_NV;
    a.aabbData = handle<VkBuffer>(value ^ 12);
    a.numAABBs = uint32_t(value ^ 13);
    a.stride = uint32_t(value ^ 14);
    a.offset = value ^ 15;
    return g;
}

void expect_equal(const VkGeometryNV& a, const VkGeometryNV& b) {
    EXPECT_EQ(a.sType, b.sType);
    EXPECT_EQ(a.pNext, nullptr);
    EXPECT_EQ(enum_bits(a.geometryType), enum_bits(b.geometryType));
    EXPECT_EQ(a.flags, b.flags);
    const auto &s = a.geometry.triangles, &t = b.geometry.triangles;
    EXPECT_EQ(s.sType, t.sType);
    EXPECT_EQ(s.vertexData, t.vertexData);
    EXPECT_EQ(s.vertexOffset, t.vertexOffset);
    EXPECT_EQ(s.vertexCount, t.vertexCount);
    EXPECT_EQ(s.vertexStride, t.vertexStride);
    EXPECT_EQ(enum_bits(s.vertexFormat), enum_bits(t.vertexFormat));
    EXPECT_EQ(s.indexData, t.indexData);
    EXPECT_EQ(s.indexOffset, t.indexOffset);
    EXPECT_EQ(s.indexCount, t.indexCount);
    EXPECT_EQ(enum_bits(s.indexType), enum_bits(t.indexType));
    EXPECT_EQ(s.transformData, t.transformData);
    EXPECT_EQ(s.transformOffset, t.transformOffset);
    const auto &x = a.geometry.aabbs, &y = b.geometry.aabbs;
    EXPECT_EQ(x.sType, y.sType);
    EXPECT_EQ(x.aabbData, y.aabbData);
    EXPECT_EQ(x.numAABBs, y.numAABBs);
    EXPECT_EQ(x.stride, y.stride);
    EXPECT_EQ(x.offset, y.offset);
}

TEST(NvConversions, GeometryRoundTripsBothMembersWhateverItsType) {
    for (auto type : {VK_GEOMETRY_TYPE_TRIANGLES_NV, VK_GEOMETRY_TYPE_AABBS_NV})
        for (uint64_t value : {uint64_t(0), uint64_t(0xabcdef), kMax64}) {
            SCOPED_TRACE(testing::Message() << "type " << type << ", value " << value);
            const VkGeometryNV in = geometry(type, value);
            flatbuffers::FlatBufferBuilder fbb;
            expect_equal(nv_geometry_from_record(
                             packed<fbs::GeometryNV>(*nv_geometry_to_record(in), fbb)),
                         in);
        }
}

TEST(NvConversions, InfoRoundTripsWithNoneOrSeveralGeometries) {
    const std::vector<VkGeometryNV> several = {geometry(VK_GEOMETRY_TYPE_TRIANGLES_NV, 1),
                                               geometry(VK_GEOMETRY_TYPE_AABBS_NV, kMax64),
                                               geometry(VK_GEOMETRY_TYPE_TRIANGLES_NV, 0)};
    for (const auto& geometries : {std::vector<VkGeometryNV>{}, several}) {
        VkAccelerationStructureInfoNV in{};
        in.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_INFO_NV;
        in.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV;
        in.flags = kMax32;
        in.instanceCount = geometries.empty() ? kMax32 : 0;
        in.geometryCount = uint32_t(geometries.size());
        in.pGeometries = geometries.empty() ? nullptr : geometries.data();
        flatbuffers::FlatBufferBuilder fbb;
        std::vector<VkGeometryNV> decoded;
        const auto out = nv_info_from_record(
            packed<fbs::AccelerationStructureInfoNV>(*nv_info_to_record(in), fbb), decoded);
        EXPECT_EQ(out.sType, in.sType);
        EXPECT_EQ(out.pNext, nullptr);
        EXPECT_EQ(out.type, in.type);
        EXPECT_EQ(out.flags, in.flags);
        EXPECT_EQ(out.instanceCount, in.instanceCount);
        ASSERT_EQ(out.geometryCount, in.geometryCount);
        EXPECT_EQ(out.pGeometries, geometries.empty() ? nullptr : decoded.data());
        for (uint32_t g = 0; g < out.geometryCount; ++g)
            expect_equal(out.pGeometries[g], in.pGeometries[g]);
    }
}

}  // namespace
}  // namespace clastrace::traces

// SPDX-License-Identifier: Apache-2.0
#include <clastrace/traces/khr_conversions.h>

#include "vk_handle_record.h"

#include <clastrace/common/enum_bits.h>

#include <cstdint>

namespace clastrace::traces {

namespace {

using common::enum_bits;
using common::set_enum_bits;
using detail::handle_from_record;
using detail::handle_to_record;

std::vector<uint32_t> next_stypes(const void* next) {
    std::vector<uint32_t> stypes;
    for (auto* s = static_cast<const VkBaseInStructure*>(next); s; s = s->pNext)
        stypes.push_back(enum_bits(s->sType));
    return stypes;
}

VkAccelerationStructureGeometryTrianglesDataKHR triangles_from_record(
    const fbs::GeometryTrianglesKHR* t) {
    VkAccelerationStructureGeometryTrianglesDataKHR out{};
    out.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_TRIANGLES_DATA_KHR;
    if (!t) return out;
    set_enum_bits(out.vertexFormat, t->vertex_format());
    out.vertexData.deviceAddress = t->vertex_data();
    out.vertexStride = t->vertex_stride();
    out.maxVertex = t->max_vertex();
    set_enum_bits(out.indexType, t->index_type());
    out.indexData.deviceAddress = t->index_data();
    out.transformData.deviceAddress = t->transform_data();
    return out;
}

}  // namespace

std::unique_ptr<fbs::GeometryKHRT> khr_geometry_to_record(
    const VkAccelerationStructureGeometryKHR& geometry) {
    auto out = std::make_unique<fbs::GeometryKHRT>();
    out->geometry_type = enum_bits(geometry.geometryType);
    out->flags = geometry.flags;
    const auto& t = geometry.geometry.triangles;
    out->triangles = std::make_unique<fbs::GeometryTrianglesKHR>(
        enum_bits(t.vertexFormat), t.vertexData.deviceAddress, t.vertexStride, t.maxVertex,
        enum_bits(t.indexType), t.indexData.deviceAddress, t.transformData.deviceAddress);
    const auto& a = geometry.geometry.aabbs;
    out->aabbs = std::make_unique<fbs::GeometryAabbsKHR>(a.data.deviceAddress, a.stride);
    const auto& i = geometry.geometry.instances;
    out->instances = std::make_unique<fbs::GeometryInstancesKHR>(i.arrayOfPointers != VK_FALSE,
                                                                 i.data.deviceAddress);
    return out;
}

VkAccelerationStructureGeometryKHR khr_geometry_from_record(const fbs::GeometryKHR& record) {
    VkAccelerationStructureGeometryKHR out{};
    out.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_KHR;
    set_enum_bits(out.geometryType, record.geometry_type());
    out.flags = record.flags();
    switch (record.geometry_type()) {
    case VK_GEOMETRY_TYPE_TRIANGLES_KHR:
        out.geometry.triangles = triangles_from_record(record.triangles());
        break;
    case VK_GEOMETRY_TYPE_AABBS_KHR:
        out.geometry.aabbs.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_AABBS_DATA_KHR;
        if (const auto* a = record.aabbs()) {
            out.geometry.aabbs.data.deviceAddress = a->data();
            out.geometry.aabbs.stride = a->stride();
        }
        break;
    case VK_GEOMETRY_TYPE_INSTANCES_KHR:
        out.geometry.instances.sType =
            VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_GEOMETRY_INSTANCES_DATA_KHR;
        if (const auto* i = record.instances()) {
            out.geometry.instances.arrayOfPointers = i->array_of_pointers() ? VK_TRUE : VK_FALSE;
            out.geometry.instances.data.deviceAddress = i->data();
        }
        break;
    default: break;
    }
    return out;
}

fbs::BuildRangeInfoKHR khr_range_to_record(const VkAccelerationStructureBuildRangeInfoKHR& range) {
    return fbs::BuildRangeInfoKHR(range.primitiveCount, range.primitiveOffset, range.firstVertex,
                                  range.transformOffset);
}

VkAccelerationStructureBuildRangeInfoKHR khr_range_from_record(
    const fbs::BuildRangeInfoKHR& range) {
    return {range.primitive_count(), range.primitive_offset(), range.first_vertex(),
            range.transform_offset()};
}

std::unique_ptr<fbs::AccelerationStructureBuildInfoKHRT> khr_build_info_to_record(
    const VkAccelerationStructureBuildGeometryInfoKHR& info,
    const VkAccelerationStructureBuildRangeInfoKHR* ranges) {
    auto out = std::make_unique<fbs::AccelerationStructureBuildInfoKHRT>();
    out->type = enum_bits(info.type);
    out->flags = info.flags;
    out->mode = enum_bits(info.mode);
    out->src = handle_to_record(info.srcAccelerationStructure);
    out->dst = handle_to_record(info.dstAccelerationStructure);
    for (uint32_t g = 0; g < info.geometryCount; ++g) {
        const VkAccelerationStructureGeometryKHR* geometry =
            info.pGeometries ? &info.pGeometries[g] : info.ppGeometries[g];
        out->geometries.push_back(khr_geometry_to_record(*geometry));
        if (ranges) out->ranges.push_back(khr_range_to_record(ranges[g]));
    }
    out->scratch_address = info.scratchData.deviceAddress;
    out->unrecorded_next_stypes = next_stypes(info.pNext);
    return out;
}

VkAccelerationStructureBuildGeometryInfoKHR khr_build_info_from_record(
    const fbs::AccelerationStructureBuildInfoKHR& record,
    std::vector<VkAccelerationStructureGeometryKHR>& geometries,
    std::vector<VkAccelerationStructureBuildRangeInfoKHR>& ranges) {
    geometries.clear();
    ranges.clear();
    if (const auto* list = record.geometries())
        for (const fbs::GeometryKHR* g : *list)
            if (g) geometries.push_back(khr_geometry_from_record(*g));
    if (const auto* list = record.ranges())
        for (const fbs::BuildRangeInfoKHR* r : *list) ranges.push_back(khr_range_from_record(*r));
    VkAccelerationStructureBuildGeometryInfoKHR out{};
    out.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_BUILD_GEOMETRY_INFO_KHR;
    set_enum_bits(out.type, record.type());
    out.flags = record.flags();
    set_enum_bits(out.mode, record.mode());
    out.srcAccelerationStructure = handle_from_record<VkAccelerationStructureKHR>(record.src());
    out.dstAccelerationStructure = handle_from_record<VkAccelerationStructureKHR>(record.dst());
    out.geometryCount = uint32_t(geometries.size());
    out.pGeometries = geometries.data();
    out.scratchData.deviceAddress = record.scratch_address();
    return out;
}

}  // namespace clastrace::traces

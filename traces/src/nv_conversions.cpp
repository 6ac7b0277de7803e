// SPDX-License-Identifier: Apache-2.0
#include <clastrace/traces/nv_conversions.h>

#include "vk_handle_record.h"

#include <clastrace/common/enum_bits.h>

#include <cstdint>
#include <type_traits>

namespace clastrace::traces {

namespace {

using common::enum_bits;
using common::set_enum_bits;
using detail::handle_from_record;
using detail::handle_to_record;

VkGeometryTrianglesNV triangles_from_record(const fbs::GeometryTrianglesNV* t) {
    VkGeometryTrianglesNV out{};
    out.sType = VK_STRUCTURE_TYPE_GEOMETRY_TRIANGLES_NV;
    if (!t) return out;
    out.vertexData = handle_from_record<VkBuffer>(t->vertex_data());
    out.vertexOffset = t->vertex_offset();
    out.vertexCount = t->vertex_count();
    out.vertexStride = t->vertex_stride();
    set_enum_bits(out.vertexFormat, t->vertex_format());
    out.indexData = handle_from_record<VkBuffer>(t->index_data());
    out.indexOffset = t->index_offset();
    out.indexCount = t->index_count();
    set_enum_bits(out.indexType, t->index_type());
    out.transformData = handle_from_record<VkBuffer>(t->transform_data());
    out.transformOffset = t->transform_offset();
    return out;
}

VkGeometryAABBNV aabbs_from_record(const fbs::GeometryAabbNV* a) {
    VkGeometryAABBNV out{};
    out.sType = VK_STRUCTURE_TYPE_GEOMETRY_AABB_NV;
    if (!a) return out;
    out.aabbData = handle_from_record<VkBuffer>(a->aabb_data());
    out.numAABBs = a->num_aabbs();
    out.stride = a->stride();
    out.offset = a->offset();
    return out;
}

}  // namespace

std::unique_ptr<fbs::GeometryNVT> nv_geometry_to_record(const VkGeometryNV& geometry) {
    auto out = std::make_unique<fbs::GeometryNVT>();
    out->geometry_type = enum_bits(geometry.geometryType);
    out->flags = geometry.flags;
    const VkGeometryTrianglesNV& t = geometry.geometry.triangles;
    out->triangles = std::make_unique<fbs::GeometryTrianglesNV>(
        handle_to_record(t.vertexData), t.vertexOffset, t.vertexCount, enum_bits(t.vertexFormat),
        t.vertexStride, handle_to_record(t.indexData), t.indexOffset, t.indexCount,
        enum_bits(t.indexType), handle_to_record(t.transformData), t.transformOffset);
    const VkGeometryAABBNV& a = geometry.geometry.aabbs;
    out->aabbs = std::make_unique<fbs::GeometryAabbNV>(handle_to_record(a.aabbData), a.numAABBs,
                                                       a.stride, a.offset);
    return out;
}

VkGeometryNV nv_geometry_from_record(const fbs::GeometryNV& record) {
    VkGeometryNV out{};
    out.sType = VK_STRUCTURE_TYPE_GEOMETRY_NV;
    set_enum_bits(out.geometryType, record.geometry_type());
    out.flags = record.flags();
    out.geometry.triangles = triangles_from_record(record.triangles());
    out.geometry.aabbs = aabbs_from_record(record.aabbs());
    return out;
}

std::unique_ptr<fbs::AccelerationStructureInfoNVT> nv_info_to_record(
    const VkAccelerationStructureInfoNV& info) {
    auto out = std::make_unique<fbs::AccelerationStructureInfoNVT>();
    out->type = enum_bits(info.type);
    out->flags = info.flags;
    out->instance_count = info.instanceCount;
    for (uint32_t g = 0; g < info.geometryCount; ++g)
        out->geometries.push_back(nv_geometry_to_record(info.pGeometries[g]));
    return out;
}

VkAccelerationStructureInfoNV nv_info_from_record(const fbs::AccelerationStructureInfoNV& record,
                                                  std::vector<VkGeometryNV>& geometries) {
    geometries.clear();
    if (const auto* list = record.geometries())
        for (const fbs::GeometryNV* g : *list)
            if (g) geometries.push_back(nv_geometry_from_record(*g));
    VkAccelerationStructureInfoNV out{};
    out.sType = VK_STRUCTURE_TYPE_ACCELERATION_STRUCTURE_INFO_NV;
    set_enum_bits(out.type, record.type());
    out.flags = record.flags();
    out.instanceCount = record.instance_count();
    out.geometryCount = uint32_t(geometries.size());
    out.pGeometries = geometries.empty() ? nullptr : geometries.data();
    return out;
}

}  // namespace clastrace::traces

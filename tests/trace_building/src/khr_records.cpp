// SPDX-License-Identifier: Apache-2.0
#include "clastrace/trace_building/khr_records.h"

#include <cstring>

namespace clastrace::trace_building {

fbs::AccelerationStructureCreateT khr_acceleration_structure_create(
    uint64_t handle, VkAccelerationStructureTypeKHR type, uint64_t buffer, uint64_t offset,
    uint64_t size, uint64_t device_address) {
    fbs::AccelerationStructureCreateT c;
    c.acceleration_structure = handle;
    c.api = 1;
    c.type = type;
    c.buffer = buffer;
    c.offset = offset;
    c.size = size;
    c.device_address = device_address;
    return c;
}

namespace {

std::unique_ptr<fbs::GeometryKHRT> geometry_record(const engine::KhrGeometry& g) {
    auto out = std::make_unique<fbs::GeometryKHRT>();
    out->geometry_type = g.type;
    out->flags = g.flags;
    const engine::KhrTriangles& t = g.triangles;
    out->triangles =
        std::make_unique<fbs::GeometryTrianglesKHR>(uint32_t(t.vertex_format), t.vertex_data,
                                                    t.vertex_stride, t.max_vertex,
                                                    uint32_t(t.index_type), t.index_data,
                                                    t.transform_data);
    out->aabbs = std::make_unique<fbs::GeometryAabbsKHR>(g.aabbs.data, g.aabbs.stride);
    out->instances = std::make_unique<fbs::GeometryInstancesKHR>(g.instances.array_of_pointers,
                                                                 g.instances.data);
    return out;
}

}  // namespace

fbs::AccelerationStructureBuildInfoKHRT khr_build_info(const engine::KhrBuildInfo& info) {
    fbs::AccelerationStructureBuildInfoKHRT out;
    out.type = info.type;
    out.flags = info.flags;
    out.mode = info.mode;
    out.src = info.src.handle;
    out.dst = info.dst.handle;
    for (const engine::KhrGeometry& g : info.geometries)
        out.geometries.push_back(geometry_record(g));
    out.scratch_address = info.scratch_address;
    for (const engine::KhrBuildRange& r : info.ranges)
        out.ranges.emplace_back(r.primitive_count, r.primitive_offset, r.first_vertex,
                                r.transform_offset);
    return out;
}

fbs::CmdBuildAccelerationStructuresKHRT khr_build(uint64_t command_buffer,
                                                  const engine::KhrBuildCommand& command) {
    fbs::CmdBuildAccelerationStructuresKHRT b;
    b.command_buffer = command_buffer;
    for (const engine::KhrBuildInfo& info : command.infos)
        b.infos.push_back(
            std::make_unique<fbs::AccelerationStructureBuildInfoKHRT>(khr_build_info(info)));
    return b;
}

fbs::CmdCopyAccelerationStructureT acceleration_structure_copy(uint64_t command_buffer, uint8_t api,
                                                               uint64_t src, uint64_t dst,
                                                               uint32_t mode) {
    fbs::CmdCopyAccelerationStructureT c;
    c.command_buffer = command_buffer;
    c.api = api;
    c.src = src;
    c.dst = dst;
    c.mode = mode;
    return c;
}

fbs::CmdCopyAccelerationStructureToMemoryT acceleration_structure_serialize(uint64_t command_buffer,
                                                                            uint64_t src,
                                                                            uint64_t dst_address) {
    fbs::CmdCopyAccelerationStructureToMemoryT c;
    c.command_buffer = command_buffer;
    c.src = src;
    c.dst_address = dst_address;
    c.mode = VK_COPY_ACCELERATION_STRUCTURE_MODE_SERIALIZE_KHR;
    return c;
}

fbs::CmdWriteAccelerationStructuresPropertiesT acceleration_structure_properties(
    uint64_t command_buffer, uint8_t api, std::vector<uint64_t> structures, uint32_t query_type,
    uint64_t query_pool, uint32_t first_query) {
    fbs::CmdWriteAccelerationStructuresPropertiesT q;
    q.command_buffer = command_buffer;
    q.api = api;
    q.acceleration_structures = std::move(structures);
    q.query_type = query_type;
    q.query_pool = query_pool;
    q.first_query = first_query;
    return q;
}

fbs::QueryPoolResultsT query_pool_results(uint64_t query_pool, uint32_t first_query,
                                          std::vector<uint64_t> values) {
    fbs::QueryPoolResultsT r;
    r.query_pool = query_pool;
    r.first_query = first_query;
    r.values = std::move(values);
    r.result = VK_SUCCESS;
    return r;
}

std::array<uint8_t, 64> instance_bytes(const std::array<float, 12>& transform,
                                       uint32_t custom_index, uint8_t mask, uint32_t sbt_offset,
                                       uint8_t flags, uint64_t reference) {
    std::array<uint8_t, 64> out{};
    std::memcpy(out.data(), transform.data(), 48);
    const uint32_t custom_and_mask = (custom_index & 0xFFFFFFu) | (uint32_t(mask) << 24);
    const uint32_t sbt_and_flags = (sbt_offset & 0xFFFFFFu) | (uint32_t(flags) << 24);
    std::memcpy(out.data() + 48, &custom_and_mask, 4);
    std::memcpy(out.data() + 52, &sbt_and_flags, 4);
    std::memcpy(out.data() + 56, &reference, 8);
    return out;
}

}  // namespace clastrace::trace_building

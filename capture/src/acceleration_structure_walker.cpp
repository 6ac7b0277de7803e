// SPDX-License-Identifier: Apache-2.0
#include "clastrace/capture/acceleration_structure_walker.h"
#include "clastrace/engine/vertex_format.h"

#include <cstring>

namespace clastrace::capture {
namespace {

struct BufferWalker {
    const BufferMemoryReader& read;
    ClusterMemoryWalk& out;
    uint64_t total = 0;

    void capture(MemoryRole role, uint32_t entry, uint64_t buffer, VkDeviceSize offset,
                 uint64_t size) {
        if (buffer == 0 || size == 0) return;
        CapturedRange range{role, entry, 0, {}, buffer, offset};
        std::string why;
        if (!read(buffer, offset, size, nullptr, why)) {
            out.issues.push_back({0, size,
                                  std::string(memory_role_name(role)) + " of geometry " +
                                      std::to_string(entry) + ": " + why});
            return;
        }
        if (total + size > kMaxCapturedBytesPerCommand) {
            out.issues.push_back({0, size,
                                  "the ranges this command references exceed the capture's "
                                  "per-command limit of 1 GiB"});
            return;
        }
        if (!read(buffer, offset, size, &range.bytes, why)) return;
        total += size;
        out.ranges.push_back(std::move(range));
    }
    // Element i at offset + i * stride, `element` bytes each: the span from the first to the last.
    void capture_strided(MemoryRole role, uint32_t entry, uint64_t buffer, VkDeviceSize offset,
                         uint64_t count, uint64_t stride, uint64_t element) {
        if (count == 0) return;
        if (stride == 0) stride = element;
        if (count > (UINT64_MAX - element) / stride) {
            out.issues.push_back(
                {0, 0, std::string(memory_role_name(role)) + ": element count overflows"});
            return;
        }
        capture(role, entry, buffer, offset, (count - 1) * stride + element);
    }
};

}  // namespace

ClusterMemoryWalk walk_build_acceleration_structure_nv_inputs(
    const BuildAccelerationStructureNVCommand& c, const BufferMemoryReader& read) {
    ClusterMemoryWalk out;
    BufferWalker walker{read, out};
    for (uint32_t g = 0; g < c.geometries.size(); ++g) {
        const VkGeometryNV& geometry = c.geometries[g];
        if (geometry.geometryType == VK_GEOMETRY_TYPE_TRIANGLES_NV) {
            const VkGeometryTrianglesNV& t = geometry.geometry.triangles;
            const uint32_t vb = engine::vertex_format_bytes(t.vertexFormat);
            if (vb == 0)
                out.issues.push_back({0, 0,
                                      "vertexFormat " + std::to_string(int(t.vertexFormat)) +
                                          " of geometry " + std::to_string(g) +
                                          " has no known size; vertices not captured"});
            else
                walker.capture_strided(MemoryRole::kVertexBuffer, g, uint64_t(t.vertexData),
                                       t.vertexOffset, t.vertexCount, t.vertexStride, vb);
            if (const uint32_t ib = engine::index_type_bytes(t.indexType))
                walker.capture(MemoryRole::kIndexBuffer, g, uint64_t(t.indexData), t.indexOffset,
                               uint64_t(t.indexCount) * ib);
            walker.capture(MemoryRole::kTransformData, g, uint64_t(t.transformData),
                           t.transformOffset, 12 * sizeof(float));
        } else if (geometry.geometryType == VK_GEOMETRY_TYPE_AABBS_NV) {
            const VkGeometryAABBNV& a = geometry.geometry.aabbs;
            walker.capture_strided(MemoryRole::kAabbs, g, uint64_t(a.aabbData), a.offset,
                                   a.numAABBs, a.stride, 6 * sizeof(float));
        }
    }
    // VkAccelerationStructureInstanceNV is 64 bytes, packed.
    if (c.type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV)
        walker.capture(MemoryRole::kInstances, 0, c.instance_data, c.instance_offset,
                       uint64_t(c.instance_count) * 64);
    out.executed_count = uint32_t(c.geometries.size());
    return out;
}

ClusterMemoryWalk walk_copy_memory_to_acceleration_structure_inputs(
    const CopyMemoryToAccelerationStructureCommand& c, const DeviceMemoryReader& read) {
    ClusterMemoryWalk out;
    constexpr uint64_t kSizeOffset = 2 * VK_UUID_SIZE;
    CapturedBytes header;
    std::string why;
    if (!read(c.src, kSizeOffset + 8, &header, why)) {
        out.issues.push_back(
            {c.src, kSizeOffset + 8, "serialized acceleration structure header: " + why});
        return out;
    }
    uint64_t total;
    std::memcpy(&total, header.data() + kSizeOffset, 8);
    if (total < kSizeOffset + 8 || total > kMaxCapturedBytesPerCommand) {
        out.issues.push_back({c.src, total,
                              "serialized acceleration structure claims " + std::to_string(total) +
                                  " bytes; only its header was captured"});
        out.ranges.push_back(
            {MemoryRole::kSerializedAccelerationStructure, 0, c.src, std::move(header)});
        return out;
    }
    CapturedRange range{MemoryRole::kSerializedAccelerationStructure, 0, c.src, {}};
    if (!read(c.src, total, &range.bytes, why)) {
        out.issues.push_back({c.src, total, "serialized acceleration structure: " + why});
        out.ranges.push_back(
            {MemoryRole::kSerializedAccelerationStructure, 0, c.src, std::move(header)});
        return out;
    }
    out.ranges.push_back(std::move(range));
    out.executed_count = 1;
    return out;
}

}  // namespace clastrace::capture

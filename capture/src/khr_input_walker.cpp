// SPDX-License-Identifier: Apache-2.0
#include "clastrace/capture/khr_input_walker.h"
#include "clastrace/engine/vertex_format.h"

#include <cstring>

namespace clastrace::capture {

bool khr_ranges_from_indirect_bytes(const uint8_t* bytes, uint64_t size, uint32_t geometry_count,
                                    uint32_t stride,
                                    std::vector<VkAccelerationStructureBuildRangeInfoKHR>& out,
                                    std::string& why) {
    out.clear();
    if (geometry_count == 0) return true;
    const uint64_t step = stride ? stride : kKhrBuildRangeBytes;
    const uint64_t needed = (uint64_t(geometry_count) - 1) * step + kKhrBuildRangeBytes;
    if (size < needed) {
        why = std::to_string(geometry_count) + " build ranges at stride " + std::to_string(step) +
              " need " + std::to_string(needed) + " bytes; " + std::to_string(size) + " were read";
        return false;
    }
    for (uint32_t g = 0; g < geometry_count; ++g) {
        VkAccelerationStructureBuildRangeInfoKHR range;
        std::memcpy(&range, bytes + g * step, sizeof range);
        out.push_back(range);
    }
    return true;
}

namespace {

// Reads ranges by device address (and source structures by buffer), within the per-command limit.
struct KhrWalker {
    const DeviceMemoryReader& read;
    const BufferMemoryReader& read_buffer;
    ClusterMemoryWalk& out;
    uint64_t total = 0;

    bool within_limit(uint64_t size) {
        if (total + size <= kMaxCapturedBytesPerCommand) return true;
        out.issues.push_back({0, size,
                              "the ranges this command references exceed the capture's "
                              "per-command limit of 1 GiB"});
        return false;
    }
    const CapturedRange* capture(MemoryRole role, uint32_t entry, VkDeviceAddress address,
                                 uint64_t size) {
        if (address == 0 || size == 0) return nullptr;
        std::string why;
        CapturedRange range{role, entry, address, {}};
        if (!within_limit(size)) return nullptr;
        if (!read(address, size, &range.bytes, why)) {
            out.issues.push_back({address, size,
                                  std::string(memory_role_name(role)) + " of geometry " +
                                      std::to_string(entry) + ": " + why});
            return nullptr;
        }
        total += size;
        out.ranges.push_back(std::move(range));
        return &out.ranges.back();
    }
    void capture_storage(uint32_t entry, const KhrStructureStorage& s) {
        if (s.acceleration_structure == 0) return;
        if (s.buffer == 0 || s.size == 0) {
            out.issues.push_back({0, 0,
                                  "source acceleration structure " +
                                      std::to_string(s.acceleration_structure) +
                                      " was created before capture: its storage is unknown"});
            return;
        }
        CapturedRange range{
            MemoryRole::kSourceAccelerationStructure, entry, 0, {}, s.buffer, s.offset};
        std::string why;
        if (!within_limit(s.size)) return;
        if (!read_buffer(s.buffer, s.offset, s.size, &range.bytes, why)) {
            out.issues.push_back({0, s.size, "source acceleration structure: " + why});
            return;
        }
        total += s.size;
        out.ranges.push_back(std::move(range));
    }
    void triangles(uint32_t entry, const VkAccelerationStructureGeometryTrianglesDataKHR& t,
                   const VkAccelerationStructureBuildRangeInfoKHR& r);
    void instances(uint32_t entry, const VkAccelerationStructureGeometryInstancesDataKHR& i,
                   const VkAccelerationStructureBuildRangeInfoKHR& r);
};

// Indexed: the indices at indexData + primitiveOffset name vertices firstVertex + [0, maxVertex].
// Not indexed: 3 * primitiveCount vertices from vertexData + primitiveOffset + firstVertex * stride.
void KhrWalker::triangles(uint32_t entry, const VkAccelerationStructureGeometryTrianglesDataKHR& t,
                          const VkAccelerationStructureBuildRangeInfoKHR& r) {
    if (r.primitiveCount == 0) return;
    const uint64_t element = engine::vertex_format_bytes(t.vertexFormat);
    const uint64_t stride = t.vertexStride ? t.vertexStride : element;
    if (element == 0) {
        out.issues.push_back({t.vertexData.deviceAddress, 0,
                              "vertexFormat " + std::to_string(int(t.vertexFormat)) +
                                  " of geometry " + std::to_string(entry) +
                                  " has no known size; vertices not captured"});
    } else if (const uint32_t ib = engine::index_type_bytes(t.indexType)) {
        capture(MemoryRole::kIndexBuffer, entry, t.indexData.deviceAddress + r.primitiveOffset,
                uint64_t(r.primitiveCount) * 3 * ib);
        capture(MemoryRole::kVertexBuffer, entry,
                t.vertexData.deviceAddress + uint64_t(r.firstVertex) * stride,
                uint64_t(t.maxVertex) * stride + element);
    } else {
        capture(MemoryRole::kVertexBuffer, entry,
                t.vertexData.deviceAddress + r.primitiveOffset + uint64_t(r.firstVertex) * stride,
                (uint64_t(r.primitiveCount) * 3 - 1) * stride + element);
    }
    if (t.transformData.deviceAddress)
        capture(MemoryRole::kTransformData, entry,
                t.transformData.deviceAddress + r.transformOffset, sizeof(VkTransformMatrixKHR));
}

// Packed: primitiveCount instances at data + primitiveOffset. Array of pointers: that many
// addresses there, and the instance each names.
void KhrWalker::instances(uint32_t entry, const VkAccelerationStructureGeometryInstancesDataKHR& i,
                          const VkAccelerationStructureBuildRangeInfoKHR& r) {
    if (r.primitiveCount == 0) return;
    const VkDeviceAddress at = i.data.deviceAddress + r.primitiveOffset;
    if (!i.arrayOfPointers) {
        capture(MemoryRole::kInstances, entry, at, uint64_t(r.primitiveCount) * kKhrInstanceBytes);
        return;
    }
    const CapturedRange* pointers =
        capture(MemoryRole::kInstancePointers, entry, at, uint64_t(r.primitiveCount) * 8);
    if (!pointers) return;
    std::vector<VkDeviceAddress> addresses(r.primitiveCount);
    std::memcpy(addresses.data(), pointers->bytes.data(), addresses.size() * 8);
    for (VkDeviceAddress address : addresses)
        capture(MemoryRole::kInstances, entry, address, kKhrInstanceBytes);
}

// The ranges an indirect build read at execution, or false (the issue said why).
bool read_indirect_ranges(KhrWalker& walker, const KhrBuildInfo& info, uint32_t entry,
                          std::vector<VkAccelerationStructureBuildRangeInfoKHR>& ranges) {
    const uint32_t count = uint32_t(info.geometries.size());
    if (count == 0) return true;
    const uint64_t step = info.indirect_stride ? info.indirect_stride : kKhrBuildRangeBytes;
    const CapturedRange* bytes =
        walker.capture(MemoryRole::kBuildRanges, entry, info.indirect_address,
                       (count - 1) * step + kKhrBuildRangeBytes);
    if (!bytes) return false;
    std::string why;
    if (khr_ranges_from_indirect_bytes(bytes->bytes.data(), bytes->bytes.size(), count,
                                       info.indirect_stride, ranges, why))
        return true;
    walker.out.issues.push_back({info.indirect_address, bytes->bytes.size(), why});
    return false;
}

}  // namespace

ClusterMemoryWalk walk_build_acceleration_structures_khr_inputs(
    const BuildAccelerationStructuresKHRCommand& command, const DeviceMemoryReader& read,
    const BufferMemoryReader& read_buffer,
    std::vector<std::vector<VkAccelerationStructureBuildRangeInfoKHR>>& indirect_ranges) {
    ClusterMemoryWalk out;
    KhrWalker walker{read, read_buffer, out};
    indirect_ranges.assign(command.indirect ? command.infos.size() : 0, {});
    for (uint32_t n = 0; n < command.infos.size(); ++n) {
        const KhrBuildInfo& info = command.infos[n];
        const std::vector<VkAccelerationStructureBuildRangeInfoKHR>* ranges = &info.ranges;
        if (command.indirect) {
            if (!read_indirect_ranges(walker, info, n, indirect_ranges[n])) continue;
            ranges = &indirect_ranges[n];
        }
        for (uint32_t g = 0; g < info.geometries.size() && g < ranges->size(); ++g) {
            const VkAccelerationStructureGeometryKHR& geometry = info.geometries[g];
            const VkAccelerationStructureBuildRangeInfoKHR& range = (*ranges)[g];
            switch (geometry.geometryType) {
            case VK_GEOMETRY_TYPE_TRIANGLES_KHR:
                walker.triangles(g, geometry.geometry.triangles, range);
                break;
            case VK_GEOMETRY_TYPE_AABBS_KHR: {
                const auto& a = geometry.geometry.aabbs;
                const uint64_t stride = a.stride ? a.stride : sizeof(VkAabbPositionsKHR);
                if (range.primitiveCount)
                    walker.capture(MemoryRole::kAabbs, g,
                                   a.data.deviceAddress + range.primitiveOffset,
                                   (uint64_t(range.primitiveCount) - 1) * stride +
                                       sizeof(VkAabbPositionsKHR));
                break;
            }
            case VK_GEOMETRY_TYPE_INSTANCES_KHR:
                walker.instances(g, geometry.geometry.instances, range);
                break;
            default: break;
            }
        }
        if (info.info.mode == VK_BUILD_ACCELERATION_STRUCTURE_MODE_UPDATE_KHR)
            walker.capture_storage(n, info.update_source);
    }
    out.executed_count = uint32_t(command.infos.size());
    return out;
}

ClusterMemoryWalk walk_copy_acceleration_structure_inputs(
    const CopyAccelerationStructureCommand& command, const BufferMemoryReader& read_buffer) {
    ClusterMemoryWalk out;
    DeviceMemoryReader no_addresses = [](VkDeviceAddress, uint64_t, CapturedBytes*,
                                         std::string& why) {
        why = "not read";
        return false;
    };
    KhrWalker walker{no_addresses, read_buffer, out};
    if (command.khr) walker.capture_storage(0, command.source);
    out.executed_count = 1;
    return out;
}

}  // namespace clastrace::capture

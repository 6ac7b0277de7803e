// SPDX-License-Identifier: Apache-2.0
#include "clastrace/capture/cluster_input_walker.h"
#include "clastrace/engine/vertex_format.h"

#include <cstring>

namespace clastrace::capture {
namespace {

using Info = VkClusterAccelerationStructureCommandsInfoNV;

uint32_t index_format_bytes(uint32_t index_type) {
    switch (index_type) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_8BIT_NV: return 1;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_16BIT_NV: return 2;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV: return 4;
    default: return 0;
    }
}

// Bytes spanned by `count` elements of `elementBytes` placed `stride` apart (0: packed).
uint64_t strided_span(uint64_t count, uint64_t stride, uint64_t element_bytes) {
    if (count == 0) return 0;
    if (stride == 0) stride = element_bytes;
    return (count - 1) * stride + element_bytes;
}

class Walker {
public:
    Walker(const DeviceMemoryReader& read, ClusterMemoryWalk& out) : read_(read), out_(out) {}

    bool capture(MemoryRole role, uint32_t entry, VkDeviceAddress address, uint64_t size) {
        if (size == 0) return true;
        CapturedRange range{role, entry, address, {}};
        std::string why;
        // Where the range is comes first (a garbage address is reported as such), its size second.
        if (!read_(address, size, nullptr, why)) {
            issue(address, size, std::string(memory_role_name(role)) + ": " + why);
            return false;
        }
        if (total_ + size > kMaxCapturedBytesPerCommand || total_ + size < total_) {
            issue(address, size,
                  "the ranges this command references exceed the capture's per-command limit of 1 "
                  "GiB");
            return false;
        }
        if (!read_(address, size, &range.bytes, why)) {
            issue(address, size, std::string(memory_role_name(role)) + ": " + why);
            return false;
        }
        total_ += size;
        out_.ranges.push_back(std::move(range));
        return true;
    }

    // Strided elements: packed strides are one range; sparse ones are one range per element, so
    // only bytes the command reads are captured.
    void capture_strided(MemoryRole role, uint32_t entry, VkDeviceAddress address, uint64_t count,
                         uint64_t stride, uint64_t element_bytes) {
        if (address == 0 || count == 0) return;
        if (stride == 0 || stride == element_bytes) {
            capture(role, entry, address, count * element_bytes);
            return;
        }
        if (stride < element_bytes) {  // overlapping elements: the union is contiguous
            capture(role, entry, address, strided_span(count, stride, element_bytes));
            return;
        }
        for (uint64_t i = 0; i < count; ++i)
            if (!capture(role, entry, address + i * stride, element_bytes)) return;
    }

    // captureStrided for arrays of little-endian 4- or 8-byte values, returning the values.
    std::vector<uint64_t> capture_strided_values(MemoryRole role, VkDeviceAddress address,
                                                 uint64_t count, uint64_t stride,
                                                 uint32_t element_bytes) {
        std::vector<uint64_t> values;
        const size_t before = out_.ranges.size();
        capture_strided(role, 0, address, count, stride, element_bytes);
        if (stride == 0) stride = element_bytes;
        auto value = [&](const uint8_t* bytes) {
            uint64_t v = 0;
            std::memcpy(&v, bytes, element_bytes);
            return v;
        };
        if (stride > element_bytes) {  // one range per element
            for (size_t r = before; r < out_.ranges.size(); ++r)
                values.push_back(value(out_.ranges[r].bytes.data()));
        } else if (out_.ranges.size() == before + 1) {  // one span
            const auto& bytes = out_.ranges[before].bytes;
            for (uint64_t i = 0; i < count; ++i) values.push_back(value(bytes.data() + i * stride));
        }
        return values;
    }

    ClusterMemoryWalk& result() { return out_; }

    const CapturedBytes* last_bytes() const {
        return out_.ranges.empty() ? nullptr : &out_.ranges.back().bytes;
    }

    void issue(VkDeviceAddress address, uint64_t size, std::string rule) {
        out_.issues.push_back({address, size, std::move(rule)});
    }

private:
    const DeviceMemoryReader& read_;
    ClusterMemoryWalk& out_;
    uint64_t total_ = 0;
};

// The triangle cluster info and its template variant share their first 64 bytes (the ABI
// header checks the offsets), so one reader serves both.
void follow_triangle_cluster(Walker& walker, uint32_t entry, const uint8_t* bytes, bool is_template,
                             const ClusterCommandParameters& p) {
    VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV info{};
    std::memcpy(&info, bytes,
                is_template ? sizeof(info)
                            : sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV));
    const uint32_t triangles = info.triangleCount;
    const uint32_t vertices = info.vertexCount;

    const uint32_t index_bytes = index_format_bytes(info.indexType);
    if (index_bytes == 0)
        walker.issue(
            info.indexBuffer, 0,
            std::string(
                is_template
                    ? "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-"
                      "indexType-10500"
                    : "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-indexType-"
                      "10491") +
                ": indexType " + std::to_string(info.indexType) + " of srcInfosArray entry " +
                std::to_string(entry) + " is not a single index format bit");
    else
        walker.capture_strided(MemoryRole::kIndexBuffer, entry, info.indexBuffer,
                               uint64_t(triangles) * 3, info.indexBufferStride, index_bytes);

    const uint32_t vertex_bytes =
        engine::vertex_format_bytes(p.triangle_cluster_input.vertexFormat);
    if (info.vertexBuffer != 0) {
        if (vertex_bytes == 0)
            walker.issue(info.vertexBuffer, 0,
                         "vertexFormat " +
                             std::to_string(int(p.triangle_cluster_input.vertexFormat)) +
                             " is not a format the layer knows the size of; vertices not captured");
        else
            walker.capture_strided(MemoryRole::kVertexBuffer, entry, info.vertexBuffer, vertices,
                                   info.vertexBufferStride, vertex_bytes);
    }
    walker.capture_strided(MemoryRole::kGeometryIndexAndFlags, entry,
                           info.geometryIndexAndFlagsBuffer, triangles,
                           info.geometryIndexAndFlagsBufferStride,
                           sizeof(VkClusterAccelerationStructureGeometryIndexAndGeometryFlagsNV));
    if (info.opacityMicromapIndexBuffer != 0) {
        const uint32_t omm_index_bytes = index_format_bytes(info.opacityMicromapIndexType);
        if (omm_index_bytes == 0)
            walker.issue(
                info.opacityMicromapIndexBuffer, 0,
                std::string(
                    is_template
                        ? "VUID-VkClusterAccelerationStructureBuildTriangleClusterTemplateInfoNV-"
                          "opacityMicromapIndexType-10501"
                        : "VUID-VkClusterAccelerationStructureBuildTriangleClusterInfoNV-"
                          "opacityMicromapIndexType-10492") +
                    ": opacityMicromapIndexType of srcInfosArray entry " + std::to_string(entry) +
                    " is not a single index format bit");
        else
            walker.capture_strided(MemoryRole::kOpacityMicromapIndices, entry,
                                   info.opacityMicromapIndexBuffer, triangles,
                                   info.opacityMicromapIndexBufferStride, omm_index_bytes);
    }
    if (is_template) walker.result().template_vertex_counts.push_back(vertices);
    if (is_template && info.instantiationBoundingBoxLimit != 0)
        walker.capture(MemoryRole::kInstantiationBoundingBox, entry,
                       info.instantiationBoundingBoxLimit, 6 * sizeof(float));
}

void follow_entry(Walker& walker, uint32_t entry, const uint8_t* bytes,
                  const ClusterCommandParameters& p,
                  const TemplateVertexCountLookup& template_vertex_count) {
    switch (p.info.input.opType) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV:
        follow_triangle_cluster(walker, entry, bytes, false, p);
        break;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV:
        follow_triangle_cluster(walker, entry, bytes, true, p);
        break;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV: {
        VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV info;
        std::memcpy(&info, bytes, sizeof info);
        walker.capture_strided(MemoryRole::kClusterReferences, entry, info.clusterReferences,
                               info.clusterReferencesCount, info.clusterReferencesStride,
                               sizeof(VkDeviceAddress));
        break;
    }
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV: {
        // The vertex array holds as many vertices as the template has, which only its build said.
        VkClusterAccelerationStructureInstantiateClusterInfoNV info;
        std::memcpy(&info, bytes, sizeof info);
        if (info.vertexBuffer.startAddress == 0) break;
        const uint32_t vertex_bytes =
            engine::vertex_format_bytes(p.triangle_cluster_input.vertexFormat);
        uint32_t vertices = 0;
        if (vertex_bytes == 0 || !template_vertex_count ||
            !template_vertex_count(info.clusterTemplateAddress, &vertices)) {
            walker.issue(info.vertexBuffer.startAddress, 0,
                         "vertexBuffer of srcInfosArray entry " + std::to_string(entry) +
                             " not captured: template " +
                             std::to_string(info.clusterTemplateAddress) +
                             " was not built under the layer");
            break;
        }
        walker.capture_strided(MemoryRole::kVertexBuffer, entry, info.vertexBuffer.startAddress,
                               vertices, info.vertexBuffer.strideInBytes, vertex_bytes);
        break;
    }
    // Move sources and templates are objects earlier builds wrote (captured as their outputs).
    default: break;
    }
}

// With an INDIRECTED_* flag the field holds the address of the value rather than the value.
// The layer reads the value there (and keeps those bytes) before following it.
bool resolve_indirect_address(Walker& walker, VkDeviceAddress& address) {
    if (address == 0) return true;
    if (!walker.capture(MemoryRole::kIndirectAddress, 0, address, sizeof(VkDeviceAddress)))
        return false;
    std::memcpy(&address, walker.last_bytes()->data(), sizeof address);
    return true;
}

// A strided region's cell holds its deviceAddress only; stride and size stay the command's
// (docs/spec-readings.md). Cells of fields the walk does not follow are captured too: replay
// reads them again. Returns dstSizesArray's address after its indirection (0 where the cell
// could not be read): explicit destinations read that array.
VkDeviceAddress capture_indirect_cells(Walker& walker, const Info& info) {
    const auto flags = info.addressResolutionFlags;
    const auto mode = info.input.opMode;
    VkDeviceAddress scratch = info.scratchData, implicit_data = info.dstImplicitData,
                    sizes = info.dstSizesArray.deviceAddress;
    if (flags & VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SCRATCH_DATA_BIT_NV)
        resolve_indirect_address(walker, scratch);
    if (mode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV &&
        (flags &
         VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_IMPLICIT_DATA_BIT_NV))
        resolve_indirect_address(walker, implicit_data);
    if (flags &
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_SIZES_ARRAY_BIT_NV)
        if (!resolve_indirect_address(walker, sizes)) sizes = 0;
    return sizes;
}

// dstAddressesArray's address after its indirection, if any (the cell is captured).
bool resolve_dst_addresses(Walker& walker, const Info& info, VkDeviceAddress& address) {
    address = info.dstAddressesArray.deviceAddress;
    if (!(info.addressResolutionFlags &
          VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_ADDRESS_ARRAY_BIT_NV))
        return true;
    return resolve_indirect_address(walker, address);
}

// The outputs walk reads a cell again to find its array; the cell is an input, kept by the
// inputs walk, so it is not kept here.
bool follow_indirect_cell(Walker& walker, VkDeviceAddress& address) {
    const size_t before = walker.result().ranges.size();
    const bool ok = resolve_indirect_address(walker, address);
    walker.result().ranges.resize(before);
    return ok;
}

}  // namespace

ClusterMemoryWalk walk_cluster_inputs(const ClusterCommandParameters& p,
                                      const DeviceMemoryReader& read,
                                      const TemplateVertexCountLookup& template_vertex_count) {
    ClusterMemoryWalk out;
    Walker walker(read, out);
    const Info& info = p.info;
    const uint32_t max_count = info.input.maxAccelerationStructureCount;
    const VkClusterAccelerationStructureAddressResolutionFlagsNV flags =
        info.addressResolutionFlags;

    VkDeviceAddress count_address = info.srcInfosCount;
    if (flags &
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_COUNT_BIT_NV)
        if (!resolve_indirect_address(walker, count_address)) return out;
    uint32_t count = max_count;
    if (count_address != 0) {
        if (!walker.capture(MemoryRole::kSrcInfosCount, 0, count_address, sizeof(uint32_t)))
            return out;
        uint32_t value;
        std::memcpy(&value, walker.last_bytes()->data(), sizeof value);
        if (value > max_count)
            walker.issue(count_address, 4,
                         "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-"
                         "10453: srcInfosCount value " +
                             std::to_string(value) + " exceeds maxAccelerationStructureCount " +
                             std::to_string(max_count));
        count = value < max_count ? value : max_count;
    }
    const uint32_t entry_bytes = cluster_src_info_size(info.input.opType);
    if (entry_bytes == 0) {
        walker.issue(0, 0,
                     "opType " + std::to_string(int(info.input.opType)) +
                         " is not an operation of spec version 4");
        return out;
    }
    VkStridedDeviceAddressRegionKHR src = info.srcInfosArray;
    if (flags &
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_ARRAY_BIT_NV)
        if (!resolve_indirect_address(walker, src.deviceAddress)) return out;
    const VkDeviceAddress dst_sizes = capture_indirect_cells(walker, info);
    const uint64_t stride = src.stride ? src.stride : entry_bytes;
    if (src.size != 0) {
        const uint64_t available =
            src.size < entry_bytes ? 0 : (src.size - entry_bytes) / stride + 1;
        if (available < count) {
            walker.issue(src.deviceAddress, src.size,
                         "VUID-vkCmdBuildClusterAccelerationStructureIndirectNV-pCommandInfos-"
                         "10454: srcInfosArray holds " +
                             std::to_string(available) + " entries, fewer than the " +
                             std::to_string(count) + " executed");
            count = uint32_t(available);
        }
    }
    out.executed_count = count;
    if (count == 0) return out;
    if (src.deviceAddress == 0) {
        walker.issue(0, 0,
                     "srcInfosArray.deviceAddress is 0 but the command executes " +
                         std::to_string(count) + " entries");
        return out;
    }

    // The entries first (so a reader sees them before the data they point at), then per entry the
    // memory it references.
    const size_t first_entry_range = out.ranges.size();
    walker.capture_strided(MemoryRole::kSrcInfos, 0, src.deviceAddress, count, stride, entry_bytes);
    const size_t last_entry_range = out.ranges.size();
    if (last_entry_range == first_entry_range) return out;
    std::vector<uint8_t> entries;  // packed copy, one entry after another
    entries.reserve(uint64_t(count) * entry_bytes);
    for (size_t r = first_entry_range; r < last_entry_range; ++r) {
        const CapturedBytes& bytes = out.ranges[r].bytes;
        if (stride == entry_bytes || stride > entry_bytes) {
            entries.insert(entries.end(), bytes.begin(), bytes.end());
        } else {  // overlapping entries were captured as one span: unpack them
            for (uint32_t i = 0; i < count; ++i)
                entries.insert(entries.end(), bytes.begin() + i * stride,
                               bytes.begin() + i * stride + entry_bytes);
        }
    }
    if (entries.size() < uint64_t(count) * entry_bytes)
        return out;  // cut short; the issue says why
    for (uint32_t i = 0; i < count; ++i)
        follow_entry(walker, i, entries.data() + uint64_t(i) * entry_bytes, p,
                     template_vertex_count);

    // Explicit destinations and their sizes are read by the command, not written (the
    // VkClusterAccelerationStructureCommandsInfoNV::dstSizesArray text).
    VkDeviceAddress dst_addresses = 0;
    if (info.input.opMode != VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV &&
        !resolve_dst_addresses(walker, info, dst_addresses))
        return out;
    if (info.input.opMode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV) {
        walker.capture_strided(MemoryRole::kDstAddresses, 0, dst_addresses, count,
                               info.dstAddressesArray.stride, sizeof(VkDeviceAddress));
        if (dst_sizes != 0)
            walker.capture_strided(MemoryRole::kDstSizes, 0, dst_sizes, count,
                                   info.dstSizesArray.stride, sizeof(uint32_t));
    }
    return out;
}

ClusterMemoryWalk walk_cluster_outputs(const ClusterCommandParameters& p, uint32_t executed_count,
                                       const DeviceMemoryReader& read) {
    ClusterMemoryWalk out;
    out.executed_count = executed_count;
    Walker walker(read, out);
    const Info& info = p.info;
    if (executed_count == 0) return out;
    const bool compute_sizes =
        info.input.opMode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_COMPUTE_SIZES_NV;
    const bool implicit =
        info.input.opMode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;

    VkDeviceAddress dst_addresses = info.dstAddressesArray.deviceAddress,
                    dst_sizes = info.dstSizesArray.deviceAddress;
    const auto flags = info.addressResolutionFlags;
    if ((flags &
         VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_ADDRESS_ARRAY_BIT_NV) &&
        !follow_indirect_cell(walker, dst_addresses))
        dst_addresses = 0;
    if ((flags &
         VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_SIZES_ARRAY_BIT_NV) &&
        !follow_indirect_cell(walker, dst_sizes))
        dst_sizes = 0;
    std::vector<uint64_t> addresses, sizes;
    if (!compute_sizes && dst_addresses != 0) {
        const size_t before = out.ranges.size();
        addresses =
            walker.capture_strided_values(MemoryRole::kDstAddresses, dst_addresses, executed_count,
                                          info.dstAddressesArray.stride, sizeof(VkDeviceAddress));
        if (!implicit)
            out.ranges.resize(before);  // explicit addresses were inputs, captured before
    }
    if (dst_sizes != 0) {
        const size_t before = out.ranges.size();
        sizes = walker.capture_strided_values(MemoryRole::kDstSizes, dst_sizes, executed_count,
                                              info.dstSizesArray.stride, sizeof(uint32_t));
        if (!implicit && !compute_sizes)
            out.ranges.resize(before);  // explicit sizes were inputs, captured before
    }
    // The objects themselves, where both their address and size are known.
    if (!compute_sizes && addresses.size() == executed_count && sizes.size() == executed_count) {
        out.ranges.reserve(out.ranges.size() +
                           executed_count);  // (as many values were read already)
        for (uint32_t i = 0; i < executed_count; ++i)
            if (addresses[i] != 0 && sizes[i] != 0)
                walker.capture(MemoryRole::kDstObject, i, addresses[i], sizes[i]);
    }
    return out;
}

}  // namespace clastrace::capture

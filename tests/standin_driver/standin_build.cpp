// SPDX-License-Identifier: MIT
#include "standin_build.h"

#include "standin_layout.h"

#include <clastrace/engine/build_sizes.h>
#include <clastrace/engine/execute.h>
#include <clastrace/engine/memory_image.h>

#include <algorithm>
#include <cstring>
#include <utility>

namespace clastrace::standin {

namespace {

using Range = std::pair<uint64_t, uint64_t>;  // [begin, end)

// An image of every buffer's bytes; buffers whose address ranges overlap share one region.
engine::MemoryImage snapshot(std::vector<HostBuffer> buffers) {
    std::sort(buffers.begin(), buffers.end(),
              [](const HostBuffer& a, const HostBuffer& b) { return a.address < b.address; });
    engine::MemoryImage image;
    size_t first = 0;
    while (first < buffers.size()) {
        uint64_t end = buffers[first].address + buffers[first].size;
        VkBufferUsageFlags usage = buffers[first].usage;
        size_t last = first + 1;
        for (; last < buffers.size() && buffers[last].address < end; ++last) {
            end = std::max(end, buffers[last].address + buffers[last].size);
            usage |= buffers[last].usage;
        }
        const uint64_t base = buffers[first].address;
        engine::MemoryRegion& region = image.add_region(base, end - base, usage, "standin buffer");
        for (size_t i = first; i < last; ++i)
            std::memcpy(region.bytes.write_at(buffers[i].address - base, buffers[i].size),
                        buffers[i].host, buffers[i].size);
        first = last;
    }
    return image;
}

// Copies the image's bytes of `ranges` to every buffer holding them.
void write_back(const engine::MemoryImage& image, const std::vector<Range>& ranges,
                const std::vector<HostBuffer>& buffers) {
    for (const auto& [begin, end] : ranges) {
        for (const HostBuffer& b : buffers) {
            const uint64_t from = std::max(begin, b.address);
            const uint64_t to = std::min(end, b.address + b.size);
            if (from >= to) continue;
            const auto bytes = image.read_bytes(from, to - from, {"standin write-back", -1});
            std::memcpy(b.host + (from - b.address), bytes.data(), to - from);
        }
    }
}

std::vector<Range> writes_of(const engine::ExecutionRecord& record) {
    std::vector<Range> ranges;
    for (const engine::MemoryAccess& a : record.accesses)
        if (a.is_write && a.end > a.begin) ranges.emplace_back(a.begin, a.end);
    return ranges;
}

uint64_t object_alignment(const VkClusterAccelerationStructureCommandsInfoNV& info) {
    const auto move_type =
        info.input.opInput.pMoveObjects &&
                info.input.opType == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV
            ? info.input.opInput.pMoveObjects->type
            : VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_NV;
    return engine::destination_alignment(info.input.opType, move_type,
                                         engine::EngineProperties::nvidia_default());
}

uint64_t element(const VkStridedDeviceAddressRegionKHR& region, uint64_t index, uint64_t natural) {
    return region.deviceAddress + index * (region.stride ? region.stride : natural);
}

// The stand-in reports padded sizes in dstSizesArray, whatever the mode.
void report_padded_sizes(const VkClusterAccelerationStructureCommandsInfoNV& info,
                         const std::vector<uint64_t>& engine_sizes, engine::MemoryImage& image,
                         std::vector<Range>& written) {
    if (info.dstSizesArray.deviceAddress == 0) return;
    const uint64_t alignment = object_alignment(info);
    for (size_t i = 0; i < engine_sizes.size(); ++i) {
        const uint64_t at = element(info.dstSizesArray, i, 4);
        const uint32_t size =
            engine_sizes[i] ? static_cast<uint32_t>(padded_size(engine_sizes[i], alignment)) : 0;
        image.write<uint32_t>(at, size, {"dstSizesArray", static_cast<int64_t>(i)});
        written.emplace_back(at, at + 4);
    }
}

std::vector<uint64_t> sizes_of(const engine::ExecutionRecord& record) {
    std::vector<uint64_t> sizes;
    for (const engine::OpResult& op : record.ops) sizes.push_back(op.executed ? op.dst_size : 0);
    return sizes;
}

engine::ExecuteOptions options_with(engine::ObjectDirectory& directory) {
    engine::ExecuteOptions options;
    options.directory = &directory;
    return options;
}

// Implicit mode, the stand-in's way: a probe run learns each object's size, the stand-in
// places them (kImplicitLeadingBytes in, padded), writes the addresses into a table in its
// scratch and lets the engine build in explicit mode through that table.
size_t execute_implicit(const VkClusterAccelerationStructureCommandsInfoNV& info,
                        const std::vector<HostBuffer>& buffers,
                        engine::ObjectDirectory& directory) {
    engine::ObjectDirectory probe_directory = directory;
    engine::MemoryImage probe_image = snapshot(buffers);
    const engine::ExecutionRecord probe =
        engine::execute(info, probe_image, options_with(probe_directory));
    const std::vector<uint64_t> sizes = sizes_of(probe);
    const std::vector<uint64_t> offsets = implicit_offsets(sizes, object_alignment(info));

    engine::MemoryImage image = snapshot(buffers);
    std::vector<Range> written;
    const uint64_t table =
        info.scratchData + address_table_offset(info.input.maxAccelerationStructureCount);
    for (size_t i = 0; i < offsets.size(); ++i) {
        const uint64_t address = offsets[i] == UINT64_MAX ? 0 : info.dstImplicitData + offsets[i];
        image.write<uint64_t>(table + 8 * i, address,
                              {"standin address table", static_cast<int64_t>(i)});
        if (info.dstAddressesArray.deviceAddress != 0) {
            const uint64_t at = element(info.dstAddressesArray, i, 8);
            image.write<uint64_t>(at, address, {"dstAddressesArray", static_cast<int64_t>(i)});
            written.emplace_back(at, at + 8);
        }
    }
    written.emplace_back(table, table + 8 * offsets.size());

    VkClusterAccelerationStructureCommandsInfoNV explicit_info = info;
    explicit_info.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
    explicit_info.dstImplicitData = 0;
    explicit_info.dstAddressesArray = {table, 8, 8 * offsets.size()};
    explicit_info.dstSizesArray = {};
    const engine::ExecutionRecord record =
        engine::execute(explicit_info, image, options_with(directory));
    for (const Range& r : writes_of(record)) written.push_back(r);
    report_padded_sizes(info, sizes_of(record), image, written);
    write_back(image, written, buffers);
    return record.findings.size();
}

// The indirected fields the stand-in writes through (or places objects in); the source
// fields stay indirected for the engine to read.
constexpr VkClusterAccelerationStructureAddressResolutionFlagsNV kDestinationIndirections =
    VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_IMPLICIT_DATA_BIT_NV |
    VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SCRATCH_DATA_BIT_NV |
    VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_ADDRESS_ARRAY_BIT_NV |
    VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_SIZES_ARRAY_BIT_NV;

bool destinations_resolved(const VkClusterAccelerationStructureCommandsInfoNV& info) {
    return (info.addressResolutionFlags & kDestinationIndirections) == 0;
}

// The 8-byte cell at `address` (docs/spec-readings.md: an indirected field's value is the
// address of a cell holding the real address); false when no buffer holds all of it.
bool read_cell(const std::vector<HostBuffer>& buffers, uint64_t address, uint64_t* value) {
    for (const HostBuffer& b : buffers)
        if (address >= b.address && address - b.address + 8 <= b.size) {
            std::memcpy(value, b.host + (address - b.address), 8);
            return true;
        }
    return false;
}

// `info` with each indirected destination field replaced by the address its cell holds, so
// the stand-in lays out and reports at its own layout as for a direct field. A field whose
// cell no buffer holds stays indirected (the engine then reports the bad cell).
VkClusterAccelerationStructureCommandsInfoNV with_destinations_resolved(
    const VkClusterAccelerationStructureCommandsInfoNV& recorded,
    const std::vector<HostBuffer>& buffers) {
    VkClusterAccelerationStructureCommandsInfoNV info = recorded;
    const auto resolve = [&](VkDeviceAddress& field, uint32_t bit) {
        uint64_t value = 0;
        if (!(info.addressResolutionFlags & bit) || field == 0) return;
        if (!read_cell(buffers, field, &value)) return;
        field = value;
        info.addressResolutionFlags &= ~bit;
    };
    resolve(
        info.dstImplicitData,
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_IMPLICIT_DATA_BIT_NV);
    resolve(info.scratchData,
            VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SCRATCH_DATA_BIT_NV);
    resolve(
        info.dstAddressesArray.deviceAddress,
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_ADDRESS_ARRAY_BIT_NV);
    resolve(info.dstSizesArray.deviceAddress,
            VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_DST_SIZES_ARRAY_BIT_NV);
    return info;
}

}  // namespace

RecordedBuild::RecordedBuild(const VkClusterAccelerationStructureCommandsInfoNV& recorded)
    : info(recorded) {
    info.pNext = nullptr;
    info.input.pNext = nullptr;
    const auto& in = recorded.input;
    switch (in.opType) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV:
        if (in.opInput.pClustersBottomLevel) bottom_level = *in.opInput.pClustersBottomLevel;
        info.input.opInput.pClustersBottomLevel = &bottom_level;
        break;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV:
        if (in.opInput.pMoveObjects) move_objects = *in.opInput.pMoveObjects;
        info.input.opInput.pMoveObjects = &move_objects;
        break;
    default:  // the triangle-cluster ops: builds, templates, instantiations, template indices
        if (in.opInput.pTriangleClusters) triangle_clusters = *in.opInput.pTriangleClusters;
        info.input.opInput.pTriangleClusters = &triangle_clusters;
        break;
    }
}

size_t execute_on_host(const RecordedBuild& build, const std::vector<HostBuffer>& buffers,
                       engine::ObjectDirectory& directory) {
    const VkClusterAccelerationStructureCommandsInfoNV info =
        with_destinations_resolved(build.info, buffers);
    if (info.input.opMode == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV &&
        destinations_resolved(info))
        return execute_implicit(info, buffers, directory);
    engine::MemoryImage image = snapshot(buffers);
    const engine::ExecutionRecord record = engine::execute(info, image, options_with(directory));
    std::vector<Range> written = writes_of(record);
    if (destinations_resolved(info) &&
        info.input.opType !=
            VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV)
        report_padded_sizes(info, sizes_of(record), image, written);
    write_back(image, written, buffers);
    return record.findings.size();
}

}  // namespace clastrace::standin

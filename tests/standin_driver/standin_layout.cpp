// SPDX-License-Identifier: MIT
#include "standin_layout.h"

#include <clastrace/engine/build_sizes.h>
#include <clastrace/engine/properties.h>

#include <algorithm>

namespace clastrace::standin {

namespace {

uint64_t align_up(uint64_t value, uint64_t alignment) {
    return alignment ? (value + alignment - 1) / alignment * alignment : value;
}

engine::BuildSizes engine_sizes_in_mode(VkClusterAccelerationStructureInputInfoNV info,
                                        VkClusterAccelerationStructureOpModeNV mode) {
    info.opMode = mode;
    return engine::cluster_build_sizes(info, engine::EngineProperties::nvidia_default());
}

}  // namespace

uint64_t padded_size(uint64_t engine_size, uint64_t alignment) {
    return align_up(engine_size + kObjectPaddingBytes, alignment);
}

uint64_t address_table_offset(uint32_t max_count) {
    return align_up(engine::scratch_bytes_for_ops(max_count), 256);
}

StandinSizes standin_build_sizes(const VkClusterAccelerationStructureInputInfoNV& info) {
    // The build runs the engine in explicit mode through the table: its scratch is what both
    // modes of the engine need, then the table, then slack.
    const engine::BuildSizes explicit_sizes =
        engine_sizes_in_mode(info,
                             VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV);
    if (!explicit_sizes.findings.empty()) return {};
    const uint64_t alignment = engine::destination_alignment(
        info.opType,
        info.opType == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV &&
                info.opInput.pMoveObjects
            ? info.opInput.pMoveObjects->type
            : VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_NV,
        engine::EngineProperties::nvidia_default());
    StandinSizes sizes;
    const uint64_t count = info.maxAccelerationStructureCount;
    sizes.padded_object_size = padded_size(explicit_sizes.single_object_size, alignment);
    sizes.build_scratch_size = std::max(address_table_offset(info.maxAccelerationStructureCount),
                                        align_up(explicit_sizes.build_scratch_size, 256)) +
                               align_up(8 * count, 256) + kScratchSlackBytes;
    switch (info.opMode) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV:
        sizes.acceleration_structure_size =
            kImplicitLeadingBytes + count * sizes.padded_object_size;
        break;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV:
        sizes.acceleration_structure_size = sizes.padded_object_size;
        break;
    default: sizes.acceleration_structure_size = 0;
    }
    return sizes;
}

std::vector<uint64_t> implicit_offsets(const std::vector<uint64_t>& engine_sizes,
                                       uint64_t alignment) {
    std::vector<uint64_t> offsets;
    uint64_t cursor = kImplicitLeadingBytes;
    for (uint64_t size : engine_sizes) {
        if (size == 0) {
            offsets.push_back(UINT64_MAX);
            continue;
        }
        cursor = align_up(cursor, alignment);
        offsets.push_back(cursor);
        cursor += padded_size(size, alignment);
    }
    return offsets;
}

}  // namespace clastrace::standin

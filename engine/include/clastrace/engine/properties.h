// SPDX-License-Identifier: Apache-2.0
// The limits and alignments the engine advertises, as
// VkPhysicalDeviceClusterAccelerationStructurePropertiesNV would.
#pragma once

#include "clastrace/vk_cluster_abi.h"

#include <cstdint>

namespace clastrace::engine {

struct EngineProperties {
    uint32_t max_vertices_per_cluster = 256;
    uint32_t max_triangles_per_cluster = 256;
    uint32_t cluster_scratch_byte_alignment = 128;
    uint32_t cluster_byte_alignment = 128;
    uint32_t cluster_template_byte_alignment = 32;
    uint32_t cluster_bottom_level_byte_alignment = 256;
    uint32_t cluster_template_bounds_byte_alignment = 32;
    uint32_t max_cluster_geometry_index = 16777215;  // 2^24 - 1, the geometryIndex field's range

    // The values a current NVIDIA driver reports (as far as public device reports show);
    // a trace's captured properties replace them through from_vk().
    static EngineProperties nvidia_default() { return EngineProperties{}; }
    static EngineProperties from_vk(
        const VkPhysicalDeviceClusterAccelerationStructurePropertiesNV& p);
    VkPhysicalDeviceClusterAccelerationStructurePropertiesNV to_vk() const;

    // Our byte formats hold vertex/triangle counts up to 256 and local indices in a byte:
    // larger captured limits are clamped to these (the spec's bit-fields allow 511).
    static constexpr uint32_t kFormatMaxVertices = 256;
    static constexpr uint32_t kFormatMaxTriangles = 256;
};

}  // namespace clastrace::engine

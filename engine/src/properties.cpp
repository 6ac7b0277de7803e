// SPDX-License-Identifier: Apache-2.0
#include "clastrace/engine/properties.h"

namespace clastrace::engine {

EngineProperties EngineProperties::from_vk(
    const VkPhysicalDeviceClusterAccelerationStructurePropertiesNV& p) {
    EngineProperties e;
    e.max_vertices_per_cluster = p.maxVerticesPerCluster;
    e.max_triangles_per_cluster = p.maxTrianglesPerCluster;
    e.cluster_scratch_byte_alignment = p.clusterScratchByteAlignment;
    e.cluster_byte_alignment = p.clusterByteAlignment;
    e.cluster_template_byte_alignment = p.clusterTemplateByteAlignment;
    e.cluster_bottom_level_byte_alignment = p.clusterBottomLevelByteAlignment;
    e.cluster_template_bounds_byte_alignment = p.clusterTemplateBoundsByteAlignment;
    e.max_cluster_geometry_index = p.maxClusterGeometryIndex;
    return e;
}

VkPhysicalDeviceClusterAccelerationStructurePropertiesNV EngineProperties::to_vk() const {
    VkPhysicalDeviceClusterAccelerationStructurePropertiesNV p{};
    p.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_PROPERTIES_NV;
    p.maxVerticesPerCluster = max_vertices_per_cluster;
    p.maxTrianglesPerCluster = max_triangles_per_cluster;
    p.clusterScratchByteAlignment = cluster_scratch_byte_alignment;
    p.clusterByteAlignment = cluster_byte_alignment;
    p.clusterTemplateByteAlignment = cluster_template_byte_alignment;
    p.clusterBottomLevelByteAlignment = cluster_bottom_level_byte_alignment;
    p.clusterTemplateBoundsByteAlignment = cluster_template_bounds_byte_alignment;
    p.maxClusterGeometryIndex = max_cluster_geometry_index;
    return p;
}

}  // namespace clastrace::engine

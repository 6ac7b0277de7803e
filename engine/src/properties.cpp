#include "clastrace/engine/properties.h"

namespace clastrace::engine {

EngineProperties EngineProperties::from_vk(const VkPhysicalDeviceClusterAccelerationStructurePropertiesNV& p) {
  EngineProperties e;
  e.maxVerticesPerCluster = p.maxVerticesPerCluster;
  e.maxTrianglesPerCluster = p.maxTrianglesPerCluster;
  e.clusterScratchByteAlignment = p.clusterScratchByteAlignment;
  e.clusterByteAlignment = p.clusterByteAlignment;
  e.clusterTemplateByteAlignment = p.clusterTemplateByteAlignment;
  e.clusterBottomLevelByteAlignment = p.clusterBottomLevelByteAlignment;
  e.clusterTemplateBoundsByteAlignment = p.clusterTemplateBoundsByteAlignment;
  e.maxClusterGeometryIndex = p.maxClusterGeometryIndex;
  return e;
}

VkPhysicalDeviceClusterAccelerationStructurePropertiesNV EngineProperties::to_vk() const {
  VkPhysicalDeviceClusterAccelerationStructurePropertiesNV p{};
  p.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_PROPERTIES_NV;
  p.maxVerticesPerCluster = maxVerticesPerCluster;
  p.maxTrianglesPerCluster = maxTrianglesPerCluster;
  p.clusterScratchByteAlignment = clusterScratchByteAlignment;
  p.clusterByteAlignment = clusterByteAlignment;
  p.clusterTemplateByteAlignment = clusterTemplateByteAlignment;
  p.clusterBottomLevelByteAlignment = clusterBottomLevelByteAlignment;
  p.clusterTemplateBoundsByteAlignment = clusterTemplateBoundsByteAlignment;
  p.maxClusterGeometryIndex = maxClusterGeometryIndex;
  return p;
}

}  // namespace clastrace::engine

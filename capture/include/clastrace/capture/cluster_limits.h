// What the layer answers for VK_NV_cluster_acceleration_structure when it serves the extension.
//
// One place on purpose: the engine will own the limits of the device it emulates and these
// defaults are to be replaced by its values. They are NVIDIA-like (Ada/Blackwell drivers).
#pragma once

#include <clastrace/vk_cluster_abi.h>

namespace clastrace::capture {

inline VkPhysicalDeviceClusterAccelerationStructurePropertiesNV servedClusterProperties() {
  VkPhysicalDeviceClusterAccelerationStructurePropertiesNV p{};
  p.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_CLUSTER_ACCELERATION_STRUCTURE_PROPERTIES_NV;
  p.maxVerticesPerCluster = 256;
  p.maxTrianglesPerCluster = 256;
  p.clusterScratchByteAlignment = 128;
  p.clusterByteAlignment = 128;
  p.clusterTemplateByteAlignment = 32;
  p.clusterBottomLevelByteAlignment = 256;
  p.clusterTemplateBoundsByteAlignment = 32;
  p.maxClusterGeometryIndex = 16777215;
  return p;
}

}  // namespace clastrace::capture

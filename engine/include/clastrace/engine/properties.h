// The limits and alignments the engine advertises, as
// VkPhysicalDeviceClusterAccelerationStructurePropertiesNV would.
#ifndef CLASTRACE_ENGINE_PROPERTIES_H
#define CLASTRACE_ENGINE_PROPERTIES_H

#include "clastrace/vk_cluster_abi.h"

#include <cstdint>

namespace clastrace::engine {

struct EngineProperties {
  uint32_t maxVerticesPerCluster = 256;
  uint32_t maxTrianglesPerCluster = 256;
  uint32_t clusterScratchByteAlignment = 128;
  uint32_t clusterByteAlignment = 128;
  uint32_t clusterTemplateByteAlignment = 32;
  uint32_t clusterBottomLevelByteAlignment = 256;
  uint32_t clusterTemplateBoundsByteAlignment = 32;
  uint32_t maxClusterGeometryIndex = 16777215;  // 2^24 - 1, the geometryIndex field's range

  // The values a current NVIDIA driver reports (as far as public device reports show);
  // a trace's captured properties replace them through from_vk().
  static EngineProperties nvidia_default() { return EngineProperties{}; }
  static EngineProperties from_vk(const VkPhysicalDeviceClusterAccelerationStructurePropertiesNV& p);
  VkPhysicalDeviceClusterAccelerationStructurePropertiesNV to_vk() const;

  // Our byte formats hold vertex/triangle counts up to 256 and local indices in a byte:
  // larger captured limits are clamped to these (the spec's bit-fields allow 511).
  static constexpr uint32_t kFormatMaxVertices = 256;
  static constexpr uint32_t kFormatMaxTriangles = 256;
};

}  // namespace clastrace::engine

#endif

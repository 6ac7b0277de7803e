#include "clastrace/capture/build_sizes_model.h"

#include <algorithm>

namespace clastrace::capture {
namespace {

uint64_t alignUp(uint64_t value, uint64_t alignment) {
  return alignment ? (value + alignment - 1) / alignment * alignment : value;
}

uint64_t vertexFormatBytes(VkFormat format) {
  switch (format) {
    case VK_FORMAT_R32G32B32_SFLOAT: return 12;
    case VK_FORMAT_R32G32B32A32_SFLOAT: return 16;
    case VK_FORMAT_R16G16B16A16_SFLOAT: return 8;
    case VK_FORMAT_R16G16B16A16_SNORM: return 8;
    case VK_FORMAT_R16G16_SFLOAT: return 4;
    default: return 16;  // unknown formats get the widest one we accept
  }
}

// Upper bound of one cluster: a header, uncompressed vertices and full 32-bit index triplets plus
// a per-triangle geometry word. Real encodings compress; this only has to be large enough.
uint64_t clusterBound(uint64_t vertices, uint64_t triangles, uint64_t vertexBytes) {
  constexpr uint64_t kHeaderBytes = 128;
  return kHeaderBytes + vertices * vertexBytes + triangles * (3 * 4 + 4);
}

}  // namespace

bool conservativeClusterBuildSizes(const VkClusterAccelerationStructureInputInfoNV& input,
                                   const VkPhysicalDeviceClusterAccelerationStructurePropertiesNV& limits,
                                   VkAccelerationStructureBuildSizesInfoKHR& sizes) {
  sizes.accelerationStructureSize = 0;
  sizes.buildScratchSize = 0;
  sizes.updateScratchSize = 0;
  const uint64_t count = input.maxAccelerationStructureCount;
  uint64_t objectBytes = 0;
  uint64_t alignment = limits.clusterByteAlignment;
  switch (input.opType) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV:
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV:
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV: {
      const auto* tri = input.opInput.pTriangleClusters;
      if (!tri) return false;
      if (input.opType == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV)
        alignment = limits.clusterTemplateByteAlignment;
      const uint64_t vb = vertexFormatBytes(tri->vertexFormat);
      const uint64_t perCluster =
          alignUp(clusterBound(tri->maxClusterVertexCount, tri->maxClusterTriangleCount, vb), alignment);
      // Totals bound the sum over clusters; each cluster also pays its header and alignment.
      const uint64_t byTotals = clusterBound(tri->maxTotalVertexCount, tri->maxTotalTriangleCount, vb) +
                                count * (128 + alignment);
      objectBytes = std::min(perCluster * count, byTotals);
      break;
    }
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV: {
      const auto* blas = input.opInput.pClustersBottomLevel;
      if (!blas) return false;
      alignment = limits.clusterBottomLevelByteAlignment;
      // A binary BVH over N clusters has < 2N nodes; 64 bytes per node and per leaf reference.
      const uint64_t perBlas = alignUp(256 + uint64_t(blas->maxClusterCountPerAccelerationStructure) * 128, alignment);
      const uint64_t byTotals = 256 * count + uint64_t(blas->maxTotalClusterCount) * 128 + count * alignment;
      objectBytes = std::min(perBlas * count, byTotals);
      break;
    }
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV: {
      const auto* move = input.opInput.pMoveObjects;
      if (!move) return false;
      objectBytes = move->maxMovedBytes;
      break;
    }
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV:
      objectBytes = 0;
      break;
    default:
      return false;
  }
  sizes.accelerationStructureSize = objectBytes;
  // Scratch: per object a sort key and a reference, aligned as the driver asks.
  sizes.buildScratchSize = alignUp(count * 64 + 256, limits.clusterScratchByteAlignment);
  return true;
}

}  // namespace clastrace::capture

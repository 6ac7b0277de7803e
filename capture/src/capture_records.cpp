#include "clastrace/capture/capture_records.h"

namespace clastrace::capture {

ClusterCommandParameters copyClusterInput(const VkClusterAccelerationStructureInputInfoNV& input) {
  ClusterCommandParameters p;
  p.info.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
  p.info.input = input;
  p.info.input.pNext = nullptr;
  p.info.input.opInput.pTriangleClusters = nullptr;
  // The union's member is chosen by opType; any member's pointer value is the same pointer.
  const void* opInput = input.opInput.pTriangleClusters;
  p.hasOpInput = opInput != nullptr;
  if (!opInput) return p;
  switch (input.opType) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV:
      p.bottomLevelInput = *input.opInput.pClustersBottomLevel;
      p.bottomLevelInput.pNext = nullptr;
      break;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV:
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV:
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV:
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV:
      p.triangleClusterInput = *input.opInput.pTriangleClusters;
      p.triangleClusterInput.pNext = nullptr;
      break;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV:
      p.moveObjectsInput = *input.opInput.pMoveObjects;
      p.moveObjectsInput.pNext = nullptr;
      break;
    default:
      p.hasOpInput = false;  // unknown op type: its input's layout is unknown, copy nothing
      break;
  }
  return p;
}

ClusterCommandParameters ClusterCommandParameters::copyOf(const VkClusterAccelerationStructureCommandsInfoNV& info) {
  ClusterCommandParameters p = copyClusterInput(info.input);
  const VkClusterAccelerationStructureInputInfoNV input = p.info.input;
  p.info = info;
  p.info.pNext = nullptr;
  p.info.input = input;
  return p;
}

VkClusterAccelerationStructureCommandsInfoNV ClusterCommandParameters::resolved() const {
  VkClusterAccelerationStructureCommandsInfoNV out = info;
  if (!hasOpInput) return out;
  switch (info.input.opType) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV:
      out.input.opInput.pClustersBottomLevel =
          const_cast<VkClusterAccelerationStructureClustersBottomLevelInputNV*>(&bottomLevelInput);
      break;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV:
      out.input.opInput.pMoveObjects = const_cast<VkClusterAccelerationStructureMoveObjectsInputNV*>(&moveObjectsInput);
      break;
    default:
      out.input.opInput.pTriangleClusters =
          const_cast<VkClusterAccelerationStructureTriangleClusterInputNV*>(&triangleClusterInput);
      break;
  }
  return out;
}

const char* memoryRoleName(MemoryRole role) {
  switch (role) {
    case MemoryRole::SrcInfosCount: return "srcInfosCount";
    case MemoryRole::SrcInfos: return "srcInfos";
    case MemoryRole::IndexBuffer: return "indexBuffer";
    case MemoryRole::VertexBuffer: return "vertexBuffer";
    case MemoryRole::GeometryIndexAndFlags: return "geometryIndexAndFlagsBuffer";
    case MemoryRole::OpacityMicromapIndices: return "opacityMicromapIndexBuffer";
    case MemoryRole::InstantiationBoundingBox: return "instantiationBoundingBoxLimit";
    case MemoryRole::ClusterReferences: return "clusterReferences";
    case MemoryRole::IndirectAddress: return "indirectAddress";
    case MemoryRole::DstAddresses: return "dstAddresses";
    case MemoryRole::DstSizes: return "dstSizes";
    case MemoryRole::DstObject: return "dstObject";
    case MemoryRole::TransformData: return "transformData";
    case MemoryRole::Aabbs: return "aabbData";
    case MemoryRole::Instances: return "instanceData";
    case MemoryRole::SerializedAccelerationStructure: return "serializedAccelerationStructure";
  }
  return "unknown";
}

}  // namespace clastrace::capture

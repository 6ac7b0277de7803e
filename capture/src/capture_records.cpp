// SPDX-License-Identifier: Apache-2.0
#include "clastrace/capture/capture_records.h"

namespace clastrace::capture {

ClusterCommandParameters copy_cluster_input(
    const VkClusterAccelerationStructureInputInfoNV& input) {
    ClusterCommandParameters p;
    p.info.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    p.info.input = input;
    p.info.input.pNext = nullptr;
    p.info.input.opInput.pTriangleClusters = nullptr;
    // The union's member is chosen by opType; any member's pointer value is the same pointer.
    const void* op_input = input.opInput.pTriangleClusters;
    p.has_op_input = op_input != nullptr;
    if (!op_input) return p;
    switch (input.opType) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV:
        p.bottom_level_input = *input.opInput.pClustersBottomLevel;
        p.bottom_level_input.pNext = nullptr;
        break;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV:
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_TEMPLATE_NV:
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_INSTANTIATE_TRIANGLE_CLUSTER_NV:
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_GET_CLUSTER_TEMPLATE_INDICES_NV:
        p.triangle_cluster_input = *input.opInput.pTriangleClusters;
        p.triangle_cluster_input.pNext = nullptr;
        break;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV:
        p.move_objects_input = *input.opInput.pMoveObjects;
        p.move_objects_input.pNext = nullptr;
        break;
    default:
        p.has_op_input = false;  // unknown op type: its input's layout is unknown, copy nothing
        break;
    }
    return p;
}

ClusterCommandParameters ClusterCommandParameters::copy_of(
    const VkClusterAccelerationStructureCommandsInfoNV& info) {
    ClusterCommandParameters p = copy_cluster_input(info.input);
    const VkClusterAccelerationStructureInputInfoNV input = p.info.input;
    p.info = info;
    p.info.pNext = nullptr;
    p.info.input = input;
    return p;
}

VkClusterAccelerationStructureCommandsInfoNV ClusterCommandParameters::resolved() const {
    VkClusterAccelerationStructureCommandsInfoNV out = info;
    if (!has_op_input) return out;
    switch (info.input.opType) {
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV:
        out.input.opInput.pClustersBottomLevel =
            const_cast<VkClusterAccelerationStructureClustersBottomLevelInputNV*>(
                &bottom_level_input);
        break;
    case VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV:
        out.input.opInput.pMoveObjects =
            const_cast<VkClusterAccelerationStructureMoveObjectsInputNV*>(&move_objects_input);
        break;
    default:
        out.input.opInput.pTriangleClusters =
            const_cast<VkClusterAccelerationStructureTriangleClusterInputNV*>(
                &triangle_cluster_input);
        break;
    }
    return out;
}

KhrBuildInfo KhrBuildInfo::copy_of(const VkAccelerationStructureBuildGeometryInfoKHR& info,
                                   const VkAccelerationStructureBuildRangeInfoKHR* ranges) {
    KhrBuildInfo copy;
    copy.info = info;
    copy.info.pNext = nullptr;
    copy.info.pGeometries = nullptr;
    copy.info.ppGeometries = nullptr;
    for (auto* s = static_cast<const VkBaseInStructure*>(info.pNext); s; s = s->pNext)
        copy.next_stypes.push_back(uint32_t(s->sType));
    for (uint32_t g = 0; g < info.geometryCount; ++g) {
        VkAccelerationStructureGeometryKHR geometry =
            info.pGeometries ? info.pGeometries[g] : *info.ppGeometries[g];
        geometry.pNext = nullptr;
        // The union's active member's pNext (e.g. motion or micromap data) is not kept either.
        if (geometry.geometryType == VK_GEOMETRY_TYPE_TRIANGLES_KHR)
            geometry.geometry.triangles.pNext = nullptr;
        else if (geometry.geometryType == VK_GEOMETRY_TYPE_AABBS_KHR)
            geometry.geometry.aabbs.pNext = nullptr;
        else if (geometry.geometryType == VK_GEOMETRY_TYPE_INSTANCES_KHR)
            geometry.geometry.instances.pNext = nullptr;
        copy.geometries.push_back(geometry);
        if (ranges) copy.ranges.push_back(ranges[g]);
    }
    return copy;
}

VkAccelerationStructureBuildGeometryInfoKHR KhrBuildInfo::resolved() const {
    VkAccelerationStructureBuildGeometryInfoKHR out = info;
    out.geometryCount = uint32_t(geometries.size());
    out.pGeometries = geometries.data();
    return out;
}

const char* memory_role_name(MemoryRole role) {
    switch (role) {
    case MemoryRole::kSrcInfosCount: return "srcInfosCount";
    case MemoryRole::kSrcInfos: return "srcInfos";
    case MemoryRole::kIndexBuffer: return "indexBuffer";
    case MemoryRole::kVertexBuffer: return "vertexBuffer";
    case MemoryRole::kGeometryIndexAndFlags: return "geometryIndexAndFlagsBuffer";
    case MemoryRole::kOpacityMicromapIndices: return "opacityMicromapIndexBuffer";
    case MemoryRole::kInstantiationBoundingBox: return "instantiationBoundingBoxLimit";
    case MemoryRole::kClusterReferences: return "clusterReferences";
    case MemoryRole::kIndirectAddress: return "indirectAddress";
    case MemoryRole::kDstAddresses: return "dstAddresses";
    case MemoryRole::kDstSizes: return "dstSizes";
    case MemoryRole::kDstObject: return "dstObject";
    case MemoryRole::kTransformData: return "transformData";
    case MemoryRole::kAabbs: return "aabbData";
    case MemoryRole::kInstances: return "instanceData";
    case MemoryRole::kSerializedAccelerationStructure: return "serializedAccelerationStructure";
    case MemoryRole::kShaderWrite: return "shaderWrite";
    case MemoryRole::kBuildRanges: return "buildRangeInfos";
    case MemoryRole::kInstancePointers: return "instancePointers";
    case MemoryRole::kSourceAccelerationStructure: return "srcAccelerationStructure";
    case MemoryRole::kTraceRaysIndirect: return "traceRaysIndirect";
    }
    return "unknown";
}

}  // namespace clastrace::capture

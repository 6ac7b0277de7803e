#include "clastrace/trace_building/cluster_records.h"

namespace clastrace::trace_building {

std::unique_ptr<fbs::ClusterInputInfoT> cluster_input(const VkClusterAccelerationStructureInputInfoNV& in) {
    auto out = std::make_unique<fbs::ClusterInputInfoT>();
    out->max_acceleration_structure_count = in.maxAccelerationStructureCount;
    out->flags = in.flags;
    out->op_type = in.opType;
    out->op_mode = in.opMode;
    if (in.opType == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV) {
        fbs::ClustersBottomLevelInputT b;
        b.max_total_cluster_count = in.opInput.pClustersBottomLevel->maxTotalClusterCount;
        b.max_cluster_count_per_acceleration_structure = in.opInput.pClustersBottomLevel->maxClusterCountPerAccelerationStructure;
        out->op_input.Set(std::move(b));
    } else if (in.opType == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV) {
        fbs::MoveObjectsInputT m;
        m.type = in.opInput.pMoveObjects->type;
        m.no_move_overlap = in.opInput.pMoveObjects->noMoveOverlap;
        m.max_moved_bytes = in.opInput.pMoveObjects->maxMovedBytes;
        out->op_input.Set(std::move(m));
    } else if (in.opInput.pTriangleClusters) {
        const auto& t = *in.opInput.pTriangleClusters;
        fbs::TriangleClusterInputT c;
        c.vertex_format = t.vertexFormat;
        c.max_geometry_index_value = t.maxGeometryIndexValue;
        c.max_cluster_unique_geometry_count = t.maxClusterUniqueGeometryCount;
        c.max_cluster_triangle_count = t.maxClusterTriangleCount;
        c.max_cluster_vertex_count = t.maxClusterVertexCount;
        c.max_total_triangle_count = t.maxTotalTriangleCount;
        c.max_total_vertex_count = t.maxTotalVertexCount;
        c.min_position_truncate_bit_count = t.minPositionTruncateBitCount;
        out->op_input.Set(std::move(c));
    }
    return out;
}

std::unique_ptr<fbs::StridedDeviceAddressRegion> strided_region(const VkStridedDeviceAddressRegionKHR& r) {
    return std::make_unique<fbs::StridedDeviceAddressRegion>(r.deviceAddress, r.stride, r.size);
}

fbs::CmdBuildClusterAccelerationStructureIndirectT cluster_build(uint64_t command_buffer,
                                                                 const VkClusterAccelerationStructureCommandsInfoNV& info) {
    fbs::CmdBuildClusterAccelerationStructureIndirectT b;
    b.command_buffer = command_buffer;
    b.input = cluster_input(info.input);
    b.dst_implicit_data = info.dstImplicitData;
    b.scratch_data = info.scratchData;
    b.dst_addresses_array = strided_region(info.dstAddressesArray);
    b.dst_sizes_array = strided_region(info.dstSizesArray);
    b.src_infos_array = strided_region(info.srcInfosArray);
    b.src_infos_count = info.srcInfosCount;
    b.address_resolution_flags = info.addressResolutionFlags;
    return b;
}

}  // namespace clastrace::trace_building

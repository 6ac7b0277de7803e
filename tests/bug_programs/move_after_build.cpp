// SPDX-License-Identifier: Apache-2.0
// Compaction by moves: the CLAS are built at addresses the host chose (explicit destinations),
// then MOVE_OBJECTS packs them into a buffer of their own. One bug per run:
//   (none)         the move follows the build in the command buffer with no barrier, so it
//                  may read a CLAS before its build is done
//   --overlap      behind the barrier, the moves are explicit and the last one's destination
//                  lies one alignment past its own source, although the input promises
//                  noMoveOverlap
//   --fixed        the barrier (BUILD/AS_WRITE -> BUILD/AS_READ|AS_WRITE), implicit
//                  destinations
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool overlap = has_flag(argc, argv, "--overlap");
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "move_after_build");
    const Quads quads = make_quads(gpu, 3);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    const VkDeviceSize alignment = gpu.cluster_props.clusterByteAlignment;
    const VkDeviceSize slot =
        place_explicitly(gpu, clas.info, clas.addresses, quads.count, alignment);
    const auto* sources = reinterpret_cast<const VkDeviceAddress*>(clas.addresses.host);

    VkClusterAccelerationStructureMoveObjectsInputNV limits{
        VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_MOVE_OBJECTS_INPUT_NV};
    limits.type = VK_CLUSTER_ACCELERATION_STRUCTURE_TYPE_TRIANGLE_CLUSTER_NV;
    limits.noMoveOverlap = VK_TRUE;
    limits.maxMovedBytes = slot * quads.count;
    VkClusterAccelerationStructureCommandsInfoNV move{
        VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV};
    move.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    move.input.maxAccelerationStructureCount = quads.count;
    move.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_MOVE_OBJECTS_NV;
    move.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    move.input.opInput.pMoveObjects = &limits;
    const VkAccelerationStructureBuildSizesInfoKHR sizes = sizes_of(gpu, move.input);
    using Info = VkClusterAccelerationStructureMoveObjectsInfoNV;
    Buffer infos = gpu.buffer(sizeof(Info) * quads.count);
    Buffer count = gpu.buffer(sizeof(uint32_t));
    Buffer packed = gpu.buffer(sizes.accelerationStructureSize);
    Buffer moved = gpu.buffer(sizeof(VkDeviceAddress) * quads.count);
    Buffer scratch = gpu.buffer(sizes.buildScratchSize);
    for (uint32_t c = 0; c < quads.count; ++c)
        reinterpret_cast<Info*>(infos.host)[c].srcAccelerationStructure = sources[c];
    std::memcpy(count.host, &quads.count, sizeof quads.count);
    move.dstImplicitData = packed.address;
    move.scratchData = scratch.address;
    move.dstAddressesArray = {moved.address, sizeof(VkDeviceAddress), moved.size};
    move.srcInfosArray = {infos.address, sizeof(Info), infos.size};
    move.srcInfosCount = count.address;
    const uint32_t last = quads.count - 1;
    if (overlap) {
        move.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_EXPLICIT_DESTINATIONS_NV;
        move.dstImplicitData = 0;
        auto* destinations = reinterpret_cast<VkDeviceAddress*>(moved.host);
        for (uint32_t c = 0; c < last; ++c)
            destinations[c] = align_up(packed.address, alignment) + c * slot;
        destinations[last] = sources[last] + alignment;
    }

    VkCommandBuffer cb = gpu.begin();
    gpu.cmd_build_clusters(cb, &clas.info);
    // The moves read the CLAS and may write where the build wrote: both access types.
    if (fixed || overlap)
        memory_barrier(cb, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                       VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR |
                           VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR);
    gpu.cmd_build_clusters(cb, &move);
    gpu.submit_and_wait(cb);
    print_range("clas_places", sources[0], slot * quads.count);
    print_range("last_source", sources[last], 0);
    return 0;
}

// SPDX-License-Identifier: Apache-2.0
// Animated clusters: every frame the CLAS are rebuilt in a staging area (explicit destinations
// the host chose) and moved from there into a packed buffer. Bug: the next rebuild into the
// staging area follows the move with no barrier, so it may overwrite a CLAS the move is still
// reading. --fixed puts a BUILD -> BUILD barrier between the move and the rebuild.
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "move_then_rebuild");
    const Quads quads = make_quads(gpu, 3);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    const VkDeviceSize alignment = gpu.cluster_props.clusterByteAlignment;
    const VkDeviceSize slot =
        place_explicitly(gpu, clas.info, clas.addresses, quads.count, alignment);
    const auto* staged = reinterpret_cast<const VkDeviceAddress*>(clas.addresses.host);

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
        reinterpret_cast<Info*>(infos.host)[c].srcAccelerationStructure = staged[c];
    std::memcpy(count.host, &quads.count, sizeof quads.count);
    move.dstImplicitData = packed.address;
    move.scratchData = scratch.address;
    move.dstAddressesArray = {moved.address, sizeof(VkDeviceAddress), moved.size};
    move.srcInfosArray = {infos.address, sizeof(Info), infos.size};
    move.srcInfosCount = count.address;

    VkCommandBuffer cb = gpu.begin();
    gpu.cmd_build_clusters(cb, &clas.info);  // frame 0's clusters
    memory_barrier(cb, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                   VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                   VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                   VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR |
                       VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR);
    gpu.cmd_build_clusters(cb, &move);
    if (fixed)
        memory_barrier(cb, VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR,
                       VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR |
                           VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR);
    gpu.cmd_build_clusters(cb, &clas.info);  // frame 1's clusters, into the same staging area
    gpu.submit_and_wait(cb);
    print_range("staged", staged[0], slot * quads.count);
    return 0;
}

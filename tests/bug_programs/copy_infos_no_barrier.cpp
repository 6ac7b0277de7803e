// SPDX-License-Identifier: Apache-2.0
// Bug: the src infos reach the device through a staging copy (vkCmdCopyBuffer), and the cluster
// build that reads them follows the copy with no barrier. --fixed records the barrier
// (COPY/TRANSFER_WRITE -> ACCELERATION_STRUCTURE_BUILD/INDIRECT_COMMAND_READ).
// --shader-read-barrier has the other bug: a synchronization-1 buffer barrier over the infos
// whose destination access is SHADER_READ, too narrow for the build's read of its src infos
// (INDIRECT_COMMAND_READ on the command's page).
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    const bool narrow = has_flag(argc, argv, "--shader-read-barrier");
    Gpu gpu;
    open(gpu, "copy_infos_no_barrier");
    const Quads quads = make_quads(gpu, 4);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    Buffer staging = gpu.buffer(clas.infos.size);
    std::memcpy(staging.host, clas.infos.host, clas.infos.size);
    std::memset(clas.infos.host, 0, clas.infos.size);

    VkCommandBuffer cb = gpu.begin();
    const VkBufferCopy whole{0, 0, clas.infos.size};
    vkCmdCopyBuffer(cb, staging.buffer, clas.infos.buffer, 1, &whole);
    if (fixed)
        memory_barrier(cb, VK_PIPELINE_STAGE_2_COPY_BIT, VK_ACCESS_2_TRANSFER_WRITE_BIT,
                       VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
    if (narrow) {
        VkBufferMemoryBarrier infos_barrier{VK_STRUCTURE_TYPE_BUFFER_MEMORY_BARRIER};
        infos_barrier.srcAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
        infos_barrier.dstAccessMask = VK_ACCESS_SHADER_READ_BIT;
        infos_barrier.srcQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
        infos_barrier.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
        infos_barrier.buffer = clas.infos.buffer;
        infos_barrier.size = VK_WHOLE_SIZE;
        vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_TRANSFER_BIT,
                             VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR, 0, 0, nullptr,
                             1, &infos_barrier, 0, nullptr);
    }
    gpu.cmd_build_clusters(cb, &clas.info);
    gpu.submit_and_wait(cb);
    print_range("infos", clas.infos.address, clas.infos.size);
    return 0;
}

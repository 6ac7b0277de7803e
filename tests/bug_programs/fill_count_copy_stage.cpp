// SPDX-License-Identifier: Apache-2.0
// Bug: the engine clears and sets the cluster count on the GPU with vkCmdFillBuffer (one word,
// the count of clusters this frame keeps) and orders it for the build with the barrier it uses
// after its staging copies: COPY/TRANSFER_WRITE -> ACCELERATION_STRUCTURE_BUILD/
// INDIRECT_COMMAND_READ. vkCmdFillBuffer runs at CLEAR, not COPY (synchronization2's stage of
// the clear commands), so the barrier's first scope misses the fill and the build may read the
// count before it is written. --v1 uses vkCmdPipelineBarrier with TRANSFER (which holds CLEAR):
// clean. --fixed names CLEAR; --all-transfer names ALL_TRANSFER: both clean.
#include "bug_gpu.h"

using namespace bug_programs;

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    const bool all_transfer = has_flag(argc, argv, "--all-transfer");
    const bool v1 = has_flag(argc, argv, "--v1");
    Gpu gpu;
    open(gpu, "fill_count_copy_stage");
    const Quads quads = make_quads(gpu, 4);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    std::memset(clas.count.host, 0, sizeof(uint32_t));

    VkCommandBuffer cb = gpu.begin();
    vkCmdFillBuffer(cb, clas.count.buffer, 0, sizeof(uint32_t), quads.count);
    if (v1) {
        VkMemoryBarrier barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER};
        barrier.srcAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
        barrier.dstAccessMask = VK_ACCESS_INDIRECT_COMMAND_READ_BIT;
        vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_TRANSFER_BIT,
                             VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR, 0, 1, &barrier,
                             0, nullptr, 0, nullptr);
    } else {
        const VkPipelineStageFlags2 src = fixed          ? VK_PIPELINE_STAGE_2_CLEAR_BIT
                                          : all_transfer ? VK_PIPELINE_STAGE_2_ALL_TRANSFER_BIT
                                                         : VK_PIPELINE_STAGE_2_COPY_BIT;
        memory_barrier(cb, src, VK_ACCESS_2_TRANSFER_WRITE_BIT,
                       VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
    }
    gpu.cmd_build_clusters(cb, &clas.info);
    gpu.submit_and_wait(cb);
    print_range("count", clas.count.address, sizeof(uint32_t));
    return 0;
}

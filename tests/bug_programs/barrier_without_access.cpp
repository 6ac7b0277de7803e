// SPDX-License-Identifier: Apache-2.0
// The src infos reach the device through a staging copy; a barrier stands between the copy and
// the cluster build, but orders the wrong thing. One bug per run:
//   (none)          a VkMemoryBarrier2 with the right stages (COPY -> ACCELERATION_STRUCTURE_
//                   BUILD) and srcAccessMask 0: an execution dependency that makes the copy's
//                   write available to nothing
//   --top-of-pipe   a synchronization-1 vkCmdPipelineBarrier whose dstStageMask is
//                   TOP_OF_PIPE with dstAccessMask 0: later commands wait (TOP_OF_PIPE in
//                   the second scope is ALL_COMMANDS with no access), but the write is made
//                   visible to none of them
//   --fixed         the barrier with TRANSFER_WRITE -> INDIRECT_COMMAND_READ
//   --fixed-split   the copy in a command buffer of its own, the synchronization-1 barrier and
//                   the build in a second, both in one vkQueueSubmit batch (a barrier orders
//                   what came before it in submission order, in any command buffer)
#include "bug_gpu.h"

using namespace bug_programs;

namespace {

void sync1_barrier(VkCommandBuffer cb, VkPipelineStageFlags dst_stage, VkAccessFlags dst_access) {
    VkMemoryBarrier barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER};
    barrier.srcAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
    barrier.dstAccessMask = dst_access;
    vkCmdPipelineBarrier(cb, VK_PIPELINE_STAGE_TRANSFER_BIT, dst_stage, 0, 1, &barrier, 0, nullptr,
                         0, nullptr);
}

}  // namespace

int main(int argc, char** argv) {
    const bool top_of_pipe = has_flag(argc, argv, "--top-of-pipe");
    const bool fixed = has_flag(argc, argv, "--fixed");
    const bool split = has_flag(argc, argv, "--fixed-split");
    Gpu gpu;
    open(gpu, "barrier_without_access");
    const Quads quads = make_quads(gpu, 4);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    Buffer staging = gpu.buffer(clas.infos.size);
    std::memcpy(staging.host, clas.infos.host, clas.infos.size);
    std::memset(clas.infos.host, 0, clas.infos.size);

    VkCommandBuffer upload = gpu.begin();
    const VkBufferCopy whole{0, 0, clas.infos.size};
    vkCmdCopyBuffer(upload, staging.buffer, clas.infos.buffer, 1, &whole);
    VkCommandBuffer build = upload;
    if (split) {
        vk_ok(vkEndCommandBuffer(upload), "vkEndCommandBuffer");
        build = gpu.begin();
        sync1_barrier(build, VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                      VK_ACCESS_INDIRECT_COMMAND_READ_BIT);
    } else if (top_of_pipe) {
        sync1_barrier(build, VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, 0);
    } else {
        memory_barrier(build, VK_PIPELINE_STAGE_2_COPY_BIT,
                       fixed ? VK_ACCESS_2_TRANSFER_WRITE_BIT : 0,
                       VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR,
                       VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT);
    }
    gpu.cmd_build_clusters(build, &clas.info);
    vk_ok(vkEndCommandBuffer(build), "vkEndCommandBuffer");
    const VkCommandBuffer both[2] = {upload, build};
    VkSubmitInfo batch{VK_STRUCTURE_TYPE_SUBMIT_INFO};
    batch.commandBufferCount = split ? 2 : 1;
    batch.pCommandBuffers = split ? both : &build;
    VkFence done = gpu.fence();
    vk_ok(vkQueueSubmit(gpu.queue, 1, &batch, done), "vkQueueSubmit");
    gpu.wait(done);
    print_range("infos", clas.infos.address, clas.infos.size);
    return 0;
}

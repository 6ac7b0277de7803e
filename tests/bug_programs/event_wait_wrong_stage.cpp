// SPDX-License-Identifier: Apache-2.0
// Bug: the src infos are copied in (vkCmdCopyBuffer) and an event's set names the copy rightly
// (COPY/TRANSFER_WRITE), but its wait's destination is COMPUTE_SHADER/SHADER_READ, the stage
// the engine's author took the cluster build to run in: the build, at
// ACCELERATION_STRUCTURE_BUILD, is outside the wait's second scope. vkCmdSetEvent2 and
// vkCmdWaitEvents2 share the one VkDependencyInfo, as the specification asks. --v1 uses
// vkCmdSetEvent(TRANSFER) and vkCmdWaitEvents with the right stages but a VkMemoryBarrier
// whose srcAccessMask is 0 (the write is never made available). --fixed waits at
// ACCELERATION_STRUCTURE_BUILD/INDIRECT_COMMAND_READ (with --v1: srcAccessMask TRANSFER_WRITE).
#include "bug_gpu.h"

using namespace bug_programs;

namespace {

void set_and_wait_v2(VkCommandBuffer cb, VkEvent event, bool fixed) {
    VkMemoryBarrier2 barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER_2};
    barrier.srcStageMask = VK_PIPELINE_STAGE_2_COPY_BIT;
    barrier.srcAccessMask = VK_ACCESS_2_TRANSFER_WRITE_BIT;
    barrier.dstStageMask = fixed ? VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR
                                 : VK_PIPELINE_STAGE_2_COMPUTE_SHADER_BIT;
    barrier.dstAccessMask =
        fixed ? VK_ACCESS_2_INDIRECT_COMMAND_READ_BIT : VK_ACCESS_2_SHADER_READ_BIT;
    VkDependencyInfo dependency{VK_STRUCTURE_TYPE_DEPENDENCY_INFO};
    dependency.memoryBarrierCount = 1;
    dependency.pMemoryBarriers = &barrier;
    vkCmdSetEvent2(cb, event, &dependency);
    vkCmdWaitEvents2(cb, 1, &event, &dependency);
}

void set_and_wait_v1(VkCommandBuffer cb, VkEvent event, bool fixed) {
    vkCmdSetEvent(cb, event, VK_PIPELINE_STAGE_TRANSFER_BIT);
    VkMemoryBarrier barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER};
    barrier.srcAccessMask = fixed ? VK_ACCESS_TRANSFER_WRITE_BIT : 0;
    barrier.dstAccessMask = VK_ACCESS_INDIRECT_COMMAND_READ_BIT;
    vkCmdWaitEvents(cb, 1, &event, VK_PIPELINE_STAGE_TRANSFER_BIT,
                    VK_PIPELINE_STAGE_ACCELERATION_STRUCTURE_BUILD_BIT_KHR, 1, &barrier, 0, nullptr,
                    0, nullptr);
}

}  // namespace

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    const bool v1 = has_flag(argc, argv, "--v1");
    Gpu gpu;
    open(gpu, "event_wait_wrong_stage");
    const Quads quads = make_quads(gpu, 3);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    Buffer staging = gpu.buffer(clas.infos.size);
    std::memcpy(staging.host, clas.infos.host, clas.infos.size);
    std::memset(clas.infos.host, 0, clas.infos.size);
    VkEventCreateInfo event_info{VK_STRUCTURE_TYPE_EVENT_CREATE_INFO};
    event_info.flags = VK_EVENT_CREATE_DEVICE_ONLY_BIT;
    VkEvent copied = VK_NULL_HANDLE;
    vk_ok(vkCreateEvent(gpu.device, &event_info, nullptr, &copied), "vkCreateEvent");

    VkCommandBuffer cb = gpu.begin();
    const VkBufferCopy whole{0, 0, clas.infos.size};
    vkCmdCopyBuffer(cb, staging.buffer, clas.infos.buffer, 1, &whole);
    if (v1)
        set_and_wait_v1(cb, copied, fixed);
    else
        set_and_wait_v2(cb, copied, fixed);
    gpu.cmd_build_clusters(cb, &clas.info);
    gpu.submit_and_wait(cb);
    print_range("infos", clas.infos.address, clas.infos.size);
    vkDestroyEvent(gpu.device, copied, nullptr);
    return 0;
}
